"""Plant of the positional rig: hobby servos that go where their pulse says.

The numbers are ours, for a 35 kg*cm 270 deg servo (DS3235 class) on the arm's
links and a 9 g 180 deg servo (SG90 class) lifting the pen; they are
documented in `ServoParams` and docs/emulator.md.

Model per servo, with pulse width w (us) sampled at the start of each PWM
period (`PositionalPlant.set_pulses(w, t)`):

    target = map(clip(w, pulse_min, pulse_max))   the servo's own linear pulse->angle map
    e = target - q
    dq = e * (1 - exp(-dt / tau))                 first-order lag of its position loop ...
    |dq| <= w_max * dt                            ... rate-limited (the motor's top speed)
    dq = 0 where |e| <= deadband                  the dead band: no move for small errors
    q stops at the hard stops                     the arm's (stop_margin beyond its limits)
    y = quantise(q + N(0, sigma))                 feedback pot through a 12-bit ADC (plant.Pots)

The hidden truth (`plant=random`, truth.py) adds, per joint: the pulse
widths at the ends of travel (pulse_min, pulse_max: the servo's map stretched
between them), its dead band, speed and lag, the horn mounted off by
horn_offset (the joint sits that far from the servo's angle), gear backlash
(the joint follows the servo's shaft within +-backlash/2) and the feedback pot
mounted off and scaled (it reads mid + pot_gain * (q - mid) + zero_offset), its
own noise. Their defaults are neutral: the nominal plant is the model above.

No pulse (PCA9685 full off, asleep) or one outside valid_us: the servo is
limp and stays where it is (a hobby servo's gear train does not backdrive on a
horizontal arm). The pen servo is a channel too: its angle past the midpoint
of its up and down angles is pen down.

`step` is the pure step function (numpy in, numpy out); `PositionalPlant`
holds the state, the pulses, the stall faults and the seeded noise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from armbridge.boards import joint_limits_rad
from armbridge.emulator.plant import PEN_CONTACT_SPREAD, PEN_CONTACT_US, PerJoint, Pots, play
from armbridge.emulator.truth import Spread, draw

#: the pulse widths of a nominal servo's ends of travel (us): SERVO_CAL's frame
NOMINAL_ENDS = (500.0, 2500.0)


@dataclass(frozen=True)
class ServoParams:
    """One positional servo's numbers (defaults: DS3235 class on the arm); the
    PerJoint ones may be a tuple of one per joint, as the hidden truth draws them.

    w_max        7.0 rad/s   top speed under the arm's load (data sheet, no load:
                             0.13 s/60 deg at 5 V = 8.1 rad/s, 0.11 s at 6.8 V = 9.5)
    tau          0.040 s     lag of the servo's own position loop on small errors
    deadband_us  3.0 us      data sheet dead band: it holds while its position is
                             within 3 us of the pulse's angle (7 mrad over 270 deg)
    pulse_min    500 us      travel ends: pulses beyond them go no further
    pulse_max    2500 us
    valid_min    400 us      pulses outside valid_min..valid_max are not a servo
    valid_max    2700 us     signal: the servo goes limp
    stop_margin  0.05 rad    the arm's hard stops this far beyond the firmware limits
    sigma        0.001 rad   gaussian noise of the feedback pot
    adc_bits     12          ADC codes over the stop-to-stop span
    max_dt       0.001 s     longest integration sub-step
    hidden truth, neutral by default (see SPREADS):
    horn_offset  0 rad       the horn sits this far off the servo's angle
    backlash     0 rad       gear play between the servo's shaft and the joint (total)
    zero_offset  0 rad       the feedback pot reads the joint this far off
    pot_gain     1           the feedback pot's scale about the middle of the joint's range
    pen_contact_us 1550 us   the rig's pen servo: the pulse at which its tip meets the paper
    """

    w_max: PerJoint = 7.0
    tau: PerJoint = 0.040
    deadband_us: PerJoint = 3.0
    pulse_min: PerJoint = 500.0
    pulse_max: PerJoint = 2500.0
    valid_min: float = 400.0
    valid_max: float = 2700.0
    stop_margin: float = 0.05
    sigma: PerJoint = 0.001
    adc_bits: int = 12
    max_dt: float = 0.001
    horn_offset: PerJoint = 0.0
    backlash: PerJoint = 0.0
    zero_offset: PerJoint = 0.0
    pot_gain: PerJoint = 1.0
    pen_contact_us: float = PEN_CONTACT_US


# The pen-lift servo: 9 g, 180 deg over 500..2500 us (SG90 class), 0.1 s/60 deg.
PEN_PARAMS = ServoParams(w_max=10.0, tau=0.020, deadband_us=10.0)

#: the typical servo the spreads are about: the neutral fields at their typical values
TYPICAL = ServoParams(backlash=0.009)

#: how a real rig's servos differ from the nominal model (truth.py); sources in each
SPREADS: tuple[Spread, ...] = (
    Spread("horn_offset", "uniform", 0.1257, per_joint=True, lo=-0.1257, hi=0.1257, unit="rad",
           source="horn on the DS3235's 25T spline: 14.4 deg a tooth, so up to +-7.2 deg (0.126 rad) off "
                  "before trim (CAL)"),
    Spread("pulse_min", "uniform", 30.0, per_joint=True, lo=470.0, hi=530.0, unit="us",
           source="end of travel at 500 us nominal (DS3235: 500..2500 us); unit to unit +-30 us "
                  "(hobby servo end points, measured by hobbyists)"),
    Spread("pulse_max", "uniform", 30.0, per_joint=True, lo=2470.0, hi=2530.0, unit="us",
           source="end of travel at 2500 us nominal, +-30 us as pulse_min"),
    Spread("deadband_us", "uniform", 1.0, per_joint=True, lo=2.0, hi=4.0, unit="us",
           source="dead band 3 us (DS3235 data sheet); digital hobby servos 2..4 us"),
    Spread("w_max", "scale", 0.07, per_joint=True, lo=5.0, hi=9.0, unit="rad/s",
           source="DS3235 0.13 s/60 deg (5 V) to 0.11 (6.8 V), +-8 % over supply; unit to unit and "
                  "joint friction as much: sigma 7 %"),
    Spread("tau", "scale", 0.15, per_joint=True, lo=0.025, hi=0.06, unit="s",
           source="the servo's own position loop (gains in its firmware, load): +-15 %, our estimate"),
    Spread("backlash", "uniform", 0.006, per_joint=True, lo=0.002, hi=0.017, unit="rad",
           source="about 0.5 deg (9 mrad) total play: metal-gear hobby servos, 0.3..1 deg (measured by "
                  "hobbyists; the DS3235 data sheet gives none)"),
    Spread("zero_offset", "uniform", 0.1257, per_joint=True, lo=-0.1257, hi=0.1257, unit="rad",
           source="feedback pot on a 25T spline: 14.4 deg a tooth, up to +-7.2 deg off"),
    Spread("pot_gain", "scale", 0.02, per_joint=True, lo=0.94, hi=1.06,
           source="ESP32 ADC gain error after eFuse Vref calibration (about +-2 %) plus the pot's "
                  "linearity (+-1..3 %); bounded at +-6 % (uncalibrated Vref)"),
    Spread("sigma", "scale", 0.3, per_joint=True, lo=0.0005, hi=0.003, unit="rad",
           source="pot wiper noise and ESP32 ADC noise (a few LSB rms uncalibrated): 1 mrad +-30 %"),
    PEN_CONTACT_SPREAD,
)


def hidden_truth(cfg: Any, rng: np.random.Generator) -> ServoParams:
    """The pca9685 rig's servo parameters drawn from SPREADS (about TYPICAL), one per joint of
    `cfg`'s limits (the pen servo keeps PEN_PARAMS)."""
    lo, _ = joint_limits_rad(cfg)
    return draw(TYPICAL, SPREADS, rng, int(lo.size))


def _at(x: PerJoint, k: int) -> float:
    """Servo k's value of a PerJoint field."""
    return float(x[k]) if isinstance(x, tuple) else float(x)


def step(q: np.ndarray, target: np.ndarray, driven: np.ndarray, dt: float, tau: np.ndarray,
         w_max: np.ndarray, deadband: np.ndarray, lo_stop: np.ndarray, hi_stop: np.ndarray,
         stalled: np.ndarray | None = None) -> np.ndarray:
    """One step of length dt (s) of servos at q (rad) toward target (rad); returns
    the new q. Pure. driven: bool mask of servos that get a valid pulse (the
    others are limp: no move); stalled: bool mask of seized servos."""
    e = np.where(driven, target - q, 0.0)
    move = np.clip(e * -np.expm1(-dt / tau), -w_max * dt, w_max * dt)
    move = np.where(np.abs(e) > deadband, move, 0.0)
    if stalled is not None:
        move = np.where(stalled, 0.0, move)
    return np.clip(q + move, lo_stop, hi_stop)


@dataclass(frozen=True)
class PenServo:
    """The pen-lift servo: its pulse->angle map (us_a at rad_a, us_b at rad_b),
    the config's pulses for pen up and down (the side of down is the paper's),
    the pulse at which its tip meets the paper (contact_us; None: midway between
    up and down), its numbers. The pen is down when the servo's angle has
    reached the contact's, whatever the firmware thinks it sent."""

    up_us: float
    down_us: float
    contact_us: float | None = None
    mapping: tuple[float, float, float, float] = (500.0, 0.0, 2500.0, math.pi)
    params: ServoParams = PEN_PARAMS


def _angle(mapping, us):
    us_a, rad_a, us_b, rad_b = mapping
    return rad_a + (np.asarray(us, float) - us_a) * (rad_b - rad_a) / (us_b - us_a)


class PositionalPlant:
    """n joint servos (and optionally the pen servo, index n) with state, time,
    pulses, stall faults and seeded pot noise.

    lo, hi: the firmware's joint limits (rad); the hard stops are `stop_margin`
    beyond them. mapping: per joint the servo's own (us_a, rad_a, us_b, rad_b)
    pulse->angle line (how the horn sits on the joint; the firmware's SERVO_CAL
    is its estimate). q0: initial positions (default mid-range); the pen starts up.
    """

    def __init__(self, lo, hi, mapping, params: ServoParams | None = None, q0=None, seed: int = 0,
                 pen: PenServo | None = None) -> None:
        self.p = params or ServoParams()
        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
        if lo.shape != hi.shape or lo.ndim != 1 or len(mapping) != lo.size:
            raise ValueError("lo, hi and mapping need one entry per joint")
        self.n = int(lo.size)
        self.lo_stop = lo - self.p.stop_margin
        self.hi_stop = hi + self.p.stop_margin
        self.mappings = [tuple(float(x) for x in m) for m in mapping]
        self.pen = pen
        servos: list[tuple[tuple[float, ...], ServoParams]] = [(m, self.p) for m in self.mappings]
        if pen is not None:
            servos.append((pen.mapping, pen.params))
        self._p = [sp for _, sp in servos]
        self._map = [m for m, _ in servos]
        self.tau = np.array([_at(sp.tau, k) for k, sp in enumerate(self._p)])
        self.w_max = np.array([_at(sp.w_max, k) for k, sp in enumerate(self._p)])
        self.deadband = np.array([_at(sp.deadband_us, k) * abs((m[3] - m[1]) / (m[2] - m[0]))
                                  for k, (m, sp) in enumerate(servos)])
        self._ends = [(_at(sp.pulse_min, k), _at(sp.pulse_max, k)) for k, sp in enumerate(self._p)]
        self._horn = np.array([_at(sp.horn_offset, k) for k, sp in enumerate(self._p)])
        self.half_play = 0.5 * np.array([_at(sp.backlash, k) for k, sp in enumerate(self._p)])
        self._backlash = bool(np.any(self.half_play))
        lo_all, hi_all = list(self.lo_stop), list(self.hi_stop)
        if pen is not None:
            ends = _angle(pen.mapping, [_at(pen.params.pulse_min, 0), _at(pen.params.pulse_max, 0)])
            lo_all.append(float(ends.min()))
            hi_all.append(float(ends.max()))
            contact = 0.5 * (pen.up_us + pen.down_us) if pen.contact_us is None else pen.contact_us
            self.pen_threshold = float(_angle(pen.mapping, contact))
            self._pen_sign = 1.0 if _angle(pen.mapping, pen.down_us) > _angle(pen.mapping, pen.up_us) else -1.0
        self._lo, self._hi = np.array(lo_all), np.array(hi_all)
        m = len(servos)
        self._q = np.empty(m)
        self._q[:self.n] = 0.5 * (lo + hi) if q0 is None else np.clip(np.asarray(q0, float), self.lo_stop, self.hi_stop)
        if pen is not None:
            self._q[self.n] = float(_angle(pen.mapping, pen.up_us))
        self._jq = self._q.copy()     # the joints (with backlash; otherwise _q, the servos' shafts, is)
        self.target = np.full(m, np.nan)
        self.driven = np.zeros(m, dtype=bool)
        self._pending: tuple[float, np.ndarray] | None = None
        self.t = 0.0
        self.stall_from = np.full(m, np.inf)
        self.pots = Pots(self.lo_stop, self.hi_stop, self.p.sigma, self.p.adc_bits, np.random.default_rng(seed))
        lo_j, hi_j = np.asarray(lo, float), np.asarray(hi, float)
        neutral_pot = np.all(np.asarray(self.p.zero_offset) == 0.0) and np.all(np.asarray(self.p.pot_gain) == 1.0)
        self._pot = None if neutral_pot else (
            0.5 * (lo_j + hi_j), np.asarray(self.p.pot_gain, float), np.asarray(self.p.zero_offset, float))
        self.pen_changes: list[tuple[float, bool]] = []   # (t, down) when the pen crossed over
        self.cfg: Any = None     # the firmware config the rig was built from (pcahal.rig_plant)

    # state ---------------------------------------------------------------
    @property
    def _joint(self) -> np.ndarray:
        return self._jq if self._backlash else self._q

    @property
    def q(self) -> np.ndarray:
        """Joint angles (rad), a view."""
        return self._joint[:self.n]

    @property
    def shaft(self) -> np.ndarray:
        """The servos' output shafts (rad, in joint angles; the joints but for backlash), a view."""
        return self._q[:self.n]

    @property
    def pen_q(self) -> float | None:
        return float(self._joint[self.n]) if self.pen is not None else None

    @property
    def pen_down(self) -> bool | None:
        """True when the pen is down (None: no pen servo)."""
        if self.pen is None:
            return None
        return bool((self._joint[self.n] - self.pen_threshold) * self._pen_sign >= 0)

    # drive ---------------------------------------------------------------
    def targets_for(self, pulses_us) -> tuple[np.ndarray, np.ndarray]:
        """(target angles, driven mask) of pulse widths (us; NaN: no pulse), one per servo."""
        w = np.asarray(pulses_us, dtype=float)
        if w.shape != self._q.shape:
            raise ValueError(f"expected {self._q.size} pulses, got {w.shape}")
        valid = np.isfinite(w)
        target = np.full(w.shape, np.nan)
        for i in np.flatnonzero(valid):
            sp = self._p[i]
            if not sp.valid_min <= w[i] <= sp.valid_max:
                valid[i] = False
                continue
            lo, hi = self._ends[i]
            x = min(max(w[i], lo), hi)
            if (lo, hi) != NOMINAL_ENDS:   # the servo's travel stretched between its own end points
                x = NOMINAL_ENDS[0] + (x - lo) * (NOMINAL_ENDS[1] - NOMINAL_ENDS[0]) / (hi - lo)
            target[i] = _angle(self._map[i], x) + self._horn[i]
        return target, valid

    def set_pulses(self, pulses_us, t: float) -> None:
        """The pulse widths the servos see from time t on (a PWM period's start;
        NaN: none). Integrate up to now before calling: a later call for the same
        t replaces an earlier one."""
        self._pending = (float(t), np.asarray(pulses_us, dtype=float).copy())
        if t <= self.t:
            self._apply()

    def _apply(self) -> None:
        assert self._pending is not None
        self.target, self.driven = self.targets_for(self._pending[1])
        self._pending = None

    def off(self) -> None:
        """Every servo limp now."""
        self._pending = None
        self.driven = np.zeros_like(self.driven)
        self.target = np.full(self._q.shape, np.nan)

    # faults --------------------------------------------------------------
    def stall(self, j: int, t: float) -> None:
        """Joint j (0-based) is seized from plant time t (s) on."""
        self.stall_from[j] = t

    # time ----------------------------------------------------------------
    def advance(self, dt: float) -> None:
        """Integrate dt seconds in sub-steps of at most max_dt, split where the pulses change."""
        end = self.t + dt
        while end - self.t > 1e-12:
            if self._pending is not None and self._pending[0] <= self.t + 1e-12:
                self._apply()
            h = min(end - self.t, self.p.max_dt)
            if self._pending is not None and self._pending[0] < self.t + h:
                h = self._pending[0] - self.t
            stalled = self.stall_from <= self.t + h
            was = self.pen_down
            if self._backlash:
                hp = self.half_play
                self._q = step(self._q, self.target, self.driven, h, self.tau, self.w_max, self.deadband,
                               self._lo - hp, self._hi + hp, stalled)
                self._jq = play(self._jq, self._q, hp, self._lo, self._hi)
            else:
                self._q = step(self._q, self.target, self.driven, h, self.tau, self.w_max, self.deadband,
                               self._lo, self._hi, stalled)
            self.t += h
            if self.pen is not None and self.pen_down != was:
                self.pen_changes.append((self.t, bool(self.pen_down)))
        if self._pending is not None and self._pending[0] <= self.t + 1e-12:
            self._apply()

    def advance_to(self, t: float) -> None:
        if t > self.t:
            self.advance(t - self.t)

    # sensing -------------------------------------------------------------
    def measure(self) -> np.ndarray:
        """Feedback pot readings of the joints (rad): the pot's reading (zero offset,
        gain), noise, then 12-bit quantisation."""
        return self.pots.measure(self.pot_reading(self.q))

    def pot_reading(self, q: np.ndarray) -> np.ndarray:
        """What the feedback pots read (rad, before noise and the ADC) at joint
        angles q: mid + pot_gain * (q - mid) + zero_offset; q itself on the nominal plant."""
        if self._pot is None:
            return q
        mid, gain, off = self._pot
        return mid + gain * (np.asarray(q, dtype=float) - mid) + off

    @property
    def quantum(self) -> np.ndarray:
        return self.pots.quantum
