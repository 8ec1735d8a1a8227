"""Servo plant of the 3R arm: n hobby servos driven by effort, read by potentiometers.

The numbers are ours, for a 35 kg*cm hobby servo (DS3235 class) on the arm's
links; they are documented in `PlantParams` and docs/emulator.md.

Model per joint, with effort u in [-1, 1] (the firmware's PWM duty, signed):

    v_cmd = u * v_servo                      commanded speed
    dv/dt = (v_cmd - v) / tau                first-order velocity lag ...
    |dv/dt| <= a_max                         ... with an acceleration limit
    dq/dt = v                                position, stopped by hard stops
    y = quantise(q + N(0, sigma))            potentiometer through a 12-bit ADC

The hidden truth (`plant=random`, truth.py) adds, per joint: a speed spread
(v_servo, a_max), an effort dead band (static friction: |u| <= deadband moves
nothing, beyond it the speed rises from 0 to v_servo at |u| = 1), gear
backlash (the joint follows the motor within +-backlash/2; the pot reads the
joint), and a pot mounted off and scaled (the firmware reads
mid + pot_gain * (q - mid) + zero_offset, mid the middle of the joint's range),
its own noise. Their defaults are neutral: the nominal plant is the model above.

`step` is the pure step function (numpy in, numpy out); `ServoPlant` holds the
state, the fault schedule and the seeded measurement noise. `Pots` (the
potentiometers and the ADC) is shared with the positional rig's plant
(servo_plant.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Union

import numpy as np

from armbridge.boards import joint_limits_rad
from armbridge.emulator.truth import Spread, draw

#: a number shared by all joints, or one per joint (what a per-joint spread draws)
PerJoint = Union[float, tuple[float, ...]]


@dataclass(frozen=True)
class PlantParams:
    """Physical numbers of the servo joints: one value for all, or (the PerJoint
    ones) a tuple of one per joint, as the hidden truth draws them.

    v_servo     5.0 rad/s   speed at full effort under the arm's load (about 0.21 s/60 deg)
    tau         0.030 s     velocity lag time constant (motor + gearbox + servo electronics)
    a_max       60 rad/s^2  acceleration limit (stall torque over the reflected inertia)
    stop_margin 0.05 rad    hard stops sit this far beyond the firmware's joint limits
    sigma       0.001 rad   gaussian noise of the potentiometer reading (1 mrad)
    adc_bits    12          ADC resolution; the code range spans hard stop to hard stop
    max_dt      0.001 s     longest integration sub-step
    hidden truth, neutral by default (see SPREADS):
    deadband    0           effort dead band (static friction), in effort units
    backlash    0 rad       gear play between the motor and the joint (total)
    zero_offset 0 rad       the pot reads the joint this far off
    pot_gain    1           the pot's scale about the middle of the joint's range
    pen_contact_us 1550 us  the pen-lift servo's pulse at which the tip meets the paper
                            (PEN_CONTACT_US; the pen is the HAL's, simhal.py)
    """

    v_servo: PerJoint = 5.0
    tau: float = 0.030
    a_max: PerJoint = 60.0
    stop_margin: float = 0.05
    sigma: PerJoint = 0.001
    adc_bits: int = 12
    max_dt: float = 0.001
    deadband: PerJoint = 0.0
    backlash: PerJoint = 0.0
    zero_offset: PerJoint = 0.0
    pot_gain: PerJoint = 1.0
    pen_contact_us: float = 1550.0


#: the default rig's pen contact width (us): between the default config's PEN_UP_US (1200) and
#: PEN_DOWN_US (1700), nearer down (the lift clears the paper)
PEN_CONTACT_US = PlantParams.pen_contact_us
#: how far a drawn rig's contact width strays (truth.py): both SPREADS use it
PEN_CONTACT_SPREAD = Spread(
    "pen_contact_us", "normal", 40.0, lo=1450.0, hi=1650.0, unit="us",
    source="where the pen tip meets the paper: the pen's length in its holder and the paper's height, against "
           "the lift's 0.09 deg/us (SG90 class, 180 deg over 2000 us: about 0.3 mm a 10 us step on a 20 mm horn); "
           "+-40 us, our estimate, bounded so that the default widths (up 1200, down 1700) still lift and draw")


#: the typical board the spreads are about: the neutral fields at their typical values
TYPICAL = PlantParams(deadband=0.015, backlash=0.009)

#: how a real board's effort rig differs from the nominal model (truth.py); sources in each
SPREADS: tuple[Spread, ...] = (
    Spread("zero_offset", "uniform", 0.1257, per_joint=True, lo=-0.1257, hi=0.1257, unit="rad",
           source="pot / horn on a 25T spline: 14.4 deg a tooth, so up to +-7.2 deg (0.126 rad) off before trim"),
    Spread("pot_gain", "scale", 0.02, per_joint=True, lo=0.94, hi=1.06,
           source="ESP32 ADC gain error after eFuse Vref calibration (about +-2 %, Espressif ADC docs) "
                  "plus the pot's linearity (+-1..3 %, conductive plastic); bounded at +-6 % (uncalibrated Vref)"),
    Spread("v_servo", "scale", 0.07, per_joint=True, lo=3.5, hi=6.5, unit="rad/s",
           source="DS3235 speed 0.13 s/60 deg (5 V) to 0.11 (6.8 V) is +-8 % over supply; unit-to-unit "
                  "and joint friction add as much: sigma 7 %"),
    Spread("a_max", "scale", 0.10, per_joint=True, lo=40.0, hi=80.0, unit="rad/s^2",
           source="stall torque 35 kg*cm +-10 % (DS3235 data sheet, over supply) over the link's inertia"),
    Spread("deadband", "uniform", 0.01, per_joint=True, lo=0.004, hi=0.03,
           source="about 0.015 of full effort: the servo's 3 us dead band (of 500 us to full effort, 0.006) "
                  "plus the gear train's static friction (our estimate)"),
    Spread("backlash", "uniform", 0.006, per_joint=True, lo=0.002, hi=0.017, unit="rad",
           source="about 0.5 deg (9 mrad) total play: metal-gear hobby servos, 0.3..1 deg (measured by "
                  "hobbyists; the DS3235 data sheet gives none)"),
    Spread("sigma", "scale", 0.3, per_joint=True, lo=0.0005, hi=0.003, unit="rad",
           source="pot wiper noise and ESP32 ADC noise (a few LSB rms uncalibrated): 1 mrad +-30 %"),
    PEN_CONTACT_SPREAD,
)


def hidden_truth(cfg: Any, rng: np.random.Generator) -> PlantParams:
    """The effort rig's parameters drawn from SPREADS (about TYPICAL), one per joint of `cfg`'s limits."""
    lo, _ = joint_limits_rad(cfg)
    return draw(TYPICAL, SPREADS, rng, int(lo.size))


def _neutral(x: PerJoint, value: float) -> bool:
    return bool(np.all(np.asarray(x, dtype=float) == value))


def shape_effort(u: np.ndarray, deadband) -> np.ndarray:
    """The effort the motor sees through a dead band: 0 within +-deadband, then
    rising to +-1 at |u| = 1. Pure; deadband 0 returns u."""
    db = np.asarray(deadband, dtype=float)
    return np.sign(u) * np.maximum(np.abs(u) - db, 0.0) / (1.0 - db)


def play(q: np.ndarray, m: np.ndarray, half: np.ndarray, lo_stop: np.ndarray, hi_stop: np.ndarray) -> np.ndarray:
    """Backlash: the joint at q is pushed by the motor side at m only where it
    is more than `half` away; the joint stops at the hard stops. Pure."""
    return np.clip(np.clip(q, m - half, m + half), lo_stop, hi_stop)


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
    if not _neutral(p.deadband, 0.0):
        u = shape_effort(u, p.deadband)
    v_cmd = u * np.asarray(p.v_servo, dtype=float)
    dv = (v_cmd - v) * (1.0 - math.exp(-dt / p.tau))
    lim = np.asarray(p.a_max, dtype=float) * dt
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
    (rad, one per joint), so a reading never leaves the span. sigma: one for all
    joints or one per joint. rng: the seeded noise source (numpy Generator),
    owned by the plant."""

    def __init__(self, lo_stop: np.ndarray, hi_stop: np.ndarray, sigma: PerJoint, bits: int,
                 rng: np.random.Generator) -> None:
        self.lo_stop = np.asarray(lo_stop, dtype=float)
        self.span = np.asarray(hi_stop, dtype=float) - self.lo_stop
        self.sigma: Any = float(sigma) if isinstance(sigma, (int, float)) else np.asarray(sigma, dtype=float)
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
    beyond them. q0: initial positions (default: mid-range). With backlash, `m`
    is the motor side (in joint radians) and `q` the joint the pot reads.
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
        self.half_play = 0.5 * np.broadcast_to(np.asarray(self.p.backlash, dtype=float), (self.n,))
        self.m = self.q.copy()
        self._backlash = bool(np.any(self.half_play))
        self._pot = None if _neutral(self.p.zero_offset, 0.0) and _neutral(self.p.pot_gain, 1.0) else (
            0.5 * (self.lo + self.hi), np.asarray(self.p.pot_gain, float), np.asarray(self.p.zero_offset, float))

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
            if self._backlash:
                hp = self.half_play
                self.m, self.v = step(self.m, self.v, self.u, h, self.p, self.lo_stop - hp, self.hi_stop + hp,
                                      stalled)
                self.q = play(self.q, self.m, hp, self.lo_stop, self.hi_stop)
            else:
                self.q, self.v = step(self.q, self.v, self.u, h, self.p, self.lo_stop, self.hi_stop, stalled)
            self.t += h
            dt -= h

    def advance_to(self, t: float) -> None:
        if t > self.t:
            self.advance(t - self.t)

    # sensing -------------------------------------------------------------
    def measure(self) -> np.ndarray:
        """Potentiometer readings (rad): the pot's reading of the joint (zero
        offset, gain), noise, then 12-bit quantisation over the stop-to-stop span."""
        return self.pots.measure(self.pot_reading(self.q))

    def pot_reading(self, q: np.ndarray) -> np.ndarray:
        """What the pots read (rad, before noise and the ADC) at joint angles q:
        mid + pot_gain * (q - mid) + zero_offset; q itself on the nominal plant."""
        if self._pot is None:
            return q
        mid, gain, off = self._pot
        return mid + gain * (np.asarray(q, dtype=float) - mid) + off

    @property
    def quantum(self) -> np.ndarray:
        """ADC step per joint (rad)."""
        return self.pots.quantum
