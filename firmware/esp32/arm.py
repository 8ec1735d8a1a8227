"""The 3R planar servo arm's own part: Board(hal, cfg).

The protocol (lines, sessions, latches, watchdog, telemetry pacing, the
common verbs) is firmware/common/link.py's BoardLink; this file gives it the
arm's verbs (W, GAIN, SETLIM) and its control tick: the waypoint trajectory
(traj.py), one PID per joint and the following-error check. The interface
between the two is in link.py's docstring.

Capabilities, each present only when the HAL or the filesystem has it (a
board without one answers its verb VERB, docs/protocol.md §3):
  * X, XY: Cartesian waypoints solved here by the int8 net and FABRIK
    (ik3r.py), when the weights file cfg.IK_WEIGHTS is on the filesystem;
  * PEN, PENPOS: the pen-lift servo (hal.has_pen), modal: the pen state rides
    with the waypoints queued after it (traj's aux), a change dwells the settle
    time (PEN_SETTLE_MS, or PENPOS's); PENPOS sets its pulse widths (arm_pen.py);
  * CAL: positional servo calibration (hal.POSITIONAL, the PCA9685 rig);
    on the effort rig the pots' calibration, and RELAY (relay auto-tune of
    one joint's loop): arm_cal.py, which also gives CALID its settings.
    On that rig the servos close their own loops: the board writes the set
    point as positions (hal.write_positions) instead of running its PIDs, and
    the watchdog's ZERO mode holds the frozen set point.

`hal` is the duck-typed HAL of docs/architecture.md; `cfg` is the config
module (firmware/esp32/config.py) or any object with its attribute names. The
ones read here and in link.py: FW_NAME, FW_VERSION, N_JOINTS, LIMITS_MRAD,
VMAX_MRAD_S, PERIOD_MS, QSIZE, TELEMETRY_HZ, WDOG_MS, PID_KP, PID_KI, PID_KD,
PID_KFF, FOLLOW_ERR_MRAD, FOLLOW_ERR_MS, PEN_SETTLE_MS, IK_WEIGHTS,
IK_THETA_MRAD, and (optional) SPEED_KV, SPEED_KI, SPEED_TRIM, SPEED_UMIN,
SERVO_LEAD_MS (the pca9685 rig: the set point sent that far ahead along its
velocity, for the servos' own lag) (pins and
ADC/PWM/servo calibration are read by the HALs only).

The set point changes only by the trajectory (segments stretched to vmax, a
ramp at vmax into a narrowed range) or by being put at the measured position
(a stop where the arm is, which moves nothing): never in a jump.

The joints keep to vmax too (effort rig): a set point moving at vmax leaves
the lagging joint no room to catch up, and the PID's correction on top of the
feed-forward would drive it past vmax (3.9 rad/s against 3.0 on a SETLIM
ramp). `SpeedCap` bounds each PID's output to the effort that holds vmax: the
feed-forward's effort at vmax, corrected by the measured speed (SPEED_KV) and
by a trim learned while the cap holds (SPEED_KI, within +-SPEED_TRIM of kff:
the servo's real speed per effort). The joint then lags a set point at vmax
and catches up when it stops. Speeds are the pots', so a pot that reads g
times the joint's travel holds the joint at vmax / g.
"""

import ik3r
import link as L
from arm_cal import ArmCal
from arm_pen import ArmPen
import proto
import protodef as P
from pid import PID
from traj import Traj


def _milli(x: float) -> int:
    return int(round(x * 1000.0))


class SpeedCap:
    """One joint's speed limit on its effort (see the module docstring).

    update(q, dt) measures the speed (first-order filtered difference of the
    pot); bound(vmax, kff) is the most effort either way: the feed-forward's
    effort at vmax, (kff + trim) * vmax but at least umin (a slow vmax must not
    leave the joint too little effort to break its static friction or hold),
    less kv times the speed the joint has over vmax that way.
    learn(u, hi, lo, vmax, kff, dt) moves the trim while the output has sat at
    the cap for HOLD ticks (the joint's speed settled), toward the effort that
    holds vmax.
    """

    HOLD = 20

    def __init__(self, kv: float, ki: float, trim: float, umin: float) -> None:
        self.kv = kv
        self.umin = umin
        self.ki = ki
        self.trim_max = trim
        self.trim = 0.0         # s/rad, added to kff at the cap
        self.v = 0.0            # filtered measured speed, rad/s
        self.prev = 0.0         # last position, rad ...
        self.primed = False     # ... once there is one
        self.held = 0           # ticks the output has sat at the cap
        self.alpha = 0.7        # the speed filter: the new difference's weight

    def reset(self, q: float) -> None:
        self.prev = q
        self.primed = True
        self.v = 0.0
        self.held = 0

    def update(self, q: float, dt: float) -> None:
        if self.primed and dt > 0:
            self.v += self.alpha * ((q - self.prev) / dt - self.v)
        self.prev = q
        self.primed = True

    def bound(self, vmax: float, kff: float) -> tuple:
        base = (kff + self.trim) * vmax
        if base < self.umin:
            base = self.umin
        v = self.v
        hi = base - self.kv * (v - vmax) if v > vmax else base
        lo = base - self.kv * (-v - vmax) if -v > vmax else base
        return (hi if hi > 0.0 else 0.0), (lo if lo > 0.0 else 0.0)

    def learn(self, u: float, hi: float, lo: float, vmax: float, kff: float, dt: float) -> None:
        v = self.v
        if u >= hi - 1e-9 and v > 0.0:
            err = (vmax - v) / vmax
        elif u <= -lo + 1e-9 and v < 0.0:
            err = (vmax + v) / vmax
        else:
            self.held = 0
            return
        self.held += 1
        base = (kff + self.trim) * vmax
        if self.held < self.HOLD or base < self.umin or base >= 1.0:   # the cap is not what binds
            return
        t = self.trim + self.ki * kff * err * dt
        m = self.trim_max * kff
        self.trim = m if t > m else (-m if t < -m else t)


class Board(L.LinkedBoard):
    def __init__(self, hal, cfg) -> None:
        self.hal = hal
        self.cfg = cfg
        n = cfg.N_JOINTS
        self.n = n
        self.qsize = cfg.QSIZE
        self.period_ms = cfg.PERIOD_MS
        self.hard = [[cfg.LIMITS_MRAD[j][0], cfg.LIMITS_MRAD[j][1], cfg.VMAX_MRAD_S[j]]
                     for j in range(n)]
        self.lim = [list(h) for h in self.hard]   # [min, max, vmax] now in force
        self.traj = Traj(n, cfg.QSIZE, [h[2] for h in self.hard])
        for j in range(n):
            self.traj.set_range(j, self.lim[j][0], self.lim[j][1], self.lim[j][2])
        self.pids = [PID(cfg.PID_KP[j], cfg.PID_KI[j], cfg.PID_KD[j], cfg.PID_KFF[j])
                     for j in range(n)]
        self.caps = [SpeedCap(getattr(cfg, "SPEED_KV", 0.5), getattr(cfg, "SPEED_KI", 2.0),
                              getattr(cfg, "SPEED_TRIM", 0.5), getattr(cfg, "SPEED_UMIN", 0.1))
                     for _ in range(n)]
        self.q = [0.0] * n        # measured positions, rad
        self.u = [0.0] * n        # outputs, [-1, 1]
        self._fe_ms = [0] * n     # time each joint's following error has been too big
        # Trace hook on_done(id, targets_milli), called with every completed
        # waypoint (events coalesce them per tick): the emulator keeps the
        # board's own log of executed waypoints with it.
        self.on_done = None
        self.positional = getattr(hal, "POSITIONAL", False)
        self.lead_s = getattr(cfg, "SERVO_LEAD_MS", 0) / 1000.0
        self.verbs = {"W": self._cmd_w, "GAIN": self._cmd_gain, "SETLIM": self._cmd_setlim}
        self.motion_verbs = ["W"]
        self.ik = _load_ik(hal, cfg)
        if self.ik is not None:
            self.verbs["X"] = self._cmd_x
            self.verbs["XY"] = self._cmd_x
            self.motion_verbs += ["X", "XY"]
        self.pen = None  # type: ArmPen | None  # PEN, PENPOS (arm_pen.py), with a pen-lift servo
        if getattr(hal, "has_pen", False):
            self.pen = ArmPen(self)
            self.verbs["PEN"] = self.pen.cmd_pen
            self.verbs["PENPOS"] = self.pen.cmd_penpos
            self.motion_verbs += ["PEN", "PENPOS"]
        self.cal = ArmCal(self)   # RELAY, CAL, what CALID saves (arm_cal.py)
        if self.positional:
            if hasattr(hal, "set_calibration"):
                self.verbs["CAL"] = self.cal.cmd_cal
            if hasattr(hal, "set_lead"):
                self.verbs["DBAND"] = self.cal.cmd_dband  # the servos' hysteresis (servos.py's lead)
        else:
            self.verbs["CAL"] = self.cal.cmd_cal      # the pots' calibration (arm_cal.py)
            self.verbs["RELAY"] = self.cal.cmd_relay
            self.motion_verbs.append("RELAY")
        self.link = L.BoardLink(hal, cfg, self)   # last: it calls hold_here() and sends BOOT

    # ------------------------------------------------------------ verbs

    def _cmd_w(self, v: list) -> list:
        self._queue(v[0], v[1], v[2:])
        return []

    def _cmd_x(self, v: list) -> list:
        """X id dur x y theta / XY id dur x y: solved now, queued as joint targets."""
        if self.traj.free() <= 0:     # before the solve: a full queue costs no IK
            raise proto.ProtocolError(P.FULL)
        theta = v[4] if len(v) > 4 else self.cfg.IK_THETA_MRAD
        q = self.ik.solve(v[2] / 1000000.0, v[3] / 1000000.0, theta / 1000.0)
        if q is None:
            raise proto.ProtocolError(P.REACH)
        self._queue(v[0], v[1], [_milli(a) for a in q])
        return []

    def _queue(self, wid: int, dur: int, targets: list) -> None:
        for j in range(self.n):
            if not self.lim[j][0] <= targets[j] <= self.lim[j][1]:
                raise proto.ProtocolError(P.RANGE, "", str(j + 1))
        dwell = 0
        aux = None
        pen = self.pen
        if pen is not None:
            aux = pen.next
            dwell = pen.dwell()
        if not self.traj.push(wid, dur, targets, dwell, aux):
            raise proto.ProtocolError(P.FULL)
        self.cal.finish()           # a waypoint ends a relay test
        self.link.queued = wid

    def _cmd_gain(self, v: list) -> list:
        self.pids[v[0] - 1].set_gains(v[1] / 1000.0, v[2] / 1000.0, v[3] / 1000.0)
        return []

    def _cmd_setlim(self, v: list) -> list:
        """Narrows a joint's range and speed limit within the hard ones. Refused
        RANGE (detail: the joint) when it would leave a queued target outside;
        a set point outside the new range moves into it at vmax (LIMIT)."""
        j, lo, hi, vmax = v
        hard = self.hard[j - 1]
        if lo < hard[0] or hi > hard[1] or vmax > hard[2] or self.traj.excludes(j - 1, lo, hi):
            raise proto.ProtocolError(P.RANGE, "", str(j))
        self.lim[j - 1] = [lo, hi, vmax]
        self.traj.set_range(j - 1, lo, hi, vmax)
        return []

    # ------------------------------------------------------------ BoardLink interface

    def free(self) -> int:
        return self.traj.free()

    def busy(self) -> bool:
        return self.traj.busy()

    def cal_text(self) -> list:
        return self.cal.cal_text() + (self.pen.cal_text() if self.pen is not None else [])

    def cal_apply(self, tokens: list) -> None:
        """CALID's tokens: the pen's `P=` (arm_pen.py), the rest arm_cal.py's; all checked first."""
        pen = [t for t in tokens if t[:2] == "P="]
        if pen and self.pen is None:
            raise ValueError("no pen")
        x = ArmPen.parse(pen[-1]) if pen else None
        self.cal.cal_apply([t for t in tokens if t[:2] != "P="])
        if x is not None:
            self.pen.apply(x)   # type: ignore[union-attr]

    def _read(self) -> None:
        self.hal.read_positions(self.q)
        self.cal.correct(self.q)

    def halt(self) -> None:
        self.cal.finish()
        self.traj.flush()
        self.traj.hold = False
        if self.pen is not None:
            self.pen.next = self.pen.state
        for j in range(self.n):
            self.u[j] = 0.0

    def hold_here(self) -> None:
        self.halt()
        self._read()
        self.traj.set_point([_milli(x) for x in self.q])
        for p in self.pids:
            p.reset()
        for j in range(self.n):
            self._fe_ms[j] = 0
            self.caps[j].reset(self.q[j])

    def set_hold(self, on: bool) -> None:
        self.traj.hold = on

    def control(self, mode: int) -> None:
        self._read()
        u = self.u
        dt = self.period_ms / 1000.0
        for j in range(self.n):
            self.caps[j].update(self.q[j], dt)
        if mode == L.DRIVE:
            self._advance()
            sp = self.traj.sp
            if self.positional:
                self.hal.write_positions(self._led(sp))
            else:
                vel = self.traj.vel
                for j in range(self.n):
                    pid = self.pids[j]
                    cap = self.caps[j]
                    vmax = self.lim[j][2] / 1000.0
                    hi, lo = cap.bound(vmax, pid.kff)
                    pid.out_max = hi if hi < 1.0 else 1.0
                    pid.out_min = -lo if lo < 1.0 else -1.0
                    u[j] = pid.update(sp[j] / 1000.0, self.q[j], dt, vel[j] / 1000.0)
                    cap.learn(u[j], pid.out_max, -pid.out_min, vmax, pid.kff, dt)
                self.cal.tick(u, self.q, self.period_ms)
                self.hal.write_outputs(u)
            self._check_following()
            return
        for j in range(self.n):
            u[j] = 0.0
        if mode == L.ZERO:
            if self.positional:      # a positional servo stops by holding where it was sent
                self.hal.write_positions([x / 1000.0 for x in self.traj.sp])
            else:
                self.hal.write_outputs(u)

    def _led(self, sp: list) -> list:
        """The positional servos' set points (rad): SERVO_LEAD_MS ahead along the set
        point's velocity (their own lag), within the joint's limits in force. A servo
        lags its pulse by its dead band, or by its loop's lag when that is more, plus
        half its play; DBAND's lead (servos.py) covers the band and the play, so a
        calibrated servo is led here only by what SERVO_LEAD_MS adds beyond half its
        DBAND width (without, it ran 5-9 mrad ahead at drawing speeds and 1.6 mm off
        at the strokes' corners)."""
        lead = self.lead_s
        vel = self.traj.vel
        band = self.cal.lead
        out = []
        for j in range(self.n):
            a = lead * vel[j]
            h = band[j] * 0.5
            if a > h:
                a -= h
            elif a < -h:
                a += h
            else:
                a = 0.0
            x = sp[j] + a
            lim = self.lim[j]
            x = lim[0] if x < lim[0] else (lim[1] if x > lim[1] else x)
            out.append(x / 1000.0)
        return out

    def telemetry(self) -> list:
        fields = [_milli(x) for x in self.q]
        fields += [int(round(x)) for x in self.traj.sp]
        fields += [_milli(x) for x in self.u]
        return fields

    # ------------------------------------------------------------ control

    def _advance(self) -> None:
        """One tick of the trajectory. Its events are coalesced so that short
        waypoints cannot flood the 115200-baud return lane: one DONE for the
        last waypoint completed in the tick (those before it are done too), and
        START only for a waypoint that starts from rest (otherwise it starts in
        the tick its predecessor is DONE)."""
        pen = self.pen
        if pen is not None:
            pen.tick()
        last_done = -1
        for e in self.traj.step(self.period_ms):
            if e[0] == "DONE":
                last_done = e[1]
                if self.on_done is not None:
                    self.on_done(e[1], e[2])
            elif e[0] == "AUX":
                if pen is not None and e[1] != pen.state:
                    pen.set(e[1])
            elif e[0] != "START" or last_done < 0:
                self.link.event(e[0], e[1:])
        if last_done >= 0:
            self.link.completed(last_done)

    def _check_following(self) -> None:
        limit = self.cfg.FOLLOW_ERR_MRAD
        for j in range(self.n):
            err = self.traj.sp[j] - self.q[j] * 1000.0
            if abs(err) > limit:
                self._fe_ms[j] += self.period_ms
                if self._fe_ms[j] >= self.cfg.FOLLOW_ERR_MS:
                    self.link.fault([j + 1, int(err)], "FOLLOW:%d" % (j + 1))
                    return
            else:
                self._fe_ms[j] = 0


def _load_ik(hal, cfg):
    """The board's IK (ik3r.BoardIK) from the weights on the filesystem, or None:
    no weights file, or one that does not parse (then X/XY are refused VERB and
    the board runs on; a bad file must not stop the arm's other verbs)."""
    name = getattr(cfg, "IK_WEIGHTS", None)
    if not name or not hasattr(hal, "read_file"):
        return None
    data = hal.read_file(name)
    if not data:
        return None
    try:
        return ik3r.BoardIK(cfg, data)
    except Exception:   # noqa: BLE001 - any bad file: no IK, the board runs on
        return None
