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

    dn/dt = -leak p / LEAK_REF_KPA                                       leak (n: the air, mL at P0)
    mV = mv(offset + gain theta) + N(0, sigma_mv), in steps of quant_mv  bend sensor, linear

The air starts as V_rest (the plunger retracted, the joint straight, at
atmospheric pressure); a leaky joint or fitting (leak: mL/s at LEAK_REF_KPA
gauge, laminar) loses it while pressurised. The bend sensor is linear,
calibrated like the firmware's default `BEND` (adc_a at angle a, adc_b at b,
10-bit ADC on 5 V): the firmware reads the true angle plus the noise. End stops close within `switch_mm` of either end
of the plunger's travel (the pin reads LOW, INPUT_PULLUP).

`step` is the pure step function (numpy in, numpy out); `PumpPlant` holds the
state, the motor commands and the seeded sensor noise, and offers what the
emulator needs of a plant (n, q, advance_to, stall).

Hidden truth (`plant=random`, emulator/truth.py): `PumpTruth` is the rig's
`PumpParams` with one value per joint of the fields that differ from joint to
joint on a real rig (motor, bend curve, asymmetry, leak, sensor errors);
`hidden_truth(cfg, rng)` draws them from `SPREADS`. Its defaults are the
rig's own numbers with no leak and no sensor error: the nominal plant.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cached_property
from types import SimpleNamespace
from typing import Any, Sequence

import numpy as np

from armbridge.boards.pump_rig import PumpParams
from armbridge.emulator.truth import Spread, draw

# simavr 1.6 converts vin * 1023 / vref (the datasheet's chip: vin * 1024 / vref); the
# sensor voltages are inverted through simavr's conversion so that the firmware reads
# the calibrated angle, as it would on the chip with a sensor calibrated there.
ADC_FULL = 1023
ADC_REF_MV = 5000.0      # AVCC = 5 V
LEAK_REF_KPA = 20.0      # a leak is given as its flow (mL/s of atmospheric air) at this gauge pressure

#: PumpTruth's per-joint fields that are PumpParams' too (None: the rig's value)
RIG_FIELDS = ("v_motor", "dead_duty", "k_vol_ml", "p_open_kpa", "p_hold_kpa", "p_full_kpa",
              "tau_inflate", "tau_deflate", "sigma_mv")
#: its own, neutral when nominal
EXTRA_NEUTRAL = {"leak_ml_s": 0.0, "offset_mrad": 0.0, "gain": 1.0, "quant_mv": 0.0}

Joints = tuple[float, ...] | None


@dataclass(frozen=True)
class PumpTruth:
    """One rig as it really is: `rig` (PumpParams, the nominal description the planner reads) with
    one value per joint of what differs between joints. None: the rig's value (RIG_FIELDS) or
    the neutral one (EXTRA_NEUTRAL); `nominal(rig, n)` spells every value out (truth.draw needs
    them). Other attributes (travel_mm, switch_mm, ...) are the rig's.

    v_motor, dead_duty            the motor's full-duty speed (mm/s) and dead duty
    k_vol_ml, p_open_kpa,
    p_hold_kpa, p_full_kpa        the bend-per-volume curve and the snap-open pressure
    tau_inflate, tau_deflate      the asymmetry (s)
    leak_ml_s                     leak, mL/s of atmospheric air at LEAK_REF_KPA gauge (0: tight)
    offset_mrad, gain             the bend sensor reads offset + gain theta through the firmware's line
    sigma_mv, quant_mv            its noise (mV) and its output step (mV; 0: continuous)
    """

    rig: PumpParams = PumpParams()
    v_motor: Joints = None
    dead_duty: Joints = None
    k_vol_ml: Joints = None
    p_open_kpa: Joints = None
    p_hold_kpa: Joints = None
    p_full_kpa: Joints = None
    tau_inflate: Joints = None
    tau_deflate: Joints = None
    sigma_mv: Joints = None
    leak_ml_s: Joints = None
    offset_mrad: Joints = None
    gain: Joints = None
    quant_mv: Joints = None

    def __getattr__(self, name: str) -> Any:      # the rig's scalars (travel_mm, switch_mm, v_rest_ml, ...)
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.rig, name)

    @classmethod
    def nominal(cls, rig: PumpParams, n: int) -> "PumpTruth":
        """The rig's nominal plant with every per-joint value spelled out."""
        vals = {f: (float(getattr(rig, f)),) * n for f in RIG_FIELDS}
        vals.update({f: (v,) * n for f, v in EXTRA_NEUTRAL.items()})
        return cls(rig=rig, **vals)

    @cached_property
    def arrays(self) -> SimpleNamespace:
        """The rig's numbers with the per-joint fields as arrays (what `step` computes with)."""
        ns = SimpleNamespace(**dataclasses.asdict(self.rig), v_rest_ml=self.rig.v_rest_ml)
        for f in RIG_FIELDS:
            v = getattr(self, f)
            setattr(ns, f, np.asarray(v, dtype=float) if v is not None else getattr(self.rig, f))
        for f, neutral in EXTRA_NEUTRAL.items():
            v = getattr(self, f)
            setattr(ns, f, np.asarray(v, dtype=float) if v is not None else neutral)
        return ns


def physics(p: PumpParams | PumpTruth | SimpleNamespace) -> Any:
    """What the pure functions compute with: PumpParams as they are (its scalars broadcast), a
    PumpTruth's arrays."""
    return p.arrays if isinstance(p, PumpTruth) else p


# Why each joint differs (docs/emulator.md, "Hidden truth"). The rig has no data sheet of its own
# (the paper gives no numbers): the widths are those of the parts it names.
SPREADS = (
    Spread("v_motor", "scale", 0.10, per_joint=True, lo=12.0, hi=28.0, unit="mm/s",
           source="12 V linear motors: no-load speed +-10 % between units, less under the syringe's load"),
    Spread("dead_duty", "uniform", 0.03, per_joint=True, lo=0.02, hi=0.10,
           source="motor break-away: static friction of the plunger's O-ring and the gearbox (below the "
                  "firmware's DUTY_MIN 0.12)"),
    Spread("k_vol_ml", "scale", 0.15, per_joint=True, lo=12.0, hi=28.0, unit="mL/rad",
           source="hand-cast polychloroprene joints (paper V-B): wall thickness varies, so does the air per bend"),
    Spread("p_open_kpa", "normal", 1.5, per_joint=True, lo=9.0, hi=15.0, unit="kPa",
           source="Fig. 9a: the snap-through pressure of an elastomer balloon, per joint"),
    Spread("p_hold_kpa", "normal", 0.8, per_joint=True, lo=3.0, hi=7.0, unit="kPa",
           source="Fig. 9a: where the deflating joint comes straight"),
    Spread("p_full_kpa", "scale", 0.10, per_joint=True, lo=24.0, hi=36.0, unit="kPa",
           source="bend per pressure: the elastomer's stiffness, +-10 % cast to cast"),
    Spread("tau_inflate", "scale", 0.25, per_joint=True, lo=0.02, hi=0.10, unit="s",
           source="Fig. 9a: inflation abrupt (fast), deflation smooth; the ratio varies per joint"),
    Spread("tau_deflate", "scale", 0.25, per_joint=True, lo=0.20, hi=0.80, unit="s",
           source="Fig. 9a, as tau_inflate"),
    Spread("leak_ml_s", "uniform", 0.15, per_joint=True, lo=0.0, hi=0.15, unit="mL/s",
           source="a pinhole or loose Luer fitting: about half the joints hold tight (0), the rest lose up "
                  "to 0.15 mL/s at 20 kPa (a held bend sags a few mrad/s)"),
    Spread("offset_mrad", "normal", 10.0, per_joint=True, lo=-30.0, hi=30.0, unit="mrad",
           source="flex sensors: flat resistance +-30 % (data sheet), calibrated at assembly; what "
                  "remains is drift of the straight reading"),
    Spread("gain", "scale", 0.03, per_joint=True, lo=0.9, hi=1.1,
           source="flex sensors: bend resistance repeatability and temperature, a few %"),
    Spread("sigma_mv", "scale", 0.3, per_joint=True, lo=1.0, hi=8.0, unit="mV",
           source="divider and ADC noise: 0.2-1.6 LSB of a 10-bit ADC on 5 V"),
    Spread("quant_mv", "uniform", 5.0, per_joint=True, lo=0.0, hi=5.0, unit="mV",
           source="a coarse sensor (carbon-ink flex sensors move in resistance steps): up to one LSB"),
)


def nominal_rig(cfg: Any) -> PumpParams:
    """The rig the firmware's config was built for: PumpParams with the motor's speed such that
    a full stroke at full duty takes SYRINGE_STROKE_MS (the firmware's travel estimate)."""
    stroke = getattr(cfg, "SYRINGE_STROKE_MS", None)
    rig = PumpParams()
    return PumpParams(v_motor=rig.travel_mm / (float(stroke) / 1000.0)) if stroke else rig


def hidden_truth(cfg: Any, rng: np.random.Generator) -> PumpTruth:
    """The plant of one random rig (plant=random): `nominal_rig(cfg)` with SPREADS drawn per joint."""
    n = int(cfg.N_JOINTS)
    return draw(PumpTruth.nominal(nominal_rig(cfg), n), SPREADS, rng, n)


def pressure(x: np.ndarray, theta: np.ndarray, p: Any, air: np.ndarray | None = None) -> np.ndarray:
    """Gauge pressure (kPa) of each channel: Boyle's law on the closed air volume; `air` (mL at
    atmospheric pressure) is V_rest when none has leaked (None)."""
    p = physics(p)
    v = (p.travel_mm - x) * p.area_mm2 / 1000.0 + p.v_tube_ml + p.v_joint_ml + p.k_vol_ml * theta
    return p.p0_kpa * ((p.v_rest_ml if air is None else air) / v - 1.0)


def theta_open(pk: np.ndarray, rng: np.ndarray, p: Any) -> np.ndarray:
    """The open joint's equilibrium bend (rad) at gauge pressure pk (kPa)."""
    p = physics(p)
    frac = (pk - p.p_hold_kpa) / (p.p_full_kpa - p.p_hold_kpa)
    return np.clip(frac, 0.0, 1.0) * rng


def motor_speed(u: np.ndarray, p: Any) -> np.ndarray:
    """Commanded plunger speed (mm/s) for signed duties u in [-1, 1] (+ pushes: inflates)."""
    p = physics(p)
    u = np.clip(np.asarray(u, dtype=float), -1.0, 1.0)
    mag = np.clip((np.abs(u) - p.dead_duty) / (1.0 - p.dead_duty), 0.0, 1.0)
    return np.sign(u) * mag * p.v_motor


def step(x: np.ndarray, v: np.ndarray, theta: np.ndarray, is_open: np.ndarray, air: np.ndarray, u: np.ndarray,
         dt: float, p: Any, rng: np.ndarray, stalled: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One step of length dt (s); returns new (x, v, theta, is_open, air). Pure.

    x plunger (mm), v its speed (mm/s), theta bend (rad), is_open the joint's
    snap state, air the air in the channel (mL at atmospheric pressure), u
    signed duties, p PumpParams or PumpTruth, rng each joint's range (rad),
    stalled: motors that do not turn (their speed is forced to 0).
    """
    p = physics(p)
    v_cmd = motor_speed(u, p)
    v_new = v + (v_cmd - v) * (1.0 - math.exp(-dt / p.tau_motor))
    if stalled is not None and stalled.any():
        v_new = np.where(stalled, 0.0, v_new)
    x_new = x + 0.5 * (v + v_new) * dt
    at_end = ((x_new <= 0.0) & (v_new < 0)) | ((x_new >= p.travel_mm) & (v_new > 0))
    x_new = np.clip(x_new, 0.0, p.travel_mm)
    v_new = np.where(at_end, 0.0, v_new)

    air_new = air - p.leak_ml_s * pressure(x, theta, p, air) / LEAK_REF_KPA * dt \
        if np.any(getattr(p, "leak_ml_s", 0.0)) else air
    pk = pressure(x_new, theta, p, air_new)
    opened = is_open | (pk >= p.p_open_kpa)
    target = np.where(opened, theta_open(pk, rng, p), 0.0)
    tau = np.where(target > theta, p.tau_inflate, p.tau_deflate)
    theta_new = target + (theta - target) * np.exp(-dt / tau)
    theta_new = np.clip(theta_new, 0.0, rng)
    closed = opened & (target <= 0.0) & (theta_new < 1e-4)
    return x_new, v_new, np.where(closed, 0.0, theta_new), opened & ~closed, air_new


def sensor_mv(theta: np.ndarray, bend: Sequence[Sequence[float]], p: Any = None) -> np.ndarray:
    """Noise-free bend-sensor voltage (mV) per joint, linear through each joint's
    calibration (adc_a, a_mrad, adc_b, b_mrad): the firmware reads theta back
    (with a PumpTruth `p`: offset + gain theta, its sensors' errors)."""
    if p is not None:
        a = physics(p)
        theta = getattr(a, "offset_mrad", 0.0) / 1000.0 + getattr(a, "gain", 1.0) * theta
    cal = np.asarray(bend, dtype=float)
    adc_a, a, adc_b, b = cal[:, 0], cal[:, 1] / 1000.0, cal[:, 2], cal[:, 3] / 1000.0
    adc = adc_a + (theta - a) * (adc_b - adc_a) / (b - a)
    return np.clip((adc + 0.5) * ADC_REF_MV / ADC_FULL, 0.0, ADC_REF_MV)


class PumpPlant:
    """The n syringe channels, their joints and sensors; see the module docstring.

    rng: each joint's range (rad, its upper limit; the lower is 0, straight);
    bend: the sensor calibration per joint (the firmware's default BEND).
    """

    def __init__(self, rng: Sequence[float] | np.ndarray, bend: Sequence[Sequence[float]],
                 params: PumpParams | PumpTruth | None = None, seed: int = 0) -> None:
        self.rng = np.asarray(rng, dtype=float)
        self.n = len(self.rng)
        p = params or PumpParams()
        self.p: PumpTruth = p if isinstance(p, PumpTruth) else PumpTruth.nominal(p, self.n)
        self._a = self.p.arrays
        for f in (*RIG_FIELDS, *EXTRA_NEUTRAL):
            if np.shape(getattr(self._a, f)) not in ((), (self.n,)):
                raise ValueError(f"{f}: {getattr(self.p, f)} is not one value per joint ({self.n})")
        self.bend = [tuple(float(c) for c in b) for b in bend]
        if len(self.bend) != self.n:
            raise ValueError(f"{len(self.bend)} bend calibrations for {self.n} joints")
        self.x = np.full(self.n, self.p.x0_mm)
        self.v = np.zeros(self.n)
        self.q = np.zeros(self.n)
        self.is_open = np.zeros(self.n, dtype=bool)
        self.air = np.full(self.n, self.p.v_rest_ml)
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
            self.x, self.v, self.q, self.is_open, self.air = step(
                self.x, self.v, self.q, self.is_open, self.air, self.u, dt, self._a, self.rng, stalled)
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
        return pressure(self.x, self.q, self._a, self.air)

    def sensor_mv(self) -> np.ndarray:
        """Bend-sensor voltages now, with the sensor noise (and its steps)."""
        a = self._a
        mv = sensor_mv(self.q, self.bend, a) + self._noise.normal(0.0, a.sigma_mv, self.n)
        if np.any(a.quant_mv):
            step_mv = np.broadcast_to(a.quant_mv, mv.shape)
            mv = np.where(step_mv > 0, np.round(mv / np.where(step_mv > 0, step_mv, 1.0)) * step_mv, mv)
        return np.clip(mv, 0.0, ADC_REF_MV)

    def end_stops(self) -> tuple[np.ndarray, np.ndarray]:
        """(retracted, extended): True where that end stop is closed."""
        s = self.p.switch_mm
        return self.x <= s, self.x >= self.p.travel_mm - s

    def syringe_permille(self) -> np.ndarray:
        """Plunger positions in per-mille of travel (the telemetry's unit)."""
        return self.x / self.p.travel_mm * 1000.0
