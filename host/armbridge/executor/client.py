"""The host side of protocol v2 (docs/protocol.md): one board, one session.

`BoardClient(port, robot)` puts three pieces together:

* link/arq.py, the session layer: numbered commands, window, retransmission,
  answers, credits, epochs, keep-alive, line statistics;
* executor/handshake.py: HELLO until answered, identity and limit checks;
* executor/stream.py: one plan's waypoints under credit, done/start times,
  where to resume after a resync.

It is synchronous and single-threaded: every public method runs a loop that
reads the port with short waits, dispatches board lines and sends what is due.
Telemetry, events and errors go to the callbacks as they arrive. Most callers
open it through `executor.session.open_session`, which also applies the
latch policy.

    client = BoardClient(port, robot, on_telemetry=..., on_event=..., on_error=...)
    info = client.connect()                 # HELLO until answered, LIM j, checks
    client.command("RATE", 50)              # one command, answered or ArmbridgeError
    client.execute(durations_ms, q_milli)   # streams waypoints until the last is DONE
    client.request_hold(True)               # from any thread: HOLD at execute's next turn (False: RESUME)
    client.estop()                          # the 0x98 byte, at once

Time: every timer and timeout runs on `clock` (seconds; default the port's
`clock` attribute when it has one, e.g. an emulator K times faster than the
wall clock, else time.monotonic).

Resync: a BOOT line, a NOSESSION error, silence or a confused seq -> HELLO with
the same session and the next epoch; the reply's `done` (and `queued`, when the
board kept its queue) says where the plan stands; the rest is resent with new
seqs and RATE is set again. A routine new epoch (before seqs would repeat) is
the same HELLO, counted apart. A board that latches ESTOP/WDOG/FAULT, or
refuses a waypoint, stops the run with an ArmbridgeError that says why (for a
FAULT: the joint and its following error).
"""
from __future__ import annotations

import random
import time
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from typing import Any

from armbridge.errors import ArmbridgeError
from armbridge.executor.faults import fault_text
from armbridge.executor.handshake import BoardInfo, check_identity, check_limits, hello, parse_hello, read_limits
from armbridge.executor.hold import HoldRequests, PausableDeadline, hold_turn, release_hold
from armbridge.executor.signals import holding
from armbridge.executor.stream import Stream, Streaming
from armbridge.link import protocol as P
from armbridge.link.arq import RENEWAL, Arq
from armbridge.link.stats import LinkStats
from armbridge.link.boardclock import BoardClock
from armbridge.link.protodef import LATCHED_STATES

__all__ = ["BoardClient", "BoardInfo", "BoardClock", "LinkStats", "LATCHED_STATES"]


def _session_number(port) -> int:
    """A random session number; from the emulator's seed for a lockstep emulator, whose seeded
    runs must repeat bit for bit (the HELLO line's length depends on the number)."""
    emu = getattr(port, "emulator", None)
    if emu is not None and getattr(emu, "speed", 1.0) == 0:
        return random.Random(f"armbridge-session:{emu.seed}").randint(1, 65535)
    return random.randint(1, 65535)


class BoardClient(Streaming):
    """A protocol v2 session with one board over `port` (read(n), write(b), in_waiting).

    `robot` None: no plan (the board console): connect() checks the protocol
    version only and learns n and the limits; execute() is refused. `interrupt`:
    called before every wait for the board, may raise to end the call (a link
    engine's abort); `guard`: what holds stop signals off while bytes read are
    split into lines (executor/signals.py `holding`, for a client in the main
    thread)."""

    estop_out_of_band = True  # the e-stop is one byte, written whatever else is in flight

    # Durations given to drain() and friends are on the client's clock, which
    # already runs at the link's speed. Callers that still divide by `speed`
    # get the right answer from 1.0; remove once none does.
    speed = 1.0

    def __init__(
        self,
        port,
        robot,
        session: int | None = None,
        *,
        on_telemetry: Callable[[float, P.Telemetry], None] | None = None,
        on_event: Callable[[float | None, P.Event], None] | None = None,
        on_error: Callable[[float | None, str], None] | None = None,
        baud: int | None = None,
        connect_timeout: float = 5.0,
        silence_timeout: float | None = None,
        clock: Callable[[], float] | None = None,
        max_epoch_commands: int = P.MAX_EPOCH_COMMANDS,
        interrupt: Callable[[], None] | None = None,
        guard: Callable[[], AbstractContextManager] = holding,
    ) -> None:
        self.session = int(session) if session is not None else _session_number(port)
        if not 1 <= self.session <= 65535:
            raise ValueError(f"session {session} outside 1..65535")
        if clock is None:
            clock = getattr(port, "clock", None)
            clock = clock if callable(clock) else time.monotonic
        self.now = clock
        self.port = port
        self.robot = robot
        self.on_telemetry = on_telemetry
        self.on_event = on_event
        self.on_error = on_error
        self.connect_timeout = connect_timeout
        self.arq = Arq(port, clock=clock, baud=baud, on_line=self._on_line, on_note=lambda text: self._error(None, text),
                       silence_timeout=silence_timeout, max_epoch_commands=max_epoch_commands, guard=guard,
                       interrupt=interrupt)
        self.board_clock = BoardClock()
        self.info: BoardInfo | None = None
        self.calibration: Any = None   # executor/calcheck.Calibration, set by open_session
        self.state: str | None = None  # last state seen (HELLO, BOOT, telemetry, STAT, events)
        self.last_event: str | None = None
        self.fault_reason: str | None = None  # a latch's cause in words (EV FAULT, then STAT's reason)
        self._fault_args: tuple[str, ...] = ()  # EV FAULT's `c v`
        self._estop_wanted = False  # an e-stop sent and not yet reported by the board
        self._rate: int | None = None  # telemetry rate to restore after a resync
        self._base = 0  # waypoints streamed in this session before the current plan
        self._stream: Stream | None = None  # the current (or last) plan
        self._streaming = False
        self._hold_requests = HoldRequests()  # request_hold, from any thread (executor/hold.py)
        self._held = False  # HOLD answered OK, RESUME not yet
        self._hold_lost = False

    # ------------------------------------------------------------------ views
    @property
    def stats(self) -> LinkStats:
        return self.arq.stats

    @property
    def connected(self) -> bool:
        return self.arq.live

    def _error(self, t: float | None, text: str) -> None:
        if self.on_error is not None:
            self.on_error(t, text)

    # ------------------------------------------------------------------ board lines
    def _on_line(self, msg) -> None:
        """T, EV and BOOT lines from the session layer."""
        stream = self._stream
        if isinstance(msg, P.Telemetry):
            t = self.board_clock(msg.ms)
            self.state = msg.state
            if msg.state == "ESTOP":
                self._estop_wanted = False
            if msg.done is not None and stream is not None:
                stream.mark_done(msg.done, t)
            self.arq.idle_credit(msg.free)
            if self.on_telemetry is not None:
                self.on_telemetry(t, msg)
        elif isinstance(msg, P.Event):
            t = self.board_clock(msg.ms)
            self._on_board_event(t, msg)
            if self.on_event is not None:
                self.on_event(t, msg)
        elif isinstance(msg, P.Boot):
            self.last_event = "BOOT"
            self.state = msg.state
            self._error(None, f"board booted: {msg.fw} {msg.version} protocol {msg.proto}, state {msg.state}")
            if self._estop_wanted and msg.state != "ESTOP":
                self._error(None, "the board booted without the e-stop latched: e-stop sent again")
                self._write_estop()
            if self.on_event is not None:
                self.on_event(None, P.Event(msg.bseq, -1, "BOOT", (msg.fw, msg.version, str(msg.proto), msg.state)))

    def _on_board_event(self, t: float, ev: P.Event) -> None:
        self.last_event = ev.kind
        stream = self._stream
        try:
            wid = int(ev.args[0]) if ev.kind in ("DONE", "START") and ev.args else None
        except ValueError:
            wid = None
        if ev.kind == "DONE" and wid is not None and stream is not None:
            if stream.mark_done(wid, t) is not None and len(ev.args) > 1:
                try:
                    self.arq.idle_credit(int(ev.args[1]))
                except ValueError:
                    pass
        elif ev.kind == "START" and wid is not None and stream is not None:
            stream.mark_start(wid, t)
        elif ev.kind == "SLOW":
            self.stats.slow_events += 1
        elif ev.kind in LATCHED_STATES:
            self.state = ev.kind
            if ev.kind == "ESTOP":
                self._estop_wanted = False
            if ev.kind == "FAULT":  # `c v`; the reason token comes with STAT
                self._fault_args = tuple(ev.args)
                self.fault_reason = self._fault_text(None)

    def _fault_text(self, reason: str | None) -> str:
        """The latch's reason in words (executor/faults.py), with EV FAULT's `c v` when seen."""
        return fault_text(reason, self._fault_args, self._joint, self._unit)

    def _joint(self, j: int) -> str:
        """'joint 2 (elbow)', or 'joint 2' without a robot."""
        names = list(self.robot.joint_names) if self.robot is not None else []
        return f"joint {j} ({names[j - 1]})" if 1 <= j <= len(names) else f"joint {j}"

    def _unit(self, j: int) -> str:
        units = list(getattr(self.robot, "joint_units", ())) if self.robot is not None else []
        return units[j - 1] if 1 <= j <= len(units) else "rad"

    # ------------------------------------------------------------------ connect
    def connect(self, timeout: float | None = None) -> BoardInfo:
        """HELLO until answered, LIM of every joint, identity and limits checked
        against the robot (robot None: version only). ArmbridgeError names what differs."""
        ok = hello(self.arq, self.session, timeout if timeout is not None else self.connect_timeout)
        info = parse_hello(ok)
        check_identity(info, self.robot)
        self.arq.joints = info.n
        self.state = info.state
        # Same session as a board that ran waypoints already (an earlier run):
        # our ids follow on from its newest, so its `done` never names one of ours.
        newest = info.queued if info.queued is not None else info.done
        if newest is not None and self._stream is None:
            self._base = newest + 1
        # 8 keep-alives a watchdog period: on a lossy link (1 % of bytes damaged) four lost in a
        # row were a real risk for an idle queue (a MASR action list sent whole); eight are not.
        self.arq.keepalive = min(0.25, info.wdog_ms / 8000.0)
        self.arq.live = True
        info.limits_milli = read_limits(self.command, info.n)
        if self.robot is not None:
            try:
                check_limits(info.limits_milli, self.robot)
            except ArmbridgeError:
                self.arq.live = False
                raise
        self.info = info
        return info

    def _resync(self) -> None:
        arq = self.arq
        reason = arq.need_resync or "resync"
        routine = reason == RENEWAL
        if routine:
            self.stats.epoch_renewals += 1
        else:
            self.stats.resyncs += 1
            self._error(None, f"resync: {reason}")
        info = parse_hello(hello(arq, self.session, self.connect_timeout))
        self.state = info.state
        self._hold_lost = self._held and info.state != "HOLD"  # a board that reset: held again (hold.py)
        stream = self._stream if self._streaming else None
        if stream is not None:
            stream.resume(info.done, info.queued, reason)
        if routine:
            self._error(None, f"epoch {arq.epoch} opened (seqs never repeat within one)")
            return
        where = f", resuming at waypoint {stream.next_wp}" if stream is not None else ""
        self._error(None, f"resynced: board done={info.done if info.done is not None else '-'}{where}")
        if self._rate is not None:
            self.command("RATE", self._rate)

    def _room(self, end: float, what: str) -> None:
        """Until a command may be issued: resync when asked, wait out a full epoch."""
        arq = self.arq
        while not arq.can_issue():
            if arq.need_resync is not None:
                self._resync()
                continue
            if self.now() > end:
                raise ArmbridgeError(f"the board did not answer in time to send {what}")
            arq.loop_once()

    # ------------------------------------------------------------------ commands
    def command(self, verb: str, *args, timeout: float | None = None) -> P.Ok:
        """Send one command and wait for its answer (retransmitting as needed).
        ER -> ArmbridgeError naming the command and the refusal."""
        ans = self.ask(verb, *args, timeout=timeout)
        if isinstance(ans, P.Er):
            raise ArmbridgeError(f"the board refused {verb} {' '.join(map(str, args))}: "
                                 f"{ans.code} {ans.name} {' '.join(ans.detail)}".rstrip())
        return ans

    def can(self, verb: str, *args, timeout: float | None = None) -> bool:
        """Whether the board has a capability: the command is sent for real (so pick
        arguments that are harmless, e.g. PEN 0), OK -> True, ER VERB -> False; any
        other refusal -> ArmbridgeError."""
        ans = self.ask(verb, *args, timeout=timeout)
        if isinstance(ans, P.Er):
            if ans.code == P.VERB:
                return False
            raise ArmbridgeError(f"the board refused {verb} {' '.join(map(str, args))}: "
                                 f"{ans.code} {ans.name} {' '.join(ans.detail)}".rstrip())
        return True

    def ask(self, verb: str, *args, timeout: float | None = None) -> P.Ok | P.Er:
        """Send one command and wait for its answer, OK or ER (retransmitting as needed)."""
        if timeout is None:
            timeout = self.connect_timeout
        arq = self.arq
        end = self.now() + timeout
        ans = None
        while ans is None:
            self._room(end, verb)
            cmd = arq.issue(verb, *args, keep=True)
            while (ans := arq.answer_of(cmd)) is None:
                if arq.need_resync is not None:
                    self._resync()
                    end = self.now() + timeout
                    break  # issue it again in the new epoch
                if self.now() > end:
                    raise ArmbridgeError(f"the board did not answer {verb} within {timeout:.1f} s")
                arq.loop_once()
        return ans

    def estop(self) -> None:
        """The out-of-band e-stop byte, written at once; and again at every BOOT that comes
        before the board reports ESTOP (a byte that reached it before its receiver was on,
        during its boot, is lost in the hardware: docs/protocol.md §2)."""
        self._estop_wanted = True
        self._write_estop()

    def request_hold(self, on: bool) -> None:
        """From any thread: hold (True) or resume (False) the plan that `execute` streams; it sends
        HOLD or RESUME at its next turn, answered (a refusal, e.g. LATCHED, goes to on_error;
        nothing is cleared). The plan's deadline does not count while the board is held."""
        self._hold_requests.request(on)

    def _write_estop(self) -> None:
        self.port.write(P.ESTOP_BYTE)
        try:
            flush = getattr(self.port, "flush", None)
            if flush is not None:
                flush()
        except Exception:  # noqa: BLE001 - the byte is written; flushing is best effort
            pass

    def settle_tolerance(self, n: int):
        """The dead band the run's settle times use, or None: the line protocol has no query
        for it, so the firmware's config says (executor/settle.py)."""
        from armbridge.executor.settle import settle_tolerance

        return settle_tolerance(self.info.fw, n) if self.info is not None else None

    def set_rate(self, hz: int) -> None:
        """Telemetry rate (0..100 Hz); restored after a resync."""
        self.command("RATE", int(hz))
        self._rate = int(hz)

    def stat(self) -> tuple[str, int | None, int | None, float]:
        """STAT -> (state, done id, queued id, board time s); a latched FAULT's
        reason (STAT's fifth field) lands in `fault_reason`."""
        p = self.command("STAT").payload
        self.state = p[0]
        if p[0] in LATCHED_STATES and len(p) > 4 and p[4] != "-":  # the first cause (an ESTOP keeps it)
            self.fault_reason = self._fault_text(p[4])
        done = None if p[1] == "-" else int(p[1])
        queued = None if p[2] == "-" else int(p[2])
        return p[0], done, queued, self.board_clock(int(p[3]))

    def drain(self, seconds: float, until: Callable[[], bool] | None = None, *, resync: bool = True) -> None:
        """Keep the link serviced for `seconds` (telemetry keeps flowing to the
        callbacks, resyncs and new epochs happen as needed), or until `until()`.
        `resync` False: read and dispatch board lines only, never a HELLO (whose
        own timeout would overrun `seconds`): the wait after an e-stop."""
        end = self.now() + seconds
        while self.now() < end and not (until is not None and until()):
            if resync and self.arq.need_resync is not None:
                self._resync()
                continue
            self.arq.loop_once(min(0.01, max(0.0, end - self.now())))

    # ------------------------------------------------------------------ streaming
    def execute(
        self,
        durations_ms: Sequence[int],
        q_milli: Sequence[Sequence[int]],
        on_progress: Callable[[int], None] | None = None,
        timeout: float | None = None,
        *,
        verb: str = "W",
        pen: Sequence[int] | None = None,
        commands: Sequence[tuple[str, Sequence[int]]] | None = None,
    ) -> None:
        """Stream waypoints (W id dur q...; with verb="X", q_milli holds x y (um)
        theta (mrad) and the board solves them) under credits and return when the
        last one is DONE. `pen`: a flag per waypoint, sent as modal PEN lines
        (the board must have a pen servo: see can("PEN", 0)). Ids continue across
        the plans of a session. `commands`: one (verb, arguments after the id) per
        waypoint instead (the MASR actuator's MV/ROT actions; durations_ms then only
        time them). `timeout` (clock seconds) defaults to 30 s + 5 x the plan's duration."""
        if not self.connected:
            raise ArmbridgeError("not connected: call connect() first")
        if self.robot is None:
            raise ArmbridgeError("this session has no robot: a plan needs one (open the session with the plan's "
                                 "robot)")
        stream = Stream(durations_ms, q_milli, self._base, on_progress, verb=verb, pen=pen, commands=commands)
        self._stream, self._streaming = stream, True
        self._held = self.state == "HOLD"
        arq = self.arq
        planned = sum(stream.durations) / 1000.0
        deadline = PausableDeadline(self.now, timeout if timeout is not None else 30.0 + 5.0 * planned)
        try:
            while not stream.finished:
                if arq.need_resync is not None:
                    self._resync()
                    continue
                self._check_state(stream)
                hold_turn(self, self._hold_requests)
                stream.fill(arq)
                if arq.refused:
                    raise stream.refusal(*arq.refused.pop(0), self.state)
                deadline.tick(self._held or self.state == "HOLD")
                if deadline.passed():
                    raise ArmbridgeError(f"the plan did not finish in time: {stream.progress()}, "
                                         f"board state {self.state}")
                arq.loop_once()
            release_hold(self)  # held as the last waypoint finished: nothing is left to move
        finally:
            self._streaming = False
            stream.on_progress = None
            self._base += stream.k

    def _check_state(self, stream: Stream) -> None:
        if self.state in LATCHED_STATES:
            if self.state == "FAULT":
                try:
                    self.stat()  # its reason: what EV FAULT's `c v` mean
                except ArmbridgeError:
                    pass
            why = {
                "ESTOP": "an e-stop latched",
                "WDOG": "its watchdog fired (no valid line in time)",
                "FAULT": f"FAULT latched, {self.fault_reason or 'reason not known'}",
            }[self.state]
            raise ArmbridgeError(f"the board stopped: {why}; {stream.progress()}")
