"""The 3R planar servo arm's own part: Board(hal, cfg).

The protocol (lines, sessions, latches, watchdog, telemetry pacing, the
common verbs) is firmware/common/link.py's BoardLink; this file gives it the
arm's verbs (W, GAIN, SETLIM) and its control tick: the waypoint trajectory
(traj.py), one PID per joint and the following-error check. The interface
between the two is in link.py's docstring.

`hal` is the duck-typed HAL of docs/architecture.md; `cfg` is the config
module (firmware/esp32/config.py) or any object with its attribute names. The
ones read here and in link.py: FW_NAME, FW_VERSION, N_JOINTS, LIMITS_MRAD,
VMAX_MRAD_S, PERIOD_MS, QSIZE, TELEMETRY_HZ, WDOG_MS, PID_KP, PID_KI, PID_KD,
PID_KFF, FOLLOW_ERR_MRAD, FOLLOW_ERR_MS (pins and ADC/PWM calibration are
read by hal_esp32 only).

The set point changes only by the trajectory (segments stretched to vmax, a
ramp at vmax into a narrowed range) or by being put at the measured position
(a stop where the arm is, which moves nothing): never in a jump.
"""

import link as L
import proto
import protodef as P
from pid import PID
from traj import Traj


def _milli(x: float) -> int:
    return int(round(x * 1000.0))


class Board:
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
        self.q = [0.0] * n        # measured positions, rad
        self.u = [0.0] * n        # outputs, [-1, 1]
        self._fe_ms = [0] * n     # time each joint's following error has been too big
        # Trace hook on_done(id, targets_milli), called with every completed
        # waypoint (events coalesce them per tick): the emulator keeps the
        # board's own log of executed waypoints with it.
        self.on_done = None
        self.verbs = {"W": self._cmd_w, "GAIN": self._cmd_gain, "SETLIM": self._cmd_setlim}
        self.motion_verbs = ("W",)
        self.link = L.BoardLink(hal, cfg, self)   # last: it calls hold_here() and sends BOOT

    # ------------------------------------------------------------ entry points

    def poll(self) -> bool:
        """One pass of the main loop (BoardLink.poll). -> True if bytes came."""
        return self.link.poll()

    def tick(self) -> None:
        """One control period (BoardLink.tick)."""
        self.link.tick()

    def estop(self) -> None:
        """What the e-stop byte does (BoardLink.estop)."""
        self.link.estop()

    @property
    def state(self) -> str:
        return self.link.state

    @property
    def done(self) -> int:
        return self.link.done

    # ------------------------------------------------------------ verbs

    def _cmd_w(self, v: list) -> list:
        targets = v[2:]
        for j in range(self.n):
            if not self.lim[j][0] <= targets[j] <= self.lim[j][1]:
                raise proto.ProtocolError(P.RANGE, "", str(j + 1))
        if not self.traj.push(v[0], v[1], targets):
            raise proto.ProtocolError(P.FULL)
        self.link.queued = v[0]
        return []

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

    def halt(self) -> None:
        self.traj.flush()
        self.traj.hold = False
        for j in range(self.n):
            self.u[j] = 0.0

    def hold_here(self) -> None:
        self.halt()
        self.hal.read_positions(self.q)
        self.traj.set_point([_milli(x) for x in self.q])
        for p in self.pids:
            p.reset()
        for j in range(self.n):
            self._fe_ms[j] = 0

    def set_hold(self, on: bool) -> None:
        self.traj.hold = on

    def control(self, mode: int) -> None:
        self.hal.read_positions(self.q)
        u = self.u
        if mode == L.DRIVE:
            self._advance()
            dt = self.period_ms / 1000.0
            sp, vel = self.traj.sp, self.traj.vel
            for j in range(self.n):
                u[j] = self.pids[j].update(sp[j] / 1000.0, self.q[j], dt, vel[j] / 1000.0)
            self.hal.write_outputs(u)
            self._check_following()
            return
        for j in range(self.n):
            u[j] = 0.0
        if mode == L.ZERO:
            self.hal.write_outputs(u)

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
        last_done = -1
        for e in self.traj.step(self.period_ms):
            if e[0] == "DONE":
                last_done = e[1]
                if self.on_done is not None:
                    self.on_done(e[1], e[2])
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
