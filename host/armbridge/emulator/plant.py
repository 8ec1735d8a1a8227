"""Servo plant of the 3R arm: n hobby servos driven by effort, read by potentiometers.

The numbers are ours, for a 35 kg*cm hobby servo (DS3235 class) on the arm's
links; they are documented in `PlantParams` and docs/emulator.md.

Model per joint, with effort u in [-1, 1] (the firmware's PWM duty, signed):

    v_cmd = u * v_servo                      commanded speed
    dv/dt = (v_cmd - v) / tau                first-order velocity lag ...
    |dv/dt| <= a_max                         ... with an acceleration limit
    dq/dt = v                                position, stopped by hard stops
    y = quantise(q + N(0, sigma))            potentiometer through a 12-bit ADC

`step` is the pure step function (numpy in, numpy out); `ServoPlant` holds the
state, the fault schedule and the seeded measurement noise. `Pots` (the
potentiometers and the ADC) is shared with the positional rig's plant
(servo_plant.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PlantParams:
    """Physical numbers of one servo joint (all joints share them).

    v_servo     5.0 rad/s   speed at full effort under the arm's load (about 0.21 s/60 deg)
    tau         0.030 s     velocity lag time constant (motor + gearbox + servo electronics)
    a_max       60 rad/s^2  acceleration limit (stall torque over the reflected inertia)
    stop_margin 0.05 rad    hard stops sit this far beyond the firmware's joint limits
    sigma       0.001 rad   gaussian noise of the potentiometer reading (1 mrad)
    adc_bits    12          ADC resolution; the code range spans hard stop to hard stop
    max_dt      0.001 s     longest integration sub-step
    """

    v_servo: float = 5.0
    tau: float = 0.030
    a_max: float = 60.0
    stop_margin: float = 0.05
    sigma: float = 0.001
    adc_bits: int = 12
    max_dt: float = 0.001


def step(
    q: np.ndarray,
    v: np.ndarray,
    u: np.ndarray,
    dt: float,
    p: PlantParams,
    lo_stop: np.ndarray,
    hi_stop: np.ndarray,
    stalled: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One integration step of length dt (s); returns new (q, v). Pure.

    u: efforts, clipped to [-1, 1] (0 = no drive). stalled: bool mask of joints
    whose velocity is forced to zero (a seized gearbox or a burnt motor).
    """
    u = np.clip(np.asarray(u, dtype=float), -1.0, 1.0)
    v_cmd = u * p.v_servo
    dv = (v_cmd - v) * (1.0 - math.exp(-dt / p.tau))
    lim = p.a_max * dt
    v_new = v + np.clip(dv, -lim, lim)
    if stalled is not None and stalled.any():
        v_new = np.where(stalled, 0.0, v_new)
        v_old = np.where(stalled, 0.0, v)
    else:
        v_old = v
    q_new = q + 0.5 * (v_old + v_new) * dt
    low = q_new <= lo_stop
    high = q_new >= hi_stop
    q_new = np.clip(q_new, lo_stop, hi_stop)
    v_new = np.where((low & (v_new < 0)) | (high & (v_new > 0)), 0.0, v_new)
    return q_new, v_new


class Pots:
    """Feedback potentiometers read through an ADC: gaussian noise (sigma, rad),
    then quantisation to 2**bits codes over the stop-to-stop span lo_stop..hi_stop
    (rad, one per joint), so a reading never leaves the span. rng: the seeded
    noise source (numpy Generator), owned by the plant."""

    def __init__(self, lo_stop: np.ndarray, hi_stop: np.ndarray, sigma: float, bits: int,
                 rng: np.random.Generator) -> None:
        self.lo_stop = np.asarray(lo_stop, dtype=float)
        self.span = np.asarray(hi_stop, dtype=float) - self.lo_stop
        self.sigma = float(sigma)
        self.codes = (1 << int(bits)) - 1
        self.rng = rng

    def measure(self, q: np.ndarray) -> np.ndarray:
        noisy = q + self.rng.normal(0.0, self.sigma, self.lo_stop.size)
        code = np.clip(np.rint((noisy - self.lo_stop) / self.span * self.codes), 0, self.codes)
        return self.lo_stop + code * (self.span / self.codes)

    @property
    def quantum(self) -> np.ndarray:
        """ADC step per joint (rad)."""
        return self.span / self.codes


class ServoPlant:
    """n servo joints with state, time, faults and seeded potentiometer noise.

    lo, hi: the firmware's joint limits (rad); the hard stops are `stop_margin`
    beyond them. q0: initial positions (default: mid-range).
    """

    def __init__(
        self,
        lo,
        hi,
        params: PlantParams | None = None,
        q0=None,
        seed: int = 0,
    ) -> None:
        self.p = params or PlantParams()
        self.lo = np.asarray(lo, dtype=float)
        self.hi = np.asarray(hi, dtype=float)
        if self.lo.shape != self.hi.shape or self.lo.ndim != 1:
            raise ValueError("lo and hi must be 1-D arrays of the same length")
        self.n = int(self.lo.size)
        self.lo_stop = self.lo - self.p.stop_margin
        self.hi_stop = self.hi + self.p.stop_margin
        self.q = (
            0.5 * (self.lo + self.hi) if q0 is None else np.clip(np.asarray(q0, float), self.lo_stop, self.hi_stop)
        )
        self.v = np.zeros(self.n)
        self.u = np.zeros(self.n)
        self.driven = False
        self.t = 0.0
        self.stall_from = np.full(self.n, np.inf)
        self.pots = Pots(self.lo_stop, self.hi_stop, self.p.sigma, self.p.adc_bits, np.random.default_rng(seed))

    # drive ---------------------------------------------------------------
    def drive(self, efforts) -> None:
        """Set the efforts (clipped to [-1, 1]); the drives are on."""
        u = np.clip(np.asarray(efforts, dtype=float), -1.0, 1.0)
        if u.shape != (self.n,):
            raise ValueError(f"expected {self.n} efforts, got {u.shape}")
        self.u = u
        self.driven = True

    def off(self) -> None:
        """Drives off (PWM disabled): no torque, the velocity decays through the lag."""
        self.u = np.zeros(self.n)
        self.driven = False

    # faults --------------------------------------------------------------
    def stall(self, j: int, t: float) -> None:
        """Joint j (0-based) is stalled from plant time t (s) on: velocity forced to 0."""
        self.stall_from[j] = t

    # time ----------------------------------------------------------------
    def advance(self, dt: float) -> None:
        """Integrate dt seconds in sub-steps of at most max_dt."""
        while dt > 1e-12:
            h = min(dt, self.p.max_dt)
            stalled = self.stall_from <= self.t + h
            self.q, self.v = step(self.q, self.v, self.u, h, self.p, self.lo_stop, self.hi_stop, stalled)
            self.t += h
            dt -= h

    def advance_to(self, t: float) -> None:
        if t > self.t:
            self.advance(t - self.t)

    # sensing -------------------------------------------------------------
    def measure(self) -> np.ndarray:
        """Potentiometer readings (rad): noise, then 12-bit quantisation over the stop-to-stop span."""
        return self.pots.measure(self.q)

    @property
    def quantum(self) -> np.ndarray:
        """ADC step per joint (rad)."""
        return self.pots.quantum
