"""The same plans over Modbus RTU (docs/modbus.md): `ModbusClient`, BoardClient's surface.

open_session picks it for a `modbus:` port (executor/session.py), so `armbridge run`,
`armbridge board info|state` and the demos run unchanged. What each BoardClient
piece becomes without the line protocol:

* connect: identity (firmware name, version, protocol, n, queue size) from input
  registers 32..45, state from 0..19, limits from holding 15..23, the watchdog from
  holding 37; the same checks against the robot (executor/handshake.py).
* execute: each waypoint one FC16 write of the window 100..104 (id dur q1 q2 q3)
  while the board has free slots (input 15, the credit); completion from the done id
  (input 14). A window write whose reply is lost is not written again blindly: the
  queued id (input 19) says whether it was taken, so no waypoint runs twice.
* telemetry: input registers 0..19 read at the session's rate, handed to
  on_telemetry as the line protocol's T (angles, set points, duties, and the board's
  own columns: syringe positions and end-stop bits); a done id that moves and a state
  that changes are handed to on_event as DONE and state events.
* commands: HOLD RESUME CLR through the command register, the e-stop as its
  ESTOP command (no out-of-band byte in Modbus), GAIN DBAND SETLIM WDOG BEND as
  holding writes, RATE sets the poll rate; STAT, LIM and PING are reads. Anything
  else is refused with VERB, as a board without the capability does.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.executor.faults import fault_text
from armbridge.executor.handshake import BoardInfo, check_identity, check_limits
from armbridge.executor.hold import HoldRequests, PausableDeadline, hold_turn, release_hold
from armbridge.executor.stream import Stream, Streaming
from armbridge.link import protocol as P
from armbridge.link.boardclock import BoardClock
from armbridge.link.modbus import ModbusError, RtuMaster, to_i16
from armbridge.link.protodef import LATCHED_STATES, STATES, TICKS_PERIOD
from armbridge.link.stats import LinkStats

# docs/modbus.md (firmware/arduino_pump/modbus.h)
HR_SETPOINT, HR_KP, HR_KI, HR_KD, HR_DBAND, HR_LIM_MIN, HR_BEND, HR_COMMAND, HR_WDOG, HR_ADDRESS = \
    0, 3, 6, 9, 12, 15, 24, 36, 37, 38
HR_WINDOW = 100
IR_STATUS, IR_STATUS_N, IR_IDENT, IR_IDENT_N = 0, 20, 32, 14
CMD = {"HOLD": 1, "RESUME": 2, "CLR": 3, "ESTOP": 4, "LINE": 5}
NONE = 0xFFFF
N = 3  # the register map is laid out for three joints
EX_BUSY, EX_VALUE, EX_FAILURE = 6, 3, 4


def latch_text(code: int) -> str | None:
    """Input register 13: 0 none, 1 e-stop, 2 watchdog, 16 + j following error of joint j."""
    return {0: None, 1: "ESTOP", 2: "WDOG"}.get(code, f"FOLLOW:{code - 16}" if 17 <= code <= 16 + N else
                                                  f"reason {code}")


class ModbusClient(Streaming):
    """A plan runner over Modbus RTU to one board, with BoardClient's public surface."""

    speed = 1.0
    estop_out_of_band = False  # the e-stop is a register write: between two transactions

    def __init__(self, port, robot, session: int | None = None, *,
                 on_telemetry: Callable[[float, P.Telemetry], None] | None = None,
                 on_event: Callable[[float | None, P.Event], None] | None = None,
                 on_error: Callable[[float | None, str], None] | None = None,
                 connect_timeout: float = 5.0, master: RtuMaster | None = None,
                 interrupt: Callable[[], None] | None = None, guard: object = None) -> None:
        self.port = port
        self.robot = robot
        self.session = session  # no sessions in Modbus: kept for the console's --session
        self.master = master if master is not None else port.master
        self.now = self.master.now
        self.on_telemetry, self.on_event, self.on_error = on_telemetry, on_event, on_error
        self.connect_timeout = connect_timeout
        self.interrupt = interrupt  # called before every wait: may raise to end the call (a link engine's abort)
        self.stats = LinkStats()
        self.board_clock = BoardClock()
        self.info: BoardInfo | None = None
        self.state: str | None = None
        self.last_event: str | None = None
        self.fault_reason: str | None = None
        self.rate = 50  # telemetry polls per second (RATE)
        self.free = 0
        self.done_id: int | None = None
        self.queued_id: int | None = None
        self.board_time = 0.0
        self._base = 0
        self._stream: Stream | None = None
        self._live = False
        self._next_poll = 0.0
        self._bseq = 0
        self._hold_requests = HoldRequests()  # request_hold, from any thread (executor/hold.py)
        self._held = False  # HOLD written, RESUME not yet

    # ------------------------------------------------------------------ views
    @property
    def connected(self) -> bool:
        return self._live

    # ------------------------------------------------------------------ reads
    def _read_input(self, address: int, count: int) -> list[int]:
        self.stats.lines_sent += 1
        return self.master.read_input(address, count)

    def poll(self) -> P.Telemetry:
        """Input registers 0..19 as a T line: callbacks, done id, free slots, state."""
        r = self._read_input(IR_STATUS, IR_STATUS_N)
        ms = ((r[17] << 16) | r[18]) % TICKS_PERIOD
        t = self.board_clock(ms)
        self.board_time = t
        state = STATES[r[12]] if r[12] < len(STATES) else f"STATE{r[12]}"
        done = None if r[14] == NONE else r[14]
        self.free, self.queued_id = r[15], None if r[19] == NONE else r[19]
        self._bseq += 1
        msg = P.Telemetry(self._bseq, ms, state, done, r[15],
                          np.array([to_i16(x) for x in r[0:3]], float) / 1000.0,
                          np.array([to_i16(x) for x in r[3:6]], float) / 1000.0,
                          np.array([to_i16(x) for x in r[6:9]], float) / 1000.0,
                          (*r[9:12], r[16]))
        if state != self.state:
            if state in LATCHED_STATES:
                self.fault_reason = self._reason(r[13])
            if self.state is not None:
                kind = self._state_event(self.state, state)
                if kind is not None:
                    self._event(t, ms, kind, (self._reason(r[13]) or "",) if kind in LATCHED_STATES else ())
        self.state = state
        if done is not None and done != self.done_id:
            if self._stream is not None:
                idx = self._stream.mark_done(done, t)
                if idx is not None:
                    self._event(t, ms, "DONE", (str(done), str(r[15])))
                    if idx + 1 < self._stream.next_wp:  # the next one starts as this one ends
                        self._stream.mark_start(self._stream.wid(idx + 1), t)
        self.done_id = done
        if self.on_telemetry is not None:
            self.on_telemetry(t, msg)
        return msg

    @staticmethod
    def _state_event(old: str, new: str) -> str | None:
        """The line protocol's event for a state change seen by polling (EVENTS names)."""
        if new in LATCHED_STATES or new == "HOLD":
            return new
        if old in LATCHED_STATES:
            return "CLEAR"
        return "RESUME" if old == "HOLD" else None

    def _reason(self, code: int) -> str | None:
        """Input register 13's first cause in words (executor/faults.py)."""
        token = latch_text(code)
        if token is None or token == "ESTOP":
            return token
        names = list(self.robot.joint_names) if self.robot is not None else []
        return fault_text(token, (), lambda j: f"joint {j}" + (f" ({names[j - 1]})" if 1 <= j <= len(names) else ""),
                          lambda j: "rad")

    def _event(self, t: float, ms: int, kind: str, args: tuple[str, ...]) -> None:
        self.last_event = kind
        if self.on_event is not None:
            self.on_event(t, P.Event(self._bseq, ms, kind, args))

    # ------------------------------------------------------------------ connect
    def connect(self, timeout: float | None = None) -> BoardInfo:
        """Identity, state and limits by reads; checked against the robot (None: protocol only)."""
        try:
            ident = self._read_input(IR_IDENT, IR_IDENT_N)
        except ModbusError as exc:
            raise ArmbridgeError(f"the board did not give its identity over Modbus: {exc}") from None
        name = b"".join(bytes([w >> 8, w & 0xFF]) for w in ident[0:8]).split(b"\0")[0].decode("ascii", "replace")
        version = ".".join(str(x) for x in ident[8:11])
        tel = self.poll()
        wdog = self.master.read_holding(HR_WDOG, 1)[0]
        info = BoardInfo(fw=name, version=version, proto=ident[11], n=ident[12], qsize=ident[13], rate=self.rate,
                         wdog_ms=wdog, done=tel.done, queued=self.queued_id, state=tel.state, free=tel.free)
        check_identity(info, self.robot)
        if info.n != N:
            raise ArmbridgeError(f"the board has {info.n} joints; the Modbus register map is laid out for {N}")
        newest = info.queued if info.queued is not None else info.done
        if newest is not None:
            self._base = newest + 1  # our ids follow on from the board's newest
        lim = self.master.read_holding(HR_LIM_MIN, 3 * N)
        info.limits_milli = [(to_i16(lim[j]), to_i16(lim[N + j]), lim[2 * N + j]) for j in range(N)]
        if self.robot is not None:
            check_limits(info.limits_milli, self.robot)
        self.info = info
        self._live = True
        return info

    # ------------------------------------------------------------------ commands
    def ask(self, verb: str, *args, timeout: float | None = None) -> P.Ok | P.Er:
        """One line-protocol verb done with registers: OK (payload as the line protocol's)
        or ER (VERB for a verb Modbus does not carry, RANGE/FULL/LATCHED for 03/06/04)."""
        a = [int(x) for x in args]
        try:
            payload = self._do(verb, a)
        except ModbusError as exc:
            if exc.code is None:
                raise ArmbridgeError(str(exc)) from None
            code = {EX_VALUE: P.RANGE, EX_BUSY: P.FULL, EX_FAILURE: P.LATCHED}.get(exc.code, P.ARGS)
            return P.Er(0, None, code, P.ERROR_NAMES[code],
                        (f"modbus exception {exc.code:02d}",))
        if payload is None:
            return P.Er(0, None, P.VERB, "VERB", (verb,))
        return P.Ok(0, 0, self.free, tuple(str(x) for x in payload))

    def _do(self, verb: str, a: list[int]) -> list | None:
        m = self.master
        self.stats.commands += 1
        if verb in ("HOLD", "RESUME", "CLR"):
            m.write_register(HR_COMMAND, CMD[verb])
            return []
        if verb == "STAT":
            t = self.poll()
            return [t.state, "-" if t.done is None else t.done, "-" if self.queued_id is None else self.queued_id,
                    t.ms]
        if verb == "PING":
            return [self.poll().ms]
        if verb == "RATE" and len(a) == 1:
            self.rate = a[0]
            return []
        if verb == "LIM" and len(a) == 1 and 1 <= a[0] <= N:
            r = m.read_holding(HR_LIM_MIN + a[0] - 1, 2 * N + 1)
            return [a[0], to_i16(r[0]), to_i16(r[N]), r[2 * N]]
        if verb == "GAIN" and len(a) == 4 and 1 <= a[0] <= N:
            for base, v in zip((HR_KP, HR_KI, HR_KD), a[1:]):
                m.write_register(base + a[0] - 1, v)
            return []
        if verb == "DBAND" and len(a) == 2 and 1 <= a[0] <= N:
            m.write_register(HR_DBAND + a[0] - 1, a[1])
            return []
        if verb == "SETLIM" and len(a) == 4 and 1 <= a[0] <= N:
            for k, v in enumerate(a[1:]):
                m.write_register(HR_LIM_MIN + k * N + a[0] - 1, v)
            return []
        if verb == "WDOG" and len(a) == 1:
            m.write_register(HR_WDOG, a[0])
            return []
        if verb == "BEND" and len(a) == 5 and 1 <= a[0] <= N:
            m.write_registers(HR_BEND + 4 * (a[0] - 1), a[1:])
            return []
        return None

    def command(self, verb: str, *args, timeout: float | None = None) -> P.Ok:
        ans = self.ask(verb, *args, timeout=timeout)
        if isinstance(ans, P.Er):
            raise ArmbridgeError(f"the board refused {verb} {' '.join(map(str, args))} over Modbus: {ans.code} "
                                 f"{ans.name} {' '.join(ans.detail)}".rstrip())
        return ans

    def can(self, verb: str, *args, timeout: float | None = None) -> bool:
        ans = self.ask(verb, *args, timeout=timeout)
        if isinstance(ans, P.Er) and ans.code == P.VERB:
            return False
        if isinstance(ans, P.Er):
            raise ArmbridgeError(f"the board refused {verb}: {ans.code} {ans.name}")
        return True

    def request_hold(self, on: bool) -> None:
        """From any thread: HOLD (True) or RESUME (False) through the command register at
        execute's next turn (BoardClient.request_hold)."""
        self._hold_requests.request(on)

    def _error(self, t: float | None, text: str) -> None:
        if self.on_error is not None:
            self.on_error(t, text)

    def estop(self) -> None:
        """ESTOP through the command register (to this board; broadcast if it does not answer)."""
        try:
            self.master.write_register(HR_COMMAND, CMD["ESTOP"], retries=1)
        except ModbusError:
            self.master.broadcast_register(HR_COMMAND, CMD["ESTOP"])

    def set_rate(self, hz: int) -> None:
        self.rate = int(hz)

    def settle_tolerance(self, n: int):
        """The dead band the run's settle times use (executor/settle.py), read from the board:
        holding 12..14 and the calibrations 24..35."""
        from armbridge.executor.settle import board_tolerance

        band = self.master.read_holding(HR_DBAND, n)
        return board_tolerance(band, [to_i16(x) for x in self.master.read_holding(HR_BEND, 4 * n)], n)

    def stat(self) -> tuple[str, int | None, int | None, float]:
        t = self.poll()
        return t.state, t.done, self.queued_id, self.board_time

    def drain(self, seconds: float, until: Callable[[], bool] | None = None, *, resync: bool = True) -> None:
        """Poll the board for `seconds` or until `until()` (`resync`: as BoardClient's; Modbus has none)."""
        end = self.now() + seconds
        while self.now() < end and not (until is not None and until()):
            self._tick()

    def _tick(self) -> None:
        """Poll the board when the rate says so (at least 4 times a watchdog period)."""
        if self.interrupt is not None:
            self.interrupt()
        period = 1.0 / self.rate if self.rate > 0 else 0.25
        if self.info is not None:
            period = min(period, self.info.wdog_ms / 4000.0)
        now = self.now()
        if now >= self._next_poll:
            self._next_poll = now + period
            self.poll()
        else:
            self.master.idle(min(0.002, self._next_poll - now))

    # ------------------------------------------------------------------ streaming
    def execute(self, durations_ms: Sequence[int], q_milli: Sequence[Sequence[int]],
                on_progress: Callable[[int], None] | None = None, timeout: float | None = None, *,
                verb: str = "W", pen: Sequence[int] | None = None,
                commands: Sequence[tuple[str, Sequence[int]]] | None = None) -> None:
        """Waypoints through the window under the free-slot credit until the last is done."""
        if not self.connected:
            raise ArmbridgeError("not connected: call connect() first")
        if self.robot is None:
            raise ArmbridgeError("this session has no robot: a plan needs one (open the session with the plan's "
                                 "robot)")
        if verb != "W" or pen is not None or commands is not None:
            raise ArmbridgeError(f"over Modbus a plan is joint waypoints only (verb {verb}, pen flags and actions "
                                 "have no registers): run it over the line protocol")
        stream = Stream(durations_ms, q_milli, self._base, on_progress)
        self._stream = stream
        deadline = PausableDeadline(self.now, timeout if timeout is not None else
                                    30.0 + 5.0 * sum(stream.durations) / 1000.0)
        self.poll()
        self._held = self.state == "HOLD"
        try:
            while not stream.finished:
                if self.state in LATCHED_STATES:
                    why = {"ESTOP": "an e-stop latched", "WDOG": "its watchdog fired (no valid frame in time)",
                           "FAULT": f"FAULT latched, {self.fault_reason or 'reason not known'}"}[self.state]
                    raise ArmbridgeError(f"the board stopped: {why}; {stream.progress()}")
                hold_turn(self, self._hold_requests)  # HOLD / RESUME through the command register
                while stream.next_wp < stream.k and self.free > 0:
                    if not self._send_waypoint(stream):
                        break
                deadline.tick(self._held or self.state == "HOLD")
                if deadline.passed():
                    raise ArmbridgeError(f"the plan did not finish in time: {stream.progress()}, board state "
                                         f"{self.state}")
                self._tick()
            release_hold(self)
        finally:
            stream.on_progress = None
            self._base += stream.k

    def _send_waypoint(self, stream: Stream) -> bool:
        """One FC16 of the window; False when the board is busy (queue full)."""
        i = stream.next_wp
        wid = stream.wid(i)
        _, args = stream.commands[i]
        regs = [wid, *args]
        for attempt in range(1 + self.master.retries):
            self.stats.lines_sent += 1
            self.stats.waypoint_lines += 1
            try:
                self.master.write_registers(HR_WINDOW, regs, retries=0)
                break
            except ModbusError as exc:
                if exc.code == EX_BUSY:
                    self.free = 0
                    return False
                if exc.code is not None:
                    self.poll()
                    why = {EX_VALUE: "a value is outside the board's limits",
                           EX_FAILURE: f"it is latched in {self.state}"}.get(exc.code, str(exc))
                    raise ArmbridgeError(f"the board refused waypoint {i} (window id {wid}): {why}; "
                                         f"{stream.progress()}") from None
                self.stats.timeouts += 1
                self.poll()  # no reply: was it queued? the queued id says
                if self.queued_id == wid or (self.done_id is not None and stream.index_of(
                        self.done_id, i, i) is not None):
                    break
        else:
            raise ArmbridgeError(f"the board did not answer the window write of waypoint {i}; {stream.progress()}")
        stream.next_wp += 1
        if i == 0:  # the board time of the poll just before: a lower bound
            stream.mark_start(wid, self.board_time)
        self.stats.waypoints_sent += 1
        self.stats.waypoints_acked += 1
        self.free -= 1
        return True
