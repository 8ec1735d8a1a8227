"""Board logic of the 3R planar servo arm: Board(hal, cfg).

poll() is one pass of the main loop: bytes from the UART -> LineReader ->
(e-stop at once | line -> decode -> session rules -> verb) and then the
control tick when it is due. tick() reads the joints, advances the
trajectory, runs one PID per joint, writes the outputs, checks the watchdog
and the following error, and sends telemetry. See docs/protocol.md.

`hal` is the duck-typed HAL of docs/architecture.md; `cfg` is the config
module (firmware/esp32/config.py) or any object with its attribute names. The
ones Board reads: FW_NAME, FW_VERSION, PROTO_VERSION, N_JOINTS, LIMITS_MRAD,
VMAX_MRAD_S, PERIOD_MS, QSIZE, TELEMETRY_HZ, WDOG_MS, PID_KP, PID_KI, PID_KD,
PID_KFF, FOLLOW_ERR_MRAD, FOLLOW_ERR_MS (pins and ADC/PWM calibration are
read by hal_esp32 only).
"""

import proto
import session as sess
from pid import PID
from traj import Traj

IDLE = "IDLE"
RUN = "RUN"
HOLD = "HOLD"
ESTOP = "ESTOP"
WDOG = "WDOG"
FAULT = "FAULT"
LATCHED_STATES = (ESTOP, WDOG, FAULT)

TICKS_MASK = 0x3FFFFFFF   # ticks_ms wraps at 2**30 (MicroPython), so do board times
_PERSIST_TAG = "AB1"


def _wid(x: int):
    """A waypoint id for a line: "-" when there is none (-1)."""
    return "-" if x < 0 else x


def _milli(x: float) -> int:
    return int(round(x * 1000.0))


class Board:
    def __init__(self, hal, cfg) -> None:
        self.hal = hal
        self.cfg = cfg
        n = cfg.N_JOINTS
        self.n = n
        self.period_ms = cfg.PERIOD_MS
        self.hard = [[cfg.LIMITS_MRAD[j][0], cfg.LIMITS_MRAD[j][1], cfg.VMAX_MRAD_S[j]]
                     for j in range(n)]
        self.lim = [list(h) for h in self.hard]   # [min, max, vmax] now in force
        self.state = IDLE
        self.rate = cfg.TELEMETRY_HZ
        self.wdog_ms = cfg.WDOG_MS
        self.reader = proto.LineReader(proto.MAX_HOST_LINE)
        self.link = sess.Session()
        self.traj = Traj(n, cfg.QSIZE, [h[2] for h in self.hard])
        self.pids = [PID(cfg.PID_KP[j], cfg.PID_KI[j], cfg.PID_KD[j], cfg.PID_KFF[j])
                     for j in range(n)]
        self.q = [0.0] * n        # measured positions, rad
        self.u = [0.0] * n        # outputs, [-1, 1]
        self._fe_ms = [0] * n     # time each joint's following error has been too big
        self._telem_acc = 0
        self._events: list = []   # events raised by a command, sent after its reply
        self.session_id, self.done = self._load_persist()
        # Trace hook, called with every completed waypoint id (events coalesce
        # them per tick); the emulator keeps the board's own log with it.
        self.on_done = None
        self.queued = -1          # id of the last accepted waypoint, -1: none
        self._verbs = {
            "HELLO": self._cmd_hello, "LIM": self._cmd_lim, "W": self._cmd_w,
            "HOLD": self._cmd_hold, "RESUME": self._cmd_resume, "CLR": self._cmd_clr,
            "RATE": self._cmd_rate, "GAIN": self._cmd_gain, "SETLIM": self._cmd_setlim,
            "WDOG": self._cmd_wdog, "STAT": self._cmd_stat, "PING": self._cmd_ping,
        }
        now = hal.ticks_ms()
        self.last_rx = now
        self.next_tick = now
        self._stop_here()
        # The lone LF ends any line a reset cut short, so BOOT always decodes.
        self.hal.uart_write(b"\n")
        self._send(self.link.boot(cfg.FW_NAME, cfg.FW_VERSION, cfg.PROTO_VERSION))

    # ------------------------------------------------------------ main loop

    def poll(self) -> bool:
        """UART bytes in, lines handled, control tick if due. -> True if bytes came."""
        data = self.hal.uart_read()
        if data:
            for item in self.reader.feed(data):
                self._on_item(item)
        now = self.hal.ticks_ms()
        late = self.hal.ticks_diff(now, self.next_tick)
        if late >= 0:
            if late >= self.period_ms:   # too late: resync, no burst of ticks
                self.next_tick = (now + self.period_ms) & TICKS_MASK
            else:
                self.next_tick = (self.next_tick + self.period_ms) & TICKS_MASK
            self.tick()
        return bool(data)

    def tick(self) -> None:
        """One control period."""
        now = self.hal.ticks_ms()
        self.hal.read_positions(self.q)
        self._check_watchdog(now)
        if self.state not in LATCHED_STATES:
            self._advance()
        self._control()
        self._check_following()
        self._telemetry(now)

    # ------------------------------------------------------------ byte stream

    def _on_item(self, item) -> None:
        kind = item[0]
        if kind == "estop":
            self.estop()
        elif kind == "error":
            self._send(self.link.er("-", item[1]))
        else:
            self._on_line(item[1])

    def estop(self) -> None:
        """E-stop byte: outputs off, queue flushed, ESTOP latched, at once."""
        self.hal.outputs_off()
        self.traj.flush()
        self.traj.hold = False
        self.state = ESTOP
        for j in range(self.n):
            self.u[j] = 0.0
        self._send(self.link.ev(self._ms(), "ESTOP"))

    def _on_line(self, raw) -> None:
        try:
            seq, verb, args = proto.decode(raw)
        except proto.ProtoError as e:
            self._send(self.link.er("-", e.code))
            return
        self.last_rx = self.hal.ticks_ms()
        what = self.link.classify(seq, verb, verb == "HELLO" and args == [str(self.session_id)])
        if what == sess.EXEC:
            kind, fields = self._execute(seq, verb, args)
            if not (verb == "HELLO" and kind == "ER"):
                self.link.record(seq, kind, fields)
        elif what == sess.REPLAY:
            kind, fields = self.link.replay(seq)
        elif what == sess.FRESH or (what == sess.NOSESSION and verb in proto.READ_ONLY):
            kind, fields = self._execute(seq, verb, args)
        elif what == sess.NOSESSION:
            kind, fields = "ER", [seq, proto.NOSESSION, "NOSESSION"]
        else:
            kind, fields = "ER", [seq, proto.SEQ, "SEQ", self.link.expect]
        self._send(self.link.line(kind, fields))
        self._flush_events()

    def _execute(self, seq: int, verb: str, args):
        """Runs one command -> the answer (kind, fields) without the board seq."""
        try:
            values = proto.parse_command(verb, args, self.n)
            payload = self._verbs[verb](seq, values)
        except proto.ProtoError as e:
            fields = [seq, e.code, e.name]
            if e.detail:
                fields.append(e.detail)
            return "ER", fields
        return "OK", [seq, self.traj.free()] + payload

    # ------------------------------------------------------------ verbs

    def _cmd_hello(self, seq: int, v: list) -> list:
        if v[0] != self.session_id:
            self._new_session(v[0])
        self.link.hello(seq)
        c = self.cfg
        return [c.FW_NAME, c.FW_VERSION, c.PROTO_VERSION, self.n, self.traj.qsize,
                self.rate, self.wdog_ms, _wid(self.done), _wid(self.queued)]

    def _cmd_lim(self, seq: int, v: list) -> list:
        return [v[0]] + self.lim[v[0] - 1]

    def _cmd_w(self, seq: int, v: list) -> list:
        self._refuse_if_latched()
        targets = v[2:]
        for j in range(self.n):
            if not self.lim[j][0] <= targets[j] <= self.lim[j][1]:
                raise proto.ProtoError(proto.RANGE, "", str(j + 1))
        if not self.traj.push(v[0], v[1], targets):
            raise proto.ProtoError(proto.FULL)
        self.queued = v[0]
        if self.state == IDLE:
            self.state = RUN
        return []

    def _cmd_hold(self, seq: int, v: list) -> list:
        self._refuse_if_latched()
        if self.state != HOLD:
            self.state = HOLD
            self.traj.hold = True
            self._event("HOLD")
        return []

    def _cmd_resume(self, seq: int, v: list) -> list:
        self._refuse_if_latched()
        if self.state == HOLD:
            self.traj.hold = False
            self.state = RUN if self.traj.busy() else IDLE
            self._event("RESUME")
        return []

    def _cmd_clr(self, seq: int, v: list) -> list:
        if self.state in LATCHED_STATES:
            self.state = IDLE
            self._stop_here()
            self._event("CLEAR")
        return []

    def _cmd_rate(self, seq: int, v: list) -> list:
        self.rate = v[0]
        self._telem_acc = 0
        return []

    def _cmd_gain(self, seq: int, v: list) -> list:
        self.pids[v[0] - 1].set_gains(v[1] / 1000.0, v[2] / 1000.0, v[3] / 1000.0)
        return []

    def _cmd_setlim(self, seq: int, v: list) -> list:
        j, lo, hi, vmax = v
        hard = self.hard[j - 1]
        if lo < hard[0] or hi > hard[1] or vmax > hard[2]:
            raise proto.ProtoError(proto.RANGE)
        self.lim[j - 1] = [lo, hi, vmax]
        self.traj.vmax[j - 1] = vmax
        return []

    def _cmd_wdog(self, seq: int, v: list) -> list:
        self.wdog_ms = v[0]
        return []

    def _cmd_stat(self, seq: int, v: list) -> list:
        return [self.state, _wid(self.done), _wid(self.queued), self._ms()]

    def _cmd_ping(self, seq: int, v: list) -> list:
        return [self._ms()]

    def _refuse_if_latched(self) -> None:
        if self.state in LATCHED_STATES:
            raise proto.ProtoError(proto.LATCHED)

    def _new_session(self, sid: int) -> None:
        """A new session: empty queue, stop where the arm is, forget done/queued."""
        self.session_id = sid
        self.done = -1
        self.queued = -1
        self._stop_here()
        if self.state in (RUN, HOLD):
            self.state = IDLE
        self._save_persist()

    # ------------------------------------------------------------ control

    def _stop_here(self) -> None:
        """Empty queue; set point = measured position (clamped to the limits)."""
        self.hal.read_positions(self.q)
        self.traj.hold = False
        self.traj.set_point([_milli(x) for x in self.q])
        self._clamp_set_point()
        for p in self.pids:
            p.reset()
        for j in range(self.n):
            self._fe_ms[j] = 0

    def _advance(self) -> None:
        """One tick of the trajectory. Its events are coalesced so that short
        waypoints cannot flood the 115200-baud return lane: one DONE for the
        last waypoint completed in the tick (those before it are done too), and
        START only for a waypoint that starts from rest (otherwise it starts in
        the tick its predecessor is DONE)."""
        self.traj.hold = self.state == HOLD
        last_done = -1
        for e in self.traj.step(self.period_ms):
            if e[0] == "DONE":
                last_done = e[1]
                if self.on_done is not None:
                    self.on_done(last_done)
            elif e[0] != "START" or last_done < 0:
                self._send(self.link.ev(self._ms(), e[0], list(e[1:])))
        if last_done >= 0:
            self.done = last_done
            self._save_persist()
            self._send(self.link.ev(self._ms(), "DONE", [last_done, self.traj.free()]))
        if self.state == RUN and not self.traj.busy():
            self.state = IDLE
        self._clamp_set_point()

    def _clamp_set_point(self) -> None:
        sp = self.traj.sp
        for j in range(self.n):
            lo, hi = self.lim[j][0], self.lim[j][1]
            if sp[j] < lo:
                sp[j] = float(lo)
            elif sp[j] > hi:
                sp[j] = float(hi)

    def _control(self) -> None:
        u = self.u
        if self.state in (ESTOP, FAULT):    # drives stay off
            for j in range(self.n):
                u[j] = 0.0
            return
        if self.state == WDOG:              # zero effort, held
            for j in range(self.n):
                u[j] = 0.0
        else:
            dt = self.period_ms / 1000.0
            sp, vel = self.traj.sp, self.traj.vel
            for j in range(self.n):
                u[j] = self.pids[j].update(sp[j] / 1000.0, self.q[j], dt, vel[j] / 1000.0)
        self.hal.write_outputs(u)

    def _check_watchdog(self, now: int) -> None:
        if self.state in (RUN, HOLD) and self.hal.ticks_diff(now, self.last_rx) >= self.wdog_ms:
            self.traj.flush()
            self.traj.hold = False
            self.state = WDOG
            for j in range(self.n):
                self.u[j] = 0.0
            self.hal.write_outputs(self.u)
            self._send(self.link.ev(self._ms(), "WDOG"))

    def _check_following(self) -> None:
        if self.state in LATCHED_STATES:
            return
        limit = self.cfg.FOLLOW_ERR_MRAD
        for j in range(self.n):
            err = self.traj.sp[j] - self.q[j] * 1000.0
            if abs(err) > limit:
                self._fe_ms[j] += self.period_ms
                if self._fe_ms[j] >= self.cfg.FOLLOW_ERR_MS:
                    self._fault(j, int(err))
                    return
            else:
                self._fe_ms[j] = 0

    def _fault(self, j: int, err_mrad: int) -> None:
        self.hal.outputs_off()
        self.traj.flush()
        self.traj.hold = False
        self.state = FAULT
        for k in range(self.n):
            self.u[k] = 0.0
        self._send(self.link.ev(self._ms(), "FAULT", [j + 1, err_mrad]))

    def _telemetry(self, now: int) -> None:
        if self.rate <= 0:
            return
        self._telem_acc += self.rate * self.period_ms
        if self._telem_acc < 1000:
            return
        self._telem_acc -= 1000
        if self._telem_acc >= 1000:
            self._telem_acc = 0
        fields = [now & TICKS_MASK, self.state, _wid(self.done), self.traj.free()]
        fields += [_milli(x) for x in self.q]
        fields += [int(round(x)) for x in self.traj.sp]
        fields += [_milli(x) for x in self.u]
        self._send(self.link.line("T", fields))

    # ------------------------------------------------------------ output, persistence

    def _ms(self) -> int:
        return self.hal.ticks_ms() & TICKS_MASK

    def _send(self, data: bytes) -> None:
        self.hal.uart_write(data)

    def _event(self, kind: str, args=()) -> None:
        """An event caused by a command: sent right after the command's reply."""
        self._events.append((kind, list(args)))

    def _flush_events(self) -> None:
        for kind, args in self._events:
            self._send(self.link.ev(self._ms(), kind, args))
        self._events = []

    def _load_persist(self):
        """-> (session id, last done id); (0, -1) when nothing valid is stored."""
        try:
            data = self.hal.load_persist()
            parts = bytes(data).decode().split()
            if len(parts) == 3 and parts[0] == _PERSIST_TAG:
                return int(parts[1]), int(parts[2])
        except Exception:
            pass
        return 0, -1

    def _save_persist(self) -> None:
        text = "%s %d %d" % (_PERSIST_TAG, self.session_id, self.done)
        self.hal.save_persist(text.encode())
