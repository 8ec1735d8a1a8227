"""The syringe-pump board's calibration (`armbridge calibrate arduino_pump`): from its own sensors only.

Steps: `bend` (the sensor's zero and span: BEND; the curve is measured and reported with
it) and `gains` (GAIN, DBAND). Both need the same three strokes, so every run measures
everything and returns the settings of the steps asked for.

What the board can tell about itself, per joint (all joints at once: the channels are
independent), with the RELAY verb as an open-loop drive (a relay whose hysteresis the
reading cannot cross pushes at a known duty, +-RELAY_AMP per-mille, until the end stop;
the end stops still stop the pump; docs/pump.md "Calibration"):

* zero (`bend`): the bend sensor's straight reading. Physics gives the reference: a joint whose
  syringe is pulled back to its retracted stop is vented (the air at atmospheric
  pressure, below the pressure at which the open joint comes straight) and rests
  straight. The mean ADC count there is angle 0 (done twice, before and after the
  strokes; their mean).
* span (`bend`): the sensor's gain. The second reference is the joint's mechanical full bend:
  pushed to the extended stop the joint is far past the pressure of its full bend and
  rests at its range (the joint limit); the mean ADC count there is the range. The
  two give BEND j adc_a a adc_b b (extrapolated to counts 0 and 1023, so the integer
  arguments lose at most half a mrad). A rig whose joints do not reach a mechanical
  stop at their range needs a jig for this point (docs/pump.md, "The jig step";
  `jig_point`).
* curve (reported with `bend`): the motor's speed (the stroke's time between the end stops) and the bend per
  volume while inflating and deflating: where the closed joint snaps open (the pushed
  volume, mL), the bend it snaps to, the slope of the open branch (mrad per mL) each
  way, and where the deflating joint comes straight. The asymmetry is the difference
  of the two branches.
* `gains`: the proportional gain kp normalised to the measured open-branch rate
  (mrad/s at full duty) against the rig's nominal one (the firmware's default kp was
  set for the nominal rig), clipped to [0.6, 1.5] x KP_DEFAULT; the dead band stays the
  planner's (DBAND_DEFAULT_MRAD): the firmware's settle (6 mrad fine, 20 mrad re-seek,
  inside the band) sets the resting accuracy, and the measured sensor noise at rest is
  reported against the re-seek band (chatter when the noise reaches it).

The board's BEND is changed while measuring (shifted by +-SHIFT_MRAD so the relay can
never switch) and set back to the firmware's default at the end, whatever happens.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from armbridge.calibrate.base import Found, mean_telemetry
from armbridge.errors import ArmbridgeError

STEPS = ("bend", "gains")

RELAY_AMP = 1000         # per-mille: the strokes' duty (full: the dead duty does not matter)
SHIFT_MRAD = 3000        # BEND shift while pushing: the relay's switch is never reached
RATE_HZ = 100            # telemetry while measuring
REST_S = 4.0             # at the retracted stop before the zero is read (a bent joint relaxes: tau <= 0.8 s)
ZERO_WINDOW_S = 2.0      # the zero: the mean over the last seconds of the rest
FULL_REST_S = 2.0        # at the extended stop before the next stroke
FULL_WINDOW_S = 1.5      # the full bend: the mean over the last seconds there
STROKE_LIMIT_S = 18.0    # a stroke that has not reached its stop by then: the joint is stuck
ADC_MAX = 1023
LATCHED = ("ESTOP", "WDOG", "FAULT")
#: the open-branch rate (mrad/s at full duty) this procedure measures on the nominal rig, per joint
#: (`emu:arduino_pump?speed=0`, the rig the firmware's KP_DEFAULT was set for): kp is scaled by
#: nominal / measured, so that a joint that bends faster per duty gets a lower gain
NOMINAL_OPEN_RATE = (349.0, 487.0, 510.0)


@dataclass
class Stroke:
    """One joint's samples of one stroke: board time (s), reading (mrad, default calibration),
    stop bits (retracted, extended)."""

    t: list[float] = field(default_factory=list)
    q: list[float] = field(default_factory=list)
    ret: list[bool] = field(default_factory=list)
    ext: list[bool] = field(default_factory=list)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return np.asarray(self.t), np.asarray(self.q), np.asarray(self.ret, bool), np.asarray(self.ext, bool)


def _bend_default(cfg: Any) -> list[tuple[int, int, int, int]]:
    return [tuple(int(v) for v in b) for b in cfg.BEND_DEFAULT]   # type: ignore[misc]


def _adc(q_mrad: np.ndarray | float, bend: tuple[int, int, int, int]) -> Any:
    """The ADC count a reading (mrad) came from, through the calibration that made it."""
    adc_a, a, adc_b, b = bend
    return adc_a + (np.asarray(q_mrad, float) - a) * (adc_b - adc_a) / (b - a)


def bend_args(adc0: float, adc_full: float, range_mrad: float) -> tuple[int, int, int, int]:
    """BEND's (adc_a, a, adc_b, b) for ADC count adc0 at 0 and adc_full at the range, as the
    line's values at counts 0 and 1023 (integer mrad: at most half a mrad off)."""
    if not adc_full > adc0 + 10:
        raise ArmbridgeError(f"the full bend reads {adc_full:.1f} counts against {adc0:.1f} straight: "
                             "the sensor does not follow the joint")
    per = range_mrad / (adc_full - adc0)
    return 0, int(round(-adc0 * per)), ADC_MAX, int(round((ADC_MAX - adc0) * per))


class _Recorder:
    """Collects telemetry into the current strokes (one per joint)."""

    def __init__(self, n: int, bends: list[tuple[int, int, int, int]]) -> None:
        self.n = n
        self.strokes: list[Stroke] | None = None
        self.shift = 0.0
        self.bends = bends
        self.last_ms = 0

    def __call__(self, t: float, msg: Any) -> None:
        self.last_ms = int(msg.ms)
        if self.strokes is None or len(msg.extra) < self.n + 1:
            return
        stops = int(msg.extra[self.n])
        for j, s in enumerate(self.strokes):
            s.t.append(msg.ms / 1000.0)
            s.q.append(float(msg.q[j]) * 1000.0 - self.shift)
            s.ret.append(bool(stops >> (2 * j) & 1))
            s.ext.append(bool(stops >> (2 * j + 1) & 1))


def _set_bend(client: Any, bends: list[tuple[int, int, int, int]], shift: int) -> None:
    for j, (adc_a, a, adc_b, b) in enumerate(bends, start=1):
        client.command("BEND", j, adc_a, a + shift, adc_b, b + shift)


def _stroke(client: Any, rec: _Recorder, bends, direction: int, after_s: float) -> list[Stroke]:
    """Push (+1) or pull (-1) every syringe at RELAY_AMP to its stop and hold it there
    `after_s` s; the samples of each joint."""
    n = rec.n
    shift = -SHIFT_MRAD if direction > 0 else SHIFT_MRAD
    _set_bend(client, bends, shift)
    rec.shift = float(shift)
    rec.strokes = [Stroke() for _ in range(n)]
    for j in range(1, n + 1):
        client.command("RELAY", j, RELAY_AMP, 0, 1)
    t0 = rec.last_ms / 1000.0

    def done() -> bool:
        strokes = rec.strokes or []
        for s in strokes:
            at = s.ext if direction > 0 else s.ret
            idx = [i for i, v in enumerate(at) if v]
            if not idx or s.t[-1] - s.t[idx[0]] < after_s:
                if s.t and s.t[-1] - t0 > STROKE_LIMIT_S + after_s:
                    return True
                return False
        return True

    client.drain(STROKE_LIMIT_S + after_s + 2.0, until=done)
    strokes = rec.strokes
    rec.strokes = None
    return strokes


def _end(client: Any, bends) -> None:
    """The default BEND back, and the relays ended by CLR (set point = where the joint is) unless
    the board latched meanwhile: a latch has stopped them already, and only its owner releases it."""
    _set_bend(client, bends, 0)
    if client.command("STAT").payload[0] not in LATCHED:
        client.command("CLR")


def _rest_mean(s: Stroke, stop: str, window: float) -> tuple[float, float]:
    """Mean and standard deviation of the reading over the last `window` s at the stop."""
    t, q, ret, ext = s.arrays()
    at = ret if stop == "ret" else ext
    if not at.any():
        raise ArmbridgeError(f"the syringe never reached its {'retracted' if stop == 'ret' else 'extended'} "
                             "stop: a stalled motor or a blocked syringe")
    first = int(np.argmax(at))
    sel = (t >= t[-1] - window) & (np.arange(len(t)) >= first)
    return float(q[sel].mean()), float(q[sel].std())


def _curve(s: Stroke, direction: int, v_mm_s: float, x_start: float, noise: float,
           open_mm: float | None = None) -> dict[str, float]:
    """The bend-per-volume figures of one stroke (readings in mrad of the found calibration;
    plunger positions in mm from the retracted end, 1 mL per mm): pushing, where the closed
    joint opens, the bend it snaps to and the open branch's slope; pulling, the slope, the
    bend still held at the position where the push opened the joint (the hysteresis) and
    where the joint comes straight."""
    t, q, ret, ext = s.arrays()
    leave = ret if direction > 0 else ext
    start = int(np.argmax(~leave)) if leave.any() and (~leave).any() else 0
    x = x_start + direction * v_mm_s * (t - t[start])
    after = np.arange(len(q)) >= start
    out: dict[str, float] = {}
    thresh = max(15.0, 6.0 * noise)
    if direction > 0:
        up = np.nonzero((q > thresh) & after)[0]
        if len(up):
            k = int(up[0])
            out["open_mm"] = float(x[k])
            j = min(len(q) - 1, k + 5)
            out["snap_mrad"] = float(q[j])
            top = q.max()
            lo = np.nonzero((q > q[j] + 0.1 * (top - q[j])) & after)[0]
            hi = np.nonzero((q > 0.9 * top) & after)[0]
            if len(lo) and len(hi) and hi[0] > lo[0] + 2:
                a, b = int(lo[0]), int(hi[0])
                out["inflate_mrad_per_ml"] = float((q[b] - q[a]) / (x[b] - x[a]))
    else:
        qmax = float(q[start:].max()) if len(q) > start else 0.0
        a_idx = np.nonzero((q < 0.8 * qmax) & after)[0]
        b_idx = np.nonzero((q < 0.3 * qmax) & after)[0]
        if len(a_idx) and len(b_idx) and b_idx[0] > a_idx[0] + 2:
            a, b = int(a_idx[0]), int(b_idx[0])
            out["deflate_mrad_per_ml"] = float((q[a] - q[b]) / (x[a] - x[b]))
        if open_mm is not None:
            hold = np.nonzero((x <= open_mm) & after)[0]
            if len(hold):
                out["hysteresis_mrad"] = float(q[int(hold[0])])
        straight = np.nonzero((q < thresh) & after)[0]
        if len(straight):
            out["straight_mm"] = float(max(x[int(straight[0])], 0.0))
    return out


def _stroke_speed(s: Stroke, direction: int, travel_mm: float) -> float | None:
    """mm/s at RELAY_AMP: the travel between the stops (less the switches' gaps) over the time."""
    t, _q, ret, ext = s.arrays()
    leave, reach = (ret, ext) if direction > 0 else (ext, ret)
    if not leave.any() or not reach.any() or not (~leave).any():
        return None
    t_leave = t[int(np.argmax(~leave))]
    t_reach = t[int(np.argmax(reach))]
    if not t_reach > t_leave:
        return None
    return float(travel_mm / (t_reach - t_leave))


def calibrate(client: Any, cfg: Any, only: frozenset[str] = frozenset()) -> Found:
    """Measure the board (see the module docstring); returns the settings BEND, GAIN, DBAND."""
    from armbridge.boards.pump_rig import PumpParams

    steps = set(only or STEPS)
    n = int(cfg.N_JOINTS)
    bends = _bend_default(cfg)
    ranges = [float(hi) for _lo, hi in cfg.LIMITS_MRAD]
    rig = PumpParams()
    travel = rig.travel_mm - 2.0 * rig.switch_mm        # between the two stops' switch points
    rec = _Recorder(n, bends)
    prev_cb = getattr(client, "on_telemetry", None)

    def tap(t: float, msg: Any) -> None:
        rec(t, msg)
        if prev_cb is not None:
            prev_cb(t, msg)

    client.on_telemetry = tap
    prev_rate = getattr(client, "_rate", None)
    found = Found()
    state, _done, queued, _ms = client.stat()
    if state in LATCHED or state == "RUN":
        client.on_telemetry = prev_cb
        raise ArmbridgeError(f"the board is {state}: calibrate it at rest (CLR a latch, let a plan finish)")
    try:
        client.set_rate(RATE_HZ)
        client.drain(0.1)
        vent = _stroke(client, rec, bends, -1, REST_S)          # vented: straight at the retracted stop
        push = _stroke(client, rec, bends, +1, FULL_REST_S)     # to the extended stop: full bend
        pull = _stroke(client, rec, bends, -1, REST_S)          # back: the deflating branch, straight again
    finally:
        rec.strokes = None
        try:
            _end(client, bends)
            if prev_rate is not None:
                client.set_rate(prev_rate)
        finally:
            client.on_telemetry = prev_cb

    values: dict[str, Any] = {"joints": []}
    kp_default = int(getattr(cfg, "KP_DEFAULT", 4000))
    dband = int(getattr(cfg, "DBAND_DEFAULT_MRAD", 70))
    reseek = int(getattr(cfg, "SETTLE_RESEEK_MRAD", 20))
    nan = float("nan")
    for j in range(n):
        z1, sd1 = _rest_mean(vent[j], "ret", ZERO_WINDOW_S)
        z2, sd2 = _rest_mean(pull[j], "ret", ZERO_WINDOW_S)
        full, sdf = _rest_mean(push[j], "ext", FULL_WINDOW_S)
        adc0 = float(_adc((z1 + z2) / 2.0, bends[j]))
        adc_full = float(_adc(full, bends[j]))
        new_bend = bend_args(adc0, adc_full, ranges[j])
        per = ranges[j] / (adc_full - adc0)                 # mrad per count, found
        old_per = (bends[j][3] - bends[j][1]) / (bends[j][2] - bends[j][0])
        noise = float(max(sd1, sd2)) * per / old_per
        v_push = _stroke_speed(push[j], +1, travel)
        v_pull = _stroke_speed(pull[j], -1, travel)

        def recal(s: Stroke) -> Stroke:                     # readings through the found calibration
            q = (_adc(np.asarray(s.q), bends[j]) - adc0) * per
            return Stroke(list(s.t), list(q), list(s.ret), list(s.ext))

        curve: dict[str, float] = {}
        if v_push:
            curve.update(_curve(recal(push[j]), +1, v_push, rig.switch_mm, noise))
        if v_pull:
            curve.update(_curve(recal(pull[j]), -1, v_pull, rig.travel_mm - rig.switch_mm, noise,
                                curve.get("open_mm")))
        rate = float(curve.get("inflate_mrad_per_ml", 0.0) * (v_push or 0.0))
        kp = kp_default
        ref = NOMINAL_OPEN_RATE[j] if j < len(NOMINAL_OPEN_RATE) else 0.0
        if rate > 0 and ref > 0:
            kp = int(round(np.clip(kp_default * ref / rate, 0.6 * kp_default, 1.5 * kp_default)))
        # what the sensor's error was against the default calibration, in mrad
        offset = float((adc0 - bends[j][0]) * old_per - bends[j][1])
        gain = float(old_per / per)
        joint = {"joint": j + 1, "adc_straight": adc0, "adc_full": adc_full, "offset_mrad": offset,
                 "sensor_gain": gain, "noise_mrad": noise, "zero_repeat_mrad": abs(z1 - z2),
                 "motor_mm_s_push": v_push, "motor_mm_s_pull": v_pull, **curve,
                 "open_rate_mrad_s": rate, "kp": kp, "dband_mrad": dband, "bend": list(new_bend)}
        values["joints"].append(joint)
        if "bend" in steps:
            found.settings.append(("BEND", (j + 1, *new_bend)))
            found.lines.append(f"joint {j + 1}: straight at {adc0:.1f} counts (sensor offset {offset:+.1f} mrad), "
                               f"full bend {ranges[j]:.0f} mrad at {adc_full:.1f} (gain {gain:.3f}); "
                               f"BEND {j + 1} {' '.join(map(str, new_bend))}")
        if "bend" in steps:
            found.lines.append(
                f"joint {j + 1}: motor {v_push or nan:.1f} / {v_pull or nan:.1f} mm/s at full duty (push / pull); "
                f"opens at {curve.get('open_mm', nan):.1f} mm of plunger to {curve.get('snap_mrad', nan):.0f} mrad, "
                f"{curve.get('inflate_mrad_per_ml', nan):.1f} mrad/mL inflating, "
                f"{curve.get('deflate_mrad_per_ml', nan):.1f} deflating; deflating it still holds "
                f"{curve.get('hysteresis_mrad', nan):.0f} mrad where it opened, straight at "
                f"{curve.get('straight_mm', nan):.1f} mm")
        if "gains" in steps:
            found.settings.append(("GAIN", (j + 1, kp, 0, 0)))
            found.settings.append(("DBAND", (j + 1, dband)))
            chatter = " (reaches the re-seek band: expect chatter)" if 4.0 * noise >= reseek else ""
            found.lines.append(f"joint {j + 1}: kp {kp} (open-branch rate {rate:.0f} mrad/s at full duty), "
                               f"dead band {dband} mrad; sensor noise {noise:.1f} mrad at rest{chatter}")
    found.values = {"pump": values}
    return found


def jig_point(client: Any, j: int, angle_mrad: int, seconds: float = 2.0) -> float:
    """The jig step (docs/pump.md): with joint j held by a jig at `angle_mrad` (a protractor
    block), the mean ADC count its sensor reads there, through the board's current BEND
    (assumed the firmware's default: call it before BEND is changed). Two such points
    give BEND j without the full-bend reference."""
    return float(mean_telemetry(client, seconds)[j - 1]) * 1000.0
