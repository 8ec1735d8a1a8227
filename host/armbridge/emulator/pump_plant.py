"""Pneumatic plant of the soft arm (WJRRT paper, section V-B/C): syringes, air, bending joints.

Per joint k, as the paper builds it: a 12 V linear motor on an L298 pushes the
plunger of a 100 mL syringe, whose outlet is tubed to one polychloroprene
joint; pushing blows air in and bends the joint, pulling sucks it out and the
joint straightens. The numbers are ours (the paper gives none), documented in
`PumpParams` (boards/pump_rig.py: the rig's one description, the planner's too) and
docs/emulator.md ("Syringe-pump board in simavr").

    v_cmd = sign(u) v_motor (|u| - u0) / (1 - u0), 0 when |u| <= u0    motor (dead zone u0)
    dv/dt = (v_cmd - v) / tau_motor                                      motor lag
    dx/dt = v, x in [0, travel]                                          plunger, hard ends
    V = A (travel - x) + V_tube + V_joint0 + k_vol theta                 air volume
    p = P0 (V_rest / V - 1)                                              gauge pressure (Boyle, isothermal)

The joint (Fig. 9a: "inflation requires some extra force at the beginning;
however, deflation happens smoothly") is a balloon with snap-through: a
closed joint stays straight until p reaches p_open; then it is open and
relaxes towards the open branch

    theta_eq(p) = range (p - p_hold) / (p_full - p_hold), clipped to [0, range]

with time constant tau_inflate while theta rises (abrupt: at p_open the
target is already 28 % of the range) and tau_deflate while it falls
(smooth), so the same pressure gives a larger bend on the way down
(hysteresis). An open joint back at theta = 0 closes again. The air the bend
takes in (k_vol) lowers the pressure as it opens.

    mV = mv(theta) + N(0, sigma_mv)                                      bend sensor, linear

The bend sensor is linear, calibrated like the firmware's default `BEND`
(adc_a at angle a, adc_b at b, 10-bit ADC on 5 V): the firmware reads the
true angle plus the noise. End stops close within `switch_mm` of either end
of the plunger's travel (the pin reads LOW, INPUT_PULLUP).

`step` is the pure step function (numpy in, numpy out); `PumpPlant` holds the
state, the motor commands and the seeded sensor noise, and offers what the
emulator needs of a plant (n, q, advance_to, stall).
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from armbridge.boards.pump_rig import PumpParams

# simavr 1.6 converts vin * 1023 / vref (the datasheet's chip: vin * 1024 / vref); the
# sensor voltages are inverted through simavr's conversion so that the firmware reads
# the calibrated angle, as it would on the chip with a sensor calibrated there.
ADC_FULL = 1023
ADC_REF_MV = 5000.0      # AVCC = 5 V


def pressure(x: np.ndarray, theta: np.ndarray, p: PumpParams) -> np.ndarray:
    """Gauge pressure (kPa) of each channel: Boyle's law on the closed air volume."""
    v = (p.travel_mm - x) * p.area_mm2 / 1000.0 + p.v_tube_ml + p.v_joint_ml + p.k_vol_ml * theta
    return p.p0_kpa * (p.v_rest_ml / v - 1.0)


def theta_open(pk: np.ndarray, rng: np.ndarray, p: PumpParams) -> np.ndarray:
    """The open joint's equilibrium bend (rad) at gauge pressure pk (kPa)."""
    frac = (pk - p.p_hold_kpa) / (p.p_full_kpa - p.p_hold_kpa)
    return np.clip(frac, 0.0, 1.0) * rng


def motor_speed(u: np.ndarray, p: PumpParams) -> np.ndarray:
    """Commanded plunger speed (mm/s) for signed duties u in [-1, 1] (+ pushes: inflates)."""
    u = np.clip(np.asarray(u, dtype=float), -1.0, 1.0)
    mag = np.clip((np.abs(u) - p.dead_duty) / (1.0 - p.dead_duty), 0.0, 1.0)
    return np.sign(u) * mag * p.v_motor


def step(x: np.ndarray, v: np.ndarray, theta: np.ndarray, is_open: np.ndarray, u: np.ndarray, dt: float,
         p: PumpParams, rng: np.ndarray, stalled: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One step of length dt (s); returns new (x, v, theta, is_open). Pure.

    x plunger (mm), v its speed (mm/s), theta bend (rad), is_open the joint's
    snap state, u signed duties, rng each joint's range (rad), stalled: motors
    that do not turn (their speed is forced to 0).
    """
    v_cmd = motor_speed(u, p)
    v_new = v + (v_cmd - v) * (1.0 - math.exp(-dt / p.tau_motor))
    if stalled is not None and stalled.any():
        v_new = np.where(stalled, 0.0, v_new)
    x_new = x + 0.5 * (v + v_new) * dt
    at_end = ((x_new <= 0.0) & (v_new < 0)) | ((x_new >= p.travel_mm) & (v_new > 0))
    x_new = np.clip(x_new, 0.0, p.travel_mm)
    v_new = np.where(at_end, 0.0, v_new)

    pk = pressure(x_new, theta, p)
    opened = is_open | (pk >= p.p_open_kpa)
    target = np.where(opened, theta_open(pk, rng, p), 0.0)
    tau = np.where(target > theta, p.tau_inflate, p.tau_deflate)
    theta_new = target + (theta - target) * np.exp(-dt / tau)
    theta_new = np.clip(theta_new, 0.0, rng)
    closed = opened & (target <= 0.0) & (theta_new < 1e-4)
    return x_new, v_new, np.where(closed, 0.0, theta_new), opened & ~closed


def sensor_mv(theta: np.ndarray, bend: Sequence[Sequence[float]]) -> np.ndarray:
    """Noise-free bend-sensor voltage (mV) per joint, linear through each joint's
    calibration (adc_a, a_mrad, adc_b, b_mrad): the firmware reads theta back."""
    cal = np.asarray(bend, dtype=float)
    adc_a, a, adc_b, b = cal[:, 0], cal[:, 1] / 1000.0, cal[:, 2], cal[:, 3] / 1000.0
    adc = adc_a + (theta - a) * (adc_b - adc_a) / (b - a)
    return np.clip((adc + 0.5) * ADC_REF_MV / ADC_FULL, 0.0, ADC_REF_MV)


class PumpPlant:
    """The n syringe channels, their joints and sensors; see the module docstring.

    rng: each joint's range (rad, its upper limit; the lower is 0, straight);
    bend: the sensor calibration per joint (the firmware's default BEND).
    """

    def __init__(self, rng: Sequence[float] | np.ndarray, bend: Sequence[Sequence[float]], params: PumpParams | None = None,
                 seed: int = 0) -> None:
        self.p = params or PumpParams()
        self.rng = np.asarray(rng, dtype=float)
        self.n = len(self.rng)
        self.bend = [tuple(float(c) for c in b) for b in bend]
        if len(self.bend) != self.n:
            raise ValueError(f"{len(self.bend)} bend calibrations for {self.n} joints")
        self.x = np.full(self.n, self.p.x0_mm)
        self.v = np.zeros(self.n)
        self.q = np.zeros(self.n)
        self.is_open = np.zeros(self.n, dtype=bool)
        self.u = np.zeros(self.n)
        self.t = 0.0
        self._stall_at = np.full(self.n, np.inf)
        self._noise = np.random.default_rng(seed)
        self.cfg: Any = None      # the firmware's config, when a factory built the plant from it

    # the emulator's plant interface ------------------------------------------
    def advance_to(self, t: float) -> None:
        while self.t < t - 1e-12:
            dt = min(self.p.max_dt, t - self.t)
            stalled = self._stall_at <= self.t
            self.x, self.v, self.q, self.is_open = step(self.x, self.v, self.q, self.is_open, self.u, dt, self.p,
                                                        self.rng, stalled)
            self.t += dt

    def stall(self, j: int, t: float) -> None:
        """Motor j (0-based) seizes from sim time t on."""
        self._stall_at[j] = min(self._stall_at[j], float(t))

    # actuators and sensors ---------------------------------------------------
    def drive(self, u: Any) -> None:
        """Signed duties in [-1, 1] from now on (+ pushes the plunger: inflates)."""
        self.u = np.clip(np.asarray(u, dtype=float), -1.0, 1.0)

    def off(self) -> None:
        self.u = np.zeros(self.n)

    def pressure(self) -> np.ndarray:
        return pressure(self.x, self.q, self.p)

    def sensor_mv(self) -> np.ndarray:
        """Bend-sensor voltages now, with the sensor noise."""
        mv = sensor_mv(self.q, self.bend) + self._noise.normal(0.0, self.p.sigma_mv, self.n)
        return np.clip(mv, 0.0, ADC_REF_MV)

    def end_stops(self) -> tuple[np.ndarray, np.ndarray]:
        """(retracted, extended): True where that end stop is closed."""
        s = self.p.switch_mm
        return self.x <= s, self.x >= self.p.travel_mm - s

    def syringe_permille(self) -> np.ndarray:
        """Plunger positions in per-mille of travel (the telemetry's unit)."""
        return self.x / self.p.travel_mm * 1000.0
