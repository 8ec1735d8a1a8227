"""`armbridge calibrate esp32`: the 3R drawing arm's procedure (docs/drawing.md "Calibration").

Steps (STEPS; `only` picks some, none = all that the rig has):

* "gains" (effort rig): relay auto-tune of each joint's loop (RELAY, the
  board runs the relay in its control tick: firmware/esp32/arm_cal.py), its
  limit cycle's period Tu and amplitude a -> Ku (tuning.ultimate) -> PID gains
  by RULE (tuning.pid_gains) -> GAIN. The pca9685 rig's servos close their
  own loops: no gains there.
* "jig": where the joints really are, from the printed marks (jig.py): at
  each mark the host records what the board reads (effort rig: the pots'
  telemetry, with the pots' CAL put back to the identity first; pca9685 rig:
  the pulse it sends for the set point, with SERVO_CAL put back to the
  config's first) and the mark's true joint angles, and fits per joint
  reading = c0 + g q (g only where the marks spread the joint by MIN_SPREAD,
  else 1). It sets effort rig: the pots' CAL (arm_cal.py's reuse of the
  verb: "pulse" 1000/2000 stand for the readings mid -+ 500 mrad); pca9685
  rig: the servo's CAL at 1000 and 2000 us, and its hysteresis (DBAND: each
  mark is placed coming from below and from above, the line fitted to the
  middle; the width is the pulses' gap between the two sides corrected by
  where the feedback pots saw the joint rest, finer than a PWM count). Needs
  a jig (`jig=`: jig.make_jig): without one the step is skipped and says so.

`calibrate(client, cfg, only, jig=None, rule=RULE)` measures and returns the
settings (Found); it sends settings only where measuring needs them (RATE
50 for its readings; before the jig the rig's default CALs, and the gains
just found, so the marks are read against known settings), so the shared
flow (base.py) sends the Found's settings, then CALID. The rig is asked of
the board (probe_rig): an emulated rig (servos=) runs the same config.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from armbridge.calibrate.base import Found, mean_telemetry
from armbridge.calibrate.jig import MARKS, Jogger, ik
from armbridge.calibrate.tuning import pid_gains, ultimate
from armbridge.errors import BoardFailure

STEPS = ("gains", "jig")

#: the rule the gains step uses: of tuning.RULES the one that drew best on drawn boards
#: (bench arm3r-servo --rule; docs/drawing.md "Calibration")
RULE = "pd"
#: relay test: effort (per mille), hysteresis (mrad), counted cycles
RELAY = (150, 4, 6)
#: a joint's marks must spread it this far (rad) for its gain to be fitted
MIN_SPREAD = 0.6
LEAD_MAX_MRAD = 100          # DBAND on the servo rig (firmware/esp32/arm_cal.py): the widest it takes
RELAY_TIMEOUT_S = 30.0


def rig_of(cfg: Any) -> str:
    """The rig the config was built for (an emulated rig, servos=, swaps the HAL only: probe_rig asks)."""
    return "pca9685" if getattr(cfg, "SERVOS", "effort") == "pca9685" else "effort"


def probe_rig(client: Any, cfg: Any) -> str:
    """Which rig the board drives, asked without moving it: a waypoint to where it is, then
    RELAY while that is queued: the effort rig refuses it RANGE (motion queued), the pca9685
    rig, whose servos close their own loops, has no RELAY (VERB)."""
    from armbridge.link import protocol as P

    here = readings(client, 0.1, "target")     # where it holds: the waypoint moves nothing
    arm = Jogger(client, here)
    wid = arm.next_id()
    client.command("W", wid, 1000, *P.to_milli(here))
    ans = client.ask("RELAY", 1, 1, 0, 1)
    arm.wait(wid, 1.0)
    if isinstance(ans, P.Er) and ans.code == P.VERB:
        return "pca9685"
    if not isinstance(ans, P.Er):       # the waypoint was done first: the relay runs; a waypoint ends it
        wid = arm.next_id()
        client.command("W", wid, 200, *P.to_milli(here))
        arm.wait(wid, 0.2)
    return "effort"


def calibrate(client: Any, cfg: Any, only: frozenset[str] = frozenset(), *, jig: Any = None,
              rule: str = RULE, marks=MARKS) -> Found:
    client.set_rate(50)
    rig = probe_rig(client, cfg)
    want = set(only) if only else set(STEPS)
    found = Found()
    if "gains" in want:
        if rig == "effort":
            found = found.merge(gains_step(client, cfg, rule))
        elif only:
            found.lines.append("gains: the pca9685 rig's servos close their own loops; nothing to tune")
    if "jig" in want:
        if jig is None:
            found.lines.append("jig: skipped (no jig: --jig terminal at the arm, --jig emu on an emulated board)")
        else:
            found = found.merge(jig_step(client, cfg, jig, marks, gains=found.settings, rig=rig))
    return found


# ---------------------------------------------------------------- gains
def relay_test(client: Any, j: int, amp: int, hyst: int, cycles: int,
               timeout_s: float = RELAY_TIMEOUT_S) -> tuple[int, int]:
    """RELAY on joint j (1-based) -> (period_ms, amp_mrad) from its event ((0, 0): gave up)."""
    got: list[tuple[int, int]] = []
    prev = client.on_event

    def on_event(t, ev):
        if ev.kind == "RELAY" and len(ev.args) >= 3 and int(ev.args[0]) == j:
            got.append((int(ev.args[1]), int(ev.args[2])))
        if prev is not None:
            prev(t, ev)
    client.on_event = on_event
    try:
        client.command("RELAY", j, amp, hyst, cycles)
        client.drain(timeout_s, until=lambda: bool(got))
    finally:
        client.on_event = prev
    if not got:
        raise BoardFailure(f"joint {j}: the board sent no RELAY event in {timeout_s:g} s")
    return got[0]


def gains_of(period_ms: int, amp_mrad: int, amp: int, hyst: int, rule: str) -> tuple[float, float, float, float, float]:
    """(Ku, Tu s, kp, ki, kd) of a relay result in the board's units (effort per rad)."""
    ku = ultimate(amp / 1000.0, amp_mrad / 1000.0, hyst / 1000.0)
    tu = period_ms / 1000.0
    kp, ki, kd = pid_gains(ku, tu, rule)
    return ku, tu, kp, ki, kd


def _milli(x: float) -> int:
    return int(min(1_000_000, max(0, round(x * 1000))))


def gains_step(client: Any, cfg: Any, rule: str = RULE, relay=RELAY) -> Found:
    amp, hyst, cycles = relay
    f = Found()
    per: dict[str, Any] = {}
    for j in range(1, int(cfg.N_JOINTS) + 1):
        period, a = relay_test(client, j, amp, hyst, cycles)
        if period == 0 or a <= hyst:
            f.lines.append(f"joint {j}: the relay gave no limit cycle; its gains stay")
            per[str(j)] = {"period_ms": period, "amp_mrad": a}
            continue
        ku, tu, kp, ki, kd = gains_of(period, a, amp, hyst, rule)
        g = (_milli(kp), _milli(ki), _milli(kd))
        f.settings.append(("GAIN", (j, *g)))
        per[str(j)] = {"period_ms": period, "amp_mrad": a, "ku": round(ku, 3), "tu_s": round(tu, 4),
                       "kp": g[0] / 1000, "ki": g[1] / 1000, "kd": g[2] / 1000}
        f.lines.append(f"joint {j}: relay +-{amp / 10:g} % -> period {period} ms, amplitude {a} mrad: "
                       f"Ku {ku:.2f}/rad, Tu {tu * 1000:.0f} ms; {rule}: kp {kp:.2f} ki {ki:.2f} kd {kd:.3f}")
    f.values["gains"] = {"rule": rule, "relay": {"amp_permille": amp, "hyst_mrad": hyst, "cycles": cycles},
                         "joints": per}
    return f


# ---------------------------------------------------------------- jig
def _mid(cfg: Any) -> np.ndarray:
    return np.array([(lo + hi) / 2.0 for lo, hi in cfg.LIMITS_MRAD]) / 1000.0


def identity_cal(cfg: Any, rig: str) -> list[tuple[str, tuple[int, ...]]]:
    """The CALs that put the rig's default back: effort, the pots' identity; pca9685, SERVO_CAL
    and no lead (DBAND 0: the jig measures the servos' hysteresis as it is)."""
    if rig == "pca9685":
        return ([("CAL", (j + 1, *map(int, c))) for j, c in enumerate(cfg.SERVO_CAL)]
                + [("DBAND", (j + 1, 0)) for j in range(len(cfg.SERVO_CAL))])
    mid = [int(round((lo + hi) / 2)) for lo, hi in cfg.LIMITS_MRAD]
    return [("CAL", (j + 1, 1000, m - 500, 2000, m + 500)) for j, m in enumerate(mid)]


def _servo_line(cfg: Any, j: int) -> tuple[float, float, float]:
    """(us0, us per rad, us per PCA9685 count) of joint j under the config's SERVO_CAL and
    SERVO_FREQ_HZ (the firmware's own arithmetic: servos.py, pca9685.py)."""
    us_a, a, us_b, b = cfg.SERVO_CAL[j]
    k = (us_b - us_a) * 1000.0 / (b - a)
    osc = 25_000_000
    pre = max(3, min(255, int(osc / (4096 * cfg.SERVO_FREQ_HZ) + 0.5) - 1))
    return us_a - k * a / 1000.0, k, (pre + 1) * 1e6 / osc


def pwm_pulse(cfg: Any, j: int, q: float) -> float:
    """The pulse (us) the pca9685 rig sends joint j (0-based) for set point q (rad) under the
    config's SERVO_CAL: servos.py's line, clipped, rounded to the PCA9685's counts at SERVO_FREQ_HZ
    (the firmware's own arithmetic, pca9685.py)."""
    us0, k, per = _servo_line(cfg, j)
    us = min(2500.0, max(500.0, us0 + k * q))
    c = min(4095, max(1, int(us / per + 0.5)))
    return c * per


def count_centres(cfg: Any, q) -> np.ndarray:
    """Set points (rad) at the middle of the PCA9685 count each joint's q falls in (SERVO_CAL):
    the same pulses, as far as can be from the next count's."""
    out = np.asarray(q, float).copy()
    for j in range(len(out)):
        us0, k, _ = _servo_line(cfg, j)
        out[j] = (pwm_pulse(cfg, j, out[j]) - us0) / k
    return out


def readings(client: Any, seconds: float = 0.4, field: str = "q") -> np.ndarray:
    """The mean of the telemetry's measured joints (`field` "q"; "target": the set point) over `seconds` (rad)."""
    return mean_telemetry(client, seconds, field)


def fit_line(q: np.ndarray, r: np.ndarray, min_spread: float) -> tuple[float, float]:
    """(c0, g) of r = c0 + g q by least squares; g = 1 (offset only) when q spreads less than min_spread."""
    if np.ptp(q) < min_spread or len(q) < 2:
        return float(np.mean(r - q)), 1.0
    g, c0 = np.polyfit(q, r, 1)
    return float(c0), float(g)


def jig_step(client: Any, cfg: Any, jig: Any, marks=MARKS, gains=(), rig: str | None = None) -> Found:
    rig = rig or rig_of(cfg)
    n = int(cfg.N_JOINTS)
    f = Found()
    for verb, args in list(identity_cal(cfg, rig)) + list(gains):   # measure against the known defaults (and new gains)
        client.command(verb, *args)
    start = readings(client, 0.1, "target")
    arm = Jogger(client, start, snap=(lambda q: count_centres(cfg, q)) if rig == "pca9685" else None)
    qs, rs, used, gaps, rests, pots = [], [], [], [], [], []
    for m in marks:
        if rig == "effort":          # the pots read the joints themselves: one placement
            ok = jig.place(m, arm)
            r = readings(client) if ok else None
        else:                        # the servos rest where they came from: both sides, the middle
            got, seen = [], []
            for side in (1, -1):
                arm.side = side
                if not jig.place(m, arm):
                    break
                got.append([pwm_pulse(cfg, j, arm.setpoint[j]) for j in range(n)])
                seen.append(readings(client))     # the feedback pots: where the joint rests
            arm.side = 0
            ok = len(got) == 2
            r = np.mean(got, axis=0) if ok else None
            if ok:
                gaps.append(np.subtract(got[0], got[1]))     # us: from below less from above
                rests.append(np.subtract(seen[1], seen[0]))  # rad (pots): from above less from below
                pots.append(np.mean(seen, axis=0))
        if not ok:
            f.lines.append(f"jig: mark {m.name} skipped")
            continue
        qs.append(ik(m))
        rs.append(r)
        used.append(m.name)
    if len(used) < 2:
        f.lines.append(f"jig: {len(used)} mark(s) placed, at least 2 are needed; nothing set")
        return f
    Q, R = np.array(qs), np.array(rs)
    per: dict[str, Any] = {}
    for j in range(n):
        if rig == "effort":
            c0, g = fit_line(Q[:, j], R[:, j], MIN_SPREAD)
            mid = _mid(cfg)[j]
            # pot reading = c0 + g q; CAL: readings mid -+ 0.5 rad ("pulses" 1000, 2000) at their angles
            ra, rb = mid - 0.5, mid + 0.5
            a, b = (ra - c0) / g, (rb - c0) / g
            f.settings.append(("CAL", (j + 1, 1000, int(round(a * 1000)), 2000, int(round(b * 1000)))))
            offset = float(c0 + (g - 1.0) * mid)    # reading = mid + g (q - mid) + offset
            resid = R[:, j] - (c0 + g * Q[:, j])
            per[str(j + 1)] = {"zero_offset_rad": round(offset, 5), "pot_gain": round(g, 5),
                               "residual_max_mrad": round(float(np.max(np.abs(resid))) * 1000, 2)}
            f.lines.append(f"joint {j + 1}: the pot reads {offset * 1000:+.1f} mrad off, gain {g:.4f}")
        else:
            # the servo's line: true angle = alpha + beta * pulse
            qj, wj = Q[:, j], R[:, j]
            if np.ptp(qj) < MIN_SPREAD:
                us_a, a_cfg, us_b, b_cfg = cfg.SERVO_CAL[j]
                beta = (b_cfg - a_cfg) / 1000.0 / (us_b - us_a)
                alpha = float(np.mean(qj - beta * wj))
            else:
                beta, alpha = (float(x) for x in np.polyfit(wj, qj, 1))
            a, b = alpha + beta * 1000.0, alpha + beta * 2000.0
            f.settings.append(("CAL", (j + 1, 1000, int(round(a * 1000)), 2000, int(round(b * 1000)))))
            # the hysteresis: from below the joint rests h short of its pulse's angle, from above h
            # past it, so 2 h = beta (P_below - P_above) + (r_above - r_below) / pot gain: the pulses
            # alone are whole PWM counts (11.5 mrad at 50 Hz), the pots see where the joint really
            # rested, and their offset cancels in the difference (their gain: against the marks)
            pj = np.array([p[j] for p in pots])
            gain = float(np.polyfit(qj, pj, 1)[0]) if np.ptp(qj) >= MIN_SPREAD else 1.0
            if not 0.8 <= gain <= 1.25:
                gain = 1.0
            width = max(0.0, float(np.median([beta * g[j] + r[j] / gain for g, r in zip(gaps, rests)])))
            counts = float(np.median([abs(g[j]) for g in gaps])) * abs(beta)
            f.settings.append(("DBAND", (j + 1, int(min(LEAD_MAX_MRAD, round(width * 1000))))))
            us_a, a_cfg, us_b, b_cfg = cfg.SERVO_CAL[j]
            nominal = a_cfg / 1000.0 + (1500.0 - us_a) * (b_cfg - a_cfg) / 1000.0 / (us_b - us_a)
            horn = alpha + beta * 1500.0 - nominal
            resid = qj - (alpha + beta * wj)
            per[str(j + 1)] = {"offset_at_1500us_rad": round(horn, 5), "rad_per_us": round(beta, 8),
                               "hysteresis_mrad": round(width * 1000, 2),
                               "hysteresis_pulses_mrad": round(counts * 1000, 2), "pot_gain": round(gain, 4),
                               "residual_max_mrad": round(float(np.max(np.abs(resid))) * 1000, 2)}
            f.lines.append(f"joint {j + 1}: the servo sits {horn * 1000:+.1f} mrad off at 1500 us, "
                           f"{beta * 1e6:.1f} urad/us; {width * 1000:.1f} mrad between its two sides (DBAND)")
    f.values["jig"] = {"rig": rig, "marks": used, "joints": per}
    return f
