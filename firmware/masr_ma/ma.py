"""The MASR mobile actuator's own part: Board(hal, cfg) on the common BoardLink.

The protocol (lines, sessions, latches, watchdog, telemetry pacing, the
common verbs) is firmware/common/link.py's BoardLink, as for the arm
(firmware/esp32/arm.py); this file gives it the MA's verbs and control tick
(masr paper, section II-A). Coordinates: theta_1..theta_{n-1} (mrad), then d
(mm), n = cfg.N_JOINTS.

Verbs (docs/protocol.md section 3, "MASR actuator"): the actions MV id d,
ROT id j angle, GRIP id open, HOME id and END id, queued with credits and completed
with the link's DONE; GAIN j kp ki kd (j < n: joint j's angle loop, j = n: the
speed loop) and SETLIM j min max vmax (narrows as on the arm, section 11).

SETLIM, as the arm's: refused RANGE (detail j) when it would leave the target
of a queued or running action outside. d (j = n) known and farther outside
the new range than STOP_TOL_MM with no action under way: the board moves it
to the range's nearer end at vmax before the next action (ma_act's LIMIT
move: EV LIMIT n when it begins, state RUN meanwhile, no START or DONE); the
same after CLR or a new session (hold_here). A joint angle outside the new
range by more than ROT_TOL_MRAD is refused RANGE unless a ROT of that joint
is queued or running: the MA turns a joint only by driving to it, which is
the host's to plan (a ROT first), not a side effect of a limit.

Actions, one at a time, in order:
  MV    the speed loop drives to d along a ramped reference; done once within
        STOP_TOL_MM of d and settled.
  ROT   drive onto joint j's magnet (ramp to the near edge of the hall window,
        creep on, stop at the edge), then the angle loop turns joint j to the
        angle on the gear encoder; the worm holds it after (drive.py).
  GRIP  the gripper servo; done after GRIP_MS.
  HOME  drive to the base (ramped while d is known, at HOME_MM_S otherwise)
        and push on the base stop at most HOME_EFFORT: no wheel count for
        HOME_STOP_MS with the hall sensor on magnet 1 is d = 0.
  END   HOME's mirror onto the far end stop (d = l; d known), reporting
        EV ENDSTOP n count there (the wheel's count from home: calibration's
        second reference beside the base); the estimate is left as it is.
UNHOMED: after a reset while moving (the persisted record says m = 1), a
power on (no record), or a localisation FAULT, MV and ROT are refused UNHOMED
unless a HOME is queued or running ahead of them (END too); GRIP and HOME are not.

Calibration (ma_cal.py): MAG, WHEEL, RELAY and the settings CALID saves.
Localisation is loc.py (its docstring derives the error bound); its faults
latch FAULT MAGNET:MISSED / MAGNET:SPURIOUS and make the board unhomed. A
driven motor without encoder counts for STALL_MS is STALL:LOCO / STALL:j; a
reference the MA or the joint cannot follow is FOLLOW:j. EV FAULT carries
`coordinate value` (the magnet, the effort in per-mille or the error).

Persisted with the link's record (persist_extra / restore), one token:
`m,jd,dlink_um,e_um,th_1,...,th_{n-1}` (m: 0 at rest and homed, 1 moving,
2 unhomed; the error bound e; angles in urad), saved every PERSIST_MS while
moving, when the MA comes to rest, and with every record the link writes.
"""

import link as L
import ma_act as A
import ma_cal as C
import proto
import protodef as P
from drive import Loco, Rot
from loc import MISSED, OK, Loc
from ma_act import END, GRIP, HOME, MV, ROT

def _milli(x: float) -> int:
    return int(round(x * 1000.0))


class Board(L.LinkedBoard):
    def __init__(self, hal, cfg) -> None:
        self.hal = hal
        self.cfg = cfg
        n = cfg.N_JOINTS
        self.n = n
        self.nj = n - 1
        self.qsize = cfg.QSIZE
        self.period_ms = cfg.PERIOD_MS
        self.dt = cfg.PERIOD_MS / 1000.0
        self.hard = [[cfg.LIMITS[j][0], cfg.LIMITS[j][1], cfg.VMAX[j]] for j in range(n)]
        self.lim = [list(h) for h in self.hard]
        self.loc = Loc(cfg.LINK_LENGTHS_MM, cfg.WHEEL_MM_PER_COUNT, cfg.HALL_WINDOW_MM, cfg.SLIP_MAX)
        self.loco = Loco(cfg)
        self.rot = Rot(cfg, self.nj)
        C.init(self)                     # MAG, WHEEL and the gains as set (ma_cal.py: calibration)
        self.theta = [0.0] * self.nj     # the board's estimate of every joint angle, mrad
        self.speed = 0.0                 # MA speed from the encoder rate, mm/s
        self.unhomed = True
        self.held = False
        self.queue: list = []            # actions not begun: (id, verb, args)
        self.act = None                  # the action under way: [id, verb, args, phase, t_ms, travel0]
        self.limit_to = None             # d to move to before the next action (a narrowed range)
        self._k = cfg.SPEED_TICKS
        self._hist = [0] * self._k
        self._hi = 0
        self._c = 0
        self._g = 0
        self._still = 0                  # ms of effort without a wheel count
        self._still_rot = 0
        self._fe = 0                     # ms of following error
        self._settle = 0                 # ms an action has been settled at its end
        self._saved_ms = 0
        self._saved_c = 0
        self._saved_g = 0
        self._moving = False
        self._moved = False              # the wheel / the gear counted this period
        self._turned = False
        self._level = 0                  # hall level this period
        self._mag_now = 0                # magnet re-zeroed at this period, 0: none
        # Trace hook on_done(id, args), called with every completed action and the
        # arguments it was queued with (as arm.py's on_done): the emulator's log.
        self.on_done = None
        self.verbs = {"MV": self._cmd_mv, "ROT": self._cmd_rot, "GRIP": self._cmd_grip,
                      "HOME": self._cmd_home, "END": self._cmd_end, "GAIN": self._cmd_gain, "SETLIM": self._cmd_setlim,
                      "MAG": self._cmd_mag, "WHEEL": self._cmd_wheel, "RELAY": self._cmd_relay}
        self.motion_verbs = [MV, ROT, GRIP, HOME, END, C.RELAY]
        self._sense_counts()
        self.link = L.BoardLink(hal, cfg, self)   # last: it calls restore(), hold_here(), sends BOOT

    def d(self) -> float:
        return self.loc.d()

    # ------------------------------------------------------------ verbs

    def _cmd_mv(self, v: list) -> list:
        lo, hi = self.lim[self.n - 1][0], self.lim[self.n - 1][1]
        if not lo <= v[1] <= hi:
            raise proto.ProtocolError(P.RANGE, "", "d")
        self._homed_for()
        return self._push(v[0], MV, v[1:])

    def _cmd_rot(self, v: list) -> list:
        j = v[1]
        if j > self.nj:
            raise proto.ProtocolError(P.RANGE, "", "joint")
        if not self.lim[j - 1][0] <= v[2] <= self.lim[j - 1][1]:
            raise proto.ProtocolError(P.RANGE, "", str(j))
        dl = self.lim[self.n - 1]
        if not dl[0] <= self.loc.r[j - 1] <= dl[1]:
            raise proto.ProtocolError(P.RANGE, "", "joint")
        self._homed_for()
        return self._push(v[0], ROT, v[1:])

    def _cmd_grip(self, v: list) -> list:
        return self._push(v[0], GRIP, v[1:])

    def _cmd_home(self, v: list) -> list:
        return self._push(v[0], HOME, [])

    def _cmd_end(self, v: list) -> list:
        self._homed_for()
        return self._push(v[0], END, [])

    def _homed_for(self) -> None:
        """MV/ROT need a known d: homed, or a HOME ahead of them."""
        if not self.unhomed:
            return
        if self.act is not None and self.act[1] == HOME:
            return
        for a in self.queue:
            if a[1] == HOME:
                return
        raise proto.ProtocolError(P.UNHOMED)

    def _push(self, wid: int, verb: str, args: list) -> list:
        if len(self.queue) >= self.qsize:
            raise proto.ProtocolError(P.FULL)
        self.queue.append((wid, verb, args))
        self.link.queued = wid
        return []

    def _cmd_gain(self, v: list) -> list:
        C.gain(self, v[0], v[1], v[2], v[3])
        return []

    def _cmd_mag(self, v: list) -> list:
        return C.mag(self, v)

    def _cmd_wheel(self, v: list) -> list:
        return C.wheel(self, v)

    def _cmd_relay(self, v: list) -> list:
        return C.relay(self, v)

    def cal_text(self) -> list:
        return C.cal_text(self)

    def cal_apply(self, tokens) -> None:
        C.cal_apply(self, tokens)

    def _cmd_setlim(self, v: list) -> list:
        """Narrows coordinate j's range and speed within the hard ones; refused
        RANGE (detail: j) when a queued or running action would leave it."""
        j, lo, hi, vmax = v
        hard = self.hard[j - 1]
        if lo < hard[0] or hi > hard[1] or vmax > hard[2] or self._excludes(j, lo, hi) or self._strands(j, lo, hi):
            raise proto.ProtocolError(P.RANGE, "", str(j))
        self.lim[j - 1] = [lo, hi, vmax]
        if j == self.n:
            self._limit_d()
        return []

    def _excludes(self, j: int, lo: int, hi: int) -> bool:
        acts = list(self.queue)
        if self.act is not None:
            acts.append(self.act)
        for a in acts:
            if (a[1] == MV or a[1] == A.LIMIT) and j == self.n and not lo <= a[2][0] <= hi:
                return True
            if a[1] == ROT:
                if a[2][0] == j and not lo <= a[2][1] <= hi:
                    return True
                if j == self.n and not lo <= self.loc.r[a[2][0] - 1] <= hi:
                    return True
        return False

    def _strands(self, j: int, lo: int, hi: int) -> bool:
        """A joint angle the new range would leave outside, with no ROT of that
        joint queued or running to turn it in (the module docstring)."""
        if j == self.n:
            return False              # d: moved into the range instead (_limit_d)
        tol = self.cfg.ROT_TOL_MRAD
        if lo - tol <= self.theta[j - 1] <= hi + tol:
            return False
        acts = list(self.queue)
        if self.act is not None:
            acts.append(self.act)
        for a in acts:
            if a[1] == ROT and a[2][0] == j:
                return False
        return True

    def _limit_d(self) -> None:
        """At rest with d known and outside its range: the LIMIT move is due."""
        lo, hi = self.lim[self.n - 1][0], self.lim[self.n - 1][1]
        d = self.loc.d()
        tol = self.cfg.STOP_TOL_MM
        if self.act is None and self.loc.known and not lo - tol <= d <= hi + tol:
            self.limit_to = lo if d < lo else hi

    # ------------------------------------------------------------ BoardLink interface

    def free(self) -> int:
        return self.qsize - len(self.queue)

    def busy(self) -> bool:
        return self.act is not None or len(self.queue) > 0 or self.limit_to is not None

    def halt(self) -> None:
        self.queue = []
        self.act = None
        self.limit_to = None
        self.held = False
        self.loco.ramp.v = 0.0
        self.rot.ramp.v = 0.0
        self.loco.off()
        self.rot.off()

    def hold_here(self) -> None:
        self.halt()
        self.loco.reset(self.loc.d())
        j = self.rot.j
        if j:
            self.rot.ramp.reset(self.theta[j - 1])
        self._still = 0
        self._still_rot = 0
        self._fe = 0
        self._limit_d()

    def set_hold(self, on: bool) -> None:
        self.held = on

    def control(self, mode: int) -> None:
        if not self._sense(mode == L.DRIVE):
            return                                   # a localisation FAULT latched
        if mode == L.DRIVE:
            if self.act is None and (self.queue or self.limit_to is not None) and not self.held:
                A.begin(self)
            if self.act is not None:
                A.advance(self)
                if self.link.state == L.FAULT:
                    return
            self.hal.loco(self.loco.u)
            self.hal.rot(self.rot.u)
            if not A.check(self):
                return
        else:
            self.loco.off()
            self.rot.off()
            if mode == L.ZERO:
                self.hal.loco(0.0)
                self.hal.rot(0.0)
        self._persist()

    def telemetry(self) -> list:
        nj = self.nj
        q = [int(round(x)) for x in self.theta] + [int(round(self.loc.d()))]
        sp = [int(round(x)) for x in self.theta]
        j = self.rot.j
        if j and self._turning():
            sp[j - 1] = int(round(self.rot.ramp.x))
        sp.append(int(round(self.loco.ramp.x if self._driving() else self.loc.d())))
        u = [0] * nj + [_milli(self.loco.u)]
        if j:
            u[j - 1] = _milli(self.rot.u)
        return q + sp + u + [self.loc.jd(), int(round(self.loc.dlink())), int(round(self.speed))]

    def persist_extra(self) -> str:
        loc = self.loc
        m = 2 if self.unhomed else (1 if self._moving or self.busy() else 0)
        th = ",".join([str(int(round(x * 1000.0))) for x in self.theta])
        return "%d,%d,%d,%d,%s" % (m, loc.jd(), int(round(loc.dlink() * 1000.0)),
                                   int(round(loc.err() * 1000.0)), th)

    def restore(self, token) -> None:
        """At boot: the persisted token, or None (power on: d unknown, angles 0)."""
        self.unhomed = True
        try:
            parts = [int(x) for x in token.split(",")]
        except Exception:   # noqa: BLE001 - None or a bad token: power on
            return
        if len(parts) != 4 + self.nj or not 1 <= parts[1] <= self.nj:
            return
        self.theta = [p / 1000.0 for p in parts[4:]]
        d = self.loc.r[parts[1] - 1] + parts[2] / 1000.0
        if parts[0] == 0:
            self.loc.restore(d, parts[3] / 1000.0, self._c)
            self.unhomed = False
        else:
            self.loc.restore(d, parts[3] / 1000.0, self._c)   # the last belief, for telemetry
            self.loc.lose()

    # ------------------------------------------------------------ sensing

    def _sense_counts(self) -> None:
        c = self.hal.wheel_count()
        self._c = c
        self._g = self.hal.gear_count()
        for i in range(self._k):
            self._hist[i] = c
        self.loc.c = c
        self.loc.c_a = c

    def _sense(self, drive: bool) -> bool:
        """Encoders, hall edges, localisation -> False when it latched a FAULT."""
        hal = self.hal
        c = hal.wheel_count()
        g = hal.gear_count()
        level = hal.hall_level()
        loc = self.loc
        self._level = level
        self._mag_now = 0
        for ce in hal.hall_edges():
            kind, k = loc.edge(ce)
            if kind == OK and k:
                self._mag_now = k
                self.loco.ramp.x += loc.jump    # the reference moves with the estimate: no speed kick
                self.link.event("MAGNET", [k, ce - loc.c_home])   # and the edge's wheel count from home
            elif kind != OK:
                return self._loc_fault(kind, k, drive)
        kind, k = loc.update(c, level)
        if kind != OK:
            return self._loc_fault(kind, k, drive)
        k = self._k
        self.speed = (c - self._hist[self._hi]) * loc.q * 1000.0 / (k * self.period_ms)
        self._hist[self._hi] = c
        self._hi = (self._hi + 1) % k
        self._moved = c != self._c
        self._c = c
        if self.rot.j:
            j = self.rot.j
            self.theta[j - 1] = self.rot.track(self.theta[j - 1], g, hal.rot_load() if self.rot.sense else 0.0)
        self._turned = g != self._g
        self._g = g
        return True

    def _loc_fault(self, kind: int, k: int, drive: bool) -> bool:
        self.loc.lose()
        self.unhomed = True
        if not drive:
            return True       # latched or not yet allowed: it just no longer knows d
        reason = "MAGNET:MISSED" if kind == MISSED else "MAGNET:SPURIOUS"
        self.link.fault([self.n, k], reason)
        return False

    def _persist(self) -> None:
        moving = self.busy() or abs(self.speed) > self.cfg.SETTLE_MM_S
        now = self.hal.ticks_ms()
        due = self.hal.ticks_diff(now, self._saved_ms) >= self.cfg.PERSIST_MS
        if moving:
            if not self._moving or due:
                self._moving = True
                self._save(now)
        elif self._moving or (due and (self._c != self._saved_c or self._g != self._saved_g)):
            self._moving = False     # at rest: once, and again if a count still changed
            self._save(now)

    def _save(self, now: int) -> None:
        self._saved_ms = now
        self._saved_c = self._c
        self._saved_g = self._g
        self.link.save()

    def _driving(self) -> bool:
        return A.driving(self)

    def _turning(self) -> bool:
        return A.turning(self)
