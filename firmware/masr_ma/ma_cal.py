"""The MA's calibration verbs: functions of the Board (ma.py) `b`, kept apart so
that each file stays small (docs/masr.md, "Calibration"; docs/protocol.md
section 3).

  MAG j pos win   joint j's magnet (1..n-1): its centre along the arm in the
                  wheel's frame (um from home) and its hall half window (um).
                  The localisation (loc.py) then identifies and anchors an
                  edge on it: d := pos - way * win, not r_j - way * HALL_WINDOW_MM.
                  j = n (d, no magnet): RANGE joint; a window of 0 or over
                  3 mm, or a centre more than 5 mm off r_j: RANGE pos / win.
  WHEEL nm        the wheel's travel per encoder count (nm), within 5 % of the
                  config's WHEEL_MM_PER_COUNT (RANGE nm otherwise); the estimate
                  stays where it is.
  RELAY j amp hyst cycles
                  relay auto-tune (firmware/common/relay.py) of a loop, at rest
                  (RANGE while anything is queued or moving, LATCHED while latched):
                  j = n the speed loop (set point 0 mm/s, the MA holding its
                  place; hyst and the reported amplitude in mm/s), j < n joint
                  j's angle loop (the MA must stand on joint j's magnet: UNHOMED
                  when d is unknown, RANGE joint elsewhere; set point the angle
                  now, hyst and amplitude in mrad). After `cycles` cycles:
                  EV RELAY j period_ms amp (0 0: no cycle within 10 s), then the
                  loop brings d or the joint back to where it started (the
                  board's own move, no START or DONE).
  cal_text / cal_apply: the tokens calstore.py persists with CALID and loads at
  boot: MAG,j,pos_um,win_um per magnet, WHEEL,nm, GAIN,j,kp,ki,kd per loop
  (thousandths, as the GAIN verb).
"""

import proto
import protodef as P
from relay import Relay

RELAY = "RELAY"
TURN_BACK = "ROT"
GO_BACK = "LIMIT"


def init(b) -> None:
    cfg = b.cfg
    b.mag_um = [[int(round(r * 1000.0)), int(round(cfg.HALL_WINDOW_MM * 1000.0))] for r in b.loc.r]
    b.wheel_nm = int(round(cfg.WHEEL_MM_PER_COUNT * 1e6))
    b.gains_milli = [[_k(cfg.ROT_KP), _k(cfg.ROT_KI), _k(cfg.ROT_KD)] for _ in range(b.nj)]
    b.gains_milli.append([_k(cfg.LOCO_KP), _k(cfg.LOCO_KI), _k(cfg.LOCO_KD)])


def _k(x: float) -> int:
    return int(round(x * 1000.0))


def mag(b, v: list) -> list:
    j, pos, win = v
    _mag_ok(b, j, pos, win)
    b.mag_um[j - 1] = [pos, win]
    b.loc.set_magnet(j, pos / 1000.0, win / 1000.0)
    return []


def _mag_ok(b, j: int, pos: int, win: int) -> None:
    if j > b.nj:
        raise proto.ProtocolError(P.RANGE, "", "joint")
    if abs(pos - b.loc.r[j - 1] * 1000.0) > 5000:
        raise proto.ProtocolError(P.RANGE, "", "pos")
    if not 0 < win <= 3000:
        raise proto.ProtocolError(P.RANGE, "", "win")


def wheel(b, v: list) -> list:
    nm = v[0]
    _wheel_ok(b, nm)
    b.wheel_nm = nm
    b.loc.set_scale(nm / 1e6)
    return []


def _wheel_ok(b, nm: int) -> None:
    nominal = b.cfg.WHEEL_MM_PER_COUNT * 1e6
    if abs(nm - nominal) > 0.05 * nominal:
        raise proto.ProtocolError(P.RANGE, "", "nm")


def gain(b, j: int, kp: int, ki: int, kd: int) -> None:
    b.gains_milli[j - 1] = [kp, ki, kd]
    p, i, d = kp / 1000.0, ki / 1000.0, kd / 1000.0
    if j == b.n:
        b.loco.pid.set_gains(p, i, d)
    else:
        b.rot.gains[j - 1] = [p, i, d]
        if b.rot.j == j:
            b.rot.pid.set_gains(p, i, d)


def cal_text(b) -> list:
    out = []
    for j in range(1, b.nj + 1):
        m = b.mag_um[j - 1]
        out.append("MAG,%d,%d,%d" % (j, m[0], m[1]))
    out.append("WHEEL,%d" % b.wheel_nm)
    for j in range(1, b.n + 1):
        g = b.gains_milli[j - 1]
        out.append("GAIN,%d,%d,%d,%d" % (j, g[0], g[1], g[2]))
    return out


def cal_apply(b, tokens) -> None:
    """Every token checked first, then all applied: a file that does not fit
    changes nothing (ValueError)."""
    todo = []
    for tok in tokens:
        parts = tok.split(",")
        kind = parts[0]
        v = [int(x) for x in parts[1:]]
        try:
            if kind == "MAG" and len(v) == 3 and 1 <= v[0]:
                _mag_ok(b, v[0], v[1], v[2])
            elif kind == "WHEEL" and len(v) == 1:
                _wheel_ok(b, v[0])
            elif not (kind == "GAIN" and len(v) == 4 and 1 <= v[0] <= b.n and min(v[1:]) >= 0):
                raise ValueError(tok)
        except proto.ProtocolError:
            raise ValueError(tok)
        todo.append((kind, v))
    for kind, v in todo:
        if kind == "MAG":
            mag(b, v)
        elif kind == "WHEEL":
            wheel(b, v)
        else:
            gain(b, v[0], v[1], v[2], v[3])


# ---------------------------------------------------------------- RELAY

def relay(b, v: list) -> list:
    j, amp, hyst, cycles = v
    if b.busy() or abs(b.speed) > b.cfg.SETTLE_MM_S:
        raise proto.ProtocolError(P.RANGE, "", "joint")
    if j > b.n:
        raise proto.ProtocolError(P.RANGE, "", "joint")
    loc = b.loc
    if b.unhomed or not loc.known:
        raise proto.ProtocolError(P.UNHOMED)
    now = b.hal.ticks_ms()
    if j == b.n:
        b.rot.release()
        b.loco.reset(loc.d())
        sp = loc.d()
    else:
        if not (loc.mag == j and b._level == 1):
            raise proto.ProtocolError(P.RANGE, "", "joint")
        sp = b.theta[j - 1]
        b.loco.reset(loc.d())
        b.loco.off()
        b.rot.engage(j, sp, b._g)
    b.act = [-1, RELAY, [j, sp], "relay", now, Relay(amp / 1000.0, float(hyst), cycles, now)]
    b._fe = 0
    b._settle = 0
    return []


def relay_step(b, act) -> None:
    """One period of the relay; when it is done, EV RELAY and the way back."""
    j, sp = act[2][0], act[2][1]
    r = act[5]
    now = b.hal.ticks_ms()
    if j == b.n:
        out = r.step(0.0, b.speed, now)
        b.loco.u = 0.0 if out is None else out
        b.rot.u = 0.0
    else:
        out = r.step(sp, b.theta[j - 1], now)
        b.rot.u = 0.0 if out is None else out
        b.loco.u = 0.0
    if out is not None:
        return
    res = r.result()
    period, amp = (0, 0) if res is None else (int(round(res[0])), int(round(res[1])))
    b.link.event("RELAY", [j, period, amp])
    if j == b.n:
        act[1] = GO_BACK
        act[2] = [sp]
        act[5] = 0                    # ma_act._mv's "landed" flag
        b.loco.reset(b.loc.d())
    else:
        act[1] = TURN_BACK
        act[2] = [j, int(round(sp))]
        act[5] = b.theta[j - 1]
        b.rot.engage(j, b.theta[j - 1], b._g)
        b.rot.j = j
        b.rot.u = 0.0
    act[3] = "go" if j == b.n else "turn"
