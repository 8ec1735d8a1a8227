"""The MA's actions, one control period at a time: functions of the Board
(ma.py) `b`, kept apart so that each file stays small. The semantics are in
ma.py's docstring; the phases of an action `b.act = [id, verb, args, phase,
t0_ms, aux]`:

  MV    go                       ramp to d, done when settled on it
  MV    seek -> stop             a d on a joint's magnet (|d - r_k| <= the hall
        window; a plan's MV before a ROT): onto the magnet as ROT's seek, done
        once stopped on its hall edge (where the sensor says the MA is on it)
  ROT   seek -> stop -> turn
        seek: ramp toward w + e + 3 mm past r_j, braking so as to reach
        w + 0.5 mm short of r_j at MAG_MM_S and creeping on from there (loc.py's
        MISSED check fires before the end; getting there without an edge is
        MISSED too); the hall edge of magnet j -> stop: brake to rest where
        the MA is (the speed loop alone), until it has settled -> turn: the angle loop on the gear encoder, off
        (the worm holds) once the angle is within ROT_TOL_MRAD at the end of
        its ramp, done once the angle has stopped (aux: its last estimate).
        A ROT on the magnet it stands on (sensor high, re-zeroed there) turns at once.
        Which way to seek (`side`): toward r_j when the estimate is clear of
        the window (w + e); inside it with the sensor low, back the way the MA
        came if it passed magnet j (its anchor), else on the way it was going.
  GRIP  wait                     servo commanded at begin, done after GRIP_MS
  HOME  go -> push               go (d known): ramp to 0 arriving at creep;
        push: toward the base at creep (HOME_MM_S when d is unknown), effort
        at most HOME_EFFORT, until the wheel stops on magnet 1.
  END   go -> push               HOME's mirror at the far end (d known): ramp to
        END_APPROACH_MM short of l arriving at creep; push up at creep, effort
        at most HOME_EFFORT, until the wheel stops: EV ENDSTOP n count (the
        wheel's count from home), d's estimate left as it is. No stop within
        3 END_APPROACH_MM of the push (20 mm past l): FAULT END:MISSED.
  LIMIT go                       the board's own move of d into a range a
        SETLIM narrowed (ma.py `limit_to`; id -1: no START or DONE, EV LIMIT n
        when it begins): MV's ramp to the range's nearer end.
Every ramp runs at the d (or joint) vmax in force, HOME's too, and a creep
speed above it creeps at vmax (docs/protocol.md section 11).

Why the seek creeps only the last w + 0.5 mm (not the whole window): the edge
comes where the MA truly is w short of the magnet, which the estimate puts
within e of w short; the braking curve is still slow there (sqrt(2 a e)), and
the stop brakes the speed to 0 wherever the MA is (no pull back: anywhere
in the window is on the magnet), so an early edge costs a short overshoot
inside the window, never a wrong place.
"""

import link as L
import ma_cal as C

MV = "MV"
ROT = "ROT"
GRIP = "GRIP"
HOME = "HOME"
END = "END"
LIMIT = "LIMIT"


def begin(b) -> None:
    now = b.hal.ticks_ms()
    if b.limit_to is not None:       # the move into a narrowed range goes first
        act = [-1, LIMIT, [b.limit_to], "go", now, 0]
        b.limit_to = None
        b.link.event("LIMIT", [b.n])
    else:
        wid, verb, args = b.queue.pop(0)
        act = [wid, verb, args, "go", now, 0]
        b.link.event("START", [wid])
    verb = act[1]
    args = act[2]
    b.act = act
    b._fe = 0
    b._settle = 0
    if verb == GRIP:
        b.hal.grip(args[0] == 1)
        act[3] = "wait"
        return
    j = _magnet(b, act)
    if j:
        if _on_magnet(b, j):
            if verb == ROT:
                _engage(b, act)
                return
            act[3] = "stop"          # MV onto the magnet it stands on: nothing to drive
        else:
            act[3] = "seek"
            act[5] = _side(b, j)
    if verb == HOME and not b.loc.known:
        act[3] = "push"
        act[5] = b._c
    b.rot.release()
    if b.loco.ramp.v == 0.0:
        b.loco.reset(b.loc.d())


def _magnet(b, act) -> int:
    """The joint whose magnet the action drives onto (1-based), 0: none."""
    if act[1] == ROT:
        return act[2][0]
    if act[1] == MV and b.loc.known:
        k = b.loc.near(act[2][0])
        if abs(act[2][0] - b.loc.r[k - 1]) <= b.loc.w:
            return k
    return 0


def _on_magnet(b, j: int) -> bool:
    return b.loc.known and b.loc.mag == j and b._level == 1


def _side(b, j: int) -> int:
    """Which way (+-1) magnet j is from the MA (the module docstring)."""
    loc = b.loc
    rem = loc.m[j - 1] - loc.d()
    if abs(rem) > loc.w + loc.err():
        return 1 if rem > 0 else -1
    way = b.loco.ramp.dir
    if loc.mag == j and way:
        return -way
    if way:
        return way
    return 1 if rem >= 0 else -1


def advance(b) -> None:
    act = b.act
    verb = act[1]
    phase = act[3]
    c = b.cfg
    dt = b.dt
    if verb == C.RELAY:
        C.relay_step(b, act)
        return
    if verb == GRIP:
        if b.hal.ticks_diff(b.hal.ticks_ms(), act[4]) >= c.GRIP_MS:
            _finish(b)
        return
    if b.held:
        if phase == "turn":
            b.rot.ramp.brake(dt, c.ROT_ACCEL_MRAD_S2)
            b.rot.effort(dt, b.theta[act[2][0] - 1])
        else:
            b.loco.ramp.brake(dt, c.LOCO_ACCEL_MM_S2)
            b.loco.effort(dt, b.loc.d(), b.speed, b.lim[b.n - 1][2],
                          c.HOME_EFFORT if phase == "push" else 1.0)
        return
    if verb == MV or verb == LIMIT:
        if phase == "go":
            _mv(b, act)
        elif _seek(b, act, _magnet(b, act)):
            b.loco.off()
            _finish(b)
    elif verb == ROT:
        _rot(b, act)
    elif verb == HOME:
        _home(b, act)
    else:
        _end(b, act)


def _mv(b, act) -> None:
    c = b.cfg
    target = act[2][0]
    ramp = b.loco.ramp
    vmax = b.lim[b.n - 1][2]
    there = ramp.step(b.dt, target, vmax, c.LOCO_ACCEL_MM_S2)
    if there and not act[5]:
        act[5] = 1
        b.loco.pid.integ = 0.0      # landed: what the ramp wound up must not push it on
    d = b.loc.d()
    b.loco.effort(b.dt, d, b.speed, vmax)
    if _settled(b, there and abs(target - d) <= c.STOP_TOL_MM and abs(b.speed) <= c.SETTLE_MM_S):
        b.loco.off()
        _finish(b)


def _rot(b, act) -> None:
    c = b.cfg
    j = act[2][0]
    if act[3] == "turn":
        target = act[2][1]
        th = b.theta[j - 1]
        rot = b.rot
        there = rot.ramp.step(b.dt, target, b.lim[j - 1][2], c.ROT_ACCEL_MRAD_S2)
        b.loco.u = 0.0
        still = th == act[5]          # the joint's estimate did not move this period
        act[5] = th
        if there and abs(target - th) <= c.ROT_TOL_MRAD:
            rot.off()                 # dead band: the worm holds; no hunting through the backlash
            if _settled(b, still):    # the worm may still coast inside the play: the joint does not
                _finish(b)
            return
        b._settle = 0
        rot.effort(b.dt, th)
        return
    if _seek(b, act, j):
        b.loco.off()
        _engage(b, act)


def _seek(b, act, j: int) -> bool:
    """Onto magnet j (phases seek -> stop) -> True once stopped on it."""
    c = b.cfg
    loc = b.loc
    ramp = b.loco.ramp
    if act[3] == "seek" and b._mag_now == j:
        act[3] = "stop"
    if act[3] == "stop":
        ramp.reset(loc.d())         # the reference follows the MA: brake to rest where it is,
        b.loco.pid.reset()          # on the speed error alone (an integral would creep on)
    vmax = b.lim[b.n - 1][2]
    if act[3] == "seek":
        side = act[5]
        margin = loc.w + loc.err()
        if ramp.step(b.dt, loc.m[j - 1] + side * (margin + 3.0), vmax, c.LOCO_ACCEL_MM_S2,
                     c.MAG_MM_S, margin + loc.w + 3.5):
            b.link.fault([b.n, j], "MAGNET:MISSED")     # past the window, no edge
            return False
    b.loco.effort(b.dt, loc.d(), b.speed, vmax)
    return act[3] == "stop" and _settled(b, abs(b.speed) <= c.SETTLE_MM_S)


def _settled(b, ok: bool) -> bool:
    """ok this period and for the SETTLE_MS before it."""
    if not ok:
        b._settle = 0
        return False
    b._settle += b.period_ms
    if b._settle < b.cfg.SETTLE_MS:
        return False
    b._settle = 0
    return True


def _engage(b, act) -> None:
    j = act[2][0]
    act[3] = "turn"
    act[5] = b.theta[j - 1]
    b.loco.off()
    b.rot.engage(j, b.theta[j - 1], b._g)
    b._still_rot = 0


def _home(b, act) -> None:
    c = b.cfg
    loc = b.loc
    ramp = b.loco.ramp
    vmax = b.lim[b.n - 1][2]          # the range HOME ignores; the speed limit it keeps
    if act[3] == "go":
        if ramp.step(b.dt, 0.0, vmax, c.LOCO_ACCEL_MM_S2, c.LOCO_CREEP_MM_S):
            act[3] = "push"
            act[5] = b._c
        b.loco.effort(b.dt, loc.d(), b.speed, vmax)
        return
    v = c.LOCO_CREEP_MM_S if loc.known else c.HOME_MM_S
    ramp.step(b.dt, ramp.x - 1000.0, v if v < vmax else vmax, c.LOCO_ACCEL_MM_S2)
    b.loco.effort(b.dt, loc.d(), b.speed, vmax, c.HOME_EFFORT)
    if b._still >= c.HOME_STOP_MS and b._level == 1:
        loc.home(b._c)
        b.unhomed = False
        b.loco.reset(0.0)
        _finish(b)
        return
    if abs(b._c - act[5]) * loc.q > loc.length + 50.0:
        b.link.fault([b.n, 1], "MAGNET:MISSED")          # drove past the arm: no base stop


def _end(b, act) -> None:
    c = b.cfg
    loc = b.loc
    ramp = b.loco.ramp
    vmax = b.lim[b.n - 1][2]
    if act[3] == "go":
        if ramp.step(b.dt, loc.length - c.END_APPROACH_MM, vmax, c.LOCO_ACCEL_MM_S2, c.LOCO_CREEP_MM_S):
            act[3] = "push"
            act[5] = b._c
        b.loco.effort(b.dt, loc.d(), b.speed, vmax)
        return
    v = c.LOCO_CREEP_MM_S
    ramp.step(b.dt, ramp.x + 1000.0, v if v < vmax else vmax, c.LOCO_ACCEL_MM_S2)
    b.loco.effort(b.dt, loc.d(), b.speed, vmax, c.HOME_EFFORT)
    if b._still >= c.HOME_STOP_MS:
        b.link.event("ENDSTOP", [b.n, b._c - loc.c_home])
        b.loco.reset(loc.d())
        _finish(b)
        return
    if abs(b._c - act[5]) * loc.q > 3 * c.END_APPROACH_MM:
        b.link.fault([b.n, 0], "END:MISSED")           # drove on past l: no end stop there


def _finish(b) -> None:
    wid = b.act[0]
    args = b.act[2]
    b.act = None
    b._fe = 0
    if wid >= 0:                # not the board's own LIMIT move
        if b.on_done is not None:   # the emulator's log of executed actions, with their arguments
            b.on_done(wid, list(args))
        b.link.completed(wid)
    if b.queue and not b.held:
        begin(b)                # the next one in this period: a plan's actions run back to back


def driving(b) -> bool:
    """An action drives the MA (its d reference moves)."""
    a = b.act
    return a is not None and a[1] != GRIP and a[3] != "turn"


def turning(b) -> bool:
    a = b.act
    return a is not None and a[3] == "turn"


def check(b) -> bool:
    """Stall and following-error checks after the outputs -> False on a FAULT."""
    c = b.cfg
    p = b.period_ms
    n = b.n
    if abs(b.loco.u) >= c.STALL_U and not b._moved:
        b._still += p
    else:
        b._still = 0
    homing = b.act is not None and b.act[3] == "push"
    if b._still >= c.STALL_MS and not (homing and (b._level == 1 or b.act[1] == END)):
        b.link.fault([n, int(round(b.loco.u * 1000.0))], "STALL:LOCO")
        return False
    j = b.rot.j
    if j and abs(b.rot.u) >= c.STALL_U and not b._turned:
        b._still_rot += p
    else:
        b._still_rot = 0
    if b._still_rot >= c.STALL_MS:
        b.link.fault([j, int(round(b.rot.u * 1000.0))], "STALL:%d" % j)
        return False
    if j and b.rot.slack > c.PLAY_MAX_MRAD:       # the worm turns, no gear takes its load
        b.link.fault([j, int(b.rot.slack)], "MESH:%d" % j)
        return False
    err = 0.0
    limit = 1.0
    k = 0
    if turning(b):
        k = j
        err = b.rot.ramp.x - b.theta[j - 1]
        limit = c.FOLLOW_ERR_MRAD
    elif driving(b) and not homing:
        k = n
        err = b.loco.ramp.x - b.loc.d()
        limit = c.FOLLOW_ERR_MM
    if k and abs(err) > limit:
        b._fe += p
        if b._fe >= c.FOLLOW_ERR_MS:
            b.link.fault([k, int(err)], "FOLLOW:%d" % k)
            return False
    else:
        b._fe = 0
    return b.link.state != L.FAULT
