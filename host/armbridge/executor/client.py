"""The host side of line protocol v1 (docs/protocol.md): one board, one session.

`BoardClient(port, robot)` is synchronous and single-threaded: every public
method runs a small loop that reads the port with short waits, dispatches board
lines, and sends what is due. Telemetry, events and errors are handed to the
callbacks as they arrive.

    client = BoardClient(port, robot, on_telemetry=..., on_event=..., on_error=...)
    info = client.connect()                 # HELLO until answered, LIM j, checks (§8)
    client.command("RATE", 50)              # one command, answered or ArmbridgeError
    client.execute(durations_ms, q_milli)   # streams waypoints until the last is DONE
    client.estop()                          # the 0x98 byte, at once

Reliability (§6-§8):

* Every command carries a seq; an answer (OK or ER) ends its life. Unanswered
  commands stay in a list in seq order and are sent again when
  (a) their retransmission timer runs out: go-back-N from it. The RTO starts
      at 4 x (command line + answer) time + 50 ms and then follows the measured
      answer times (Jacobson/Karels; Karn: no samples from retransmitted lines);
  (b) the board answers `ER SEQ E`: go-back-N from E, unless a retransmission
      of E is already on its way (answers to lines sent before it are stale);
  (c) the board reports a framing error (CRC/PARSE/LONG with seq `-`): the
      timers of the lines that have reached the board are cut to the time an
      answer needs (fast retransmit);
  (d) a later command is answered while an earlier one is not: its answer was
      lost; it is sent again and the board replays the answer from its ring
      without executing it a second time.
* Window: at most `cwnd` commands unanswered, `cwnd` <= MAX_WINDOW (below the
  board's 32-entry replay ring). A lost line halves it (not below MIN_WINDOW),
  each answer grows it by 1/cwnd.
* Credits (§7): at most FREE waypoints unacknowledged, FREE from the OK with
  the newest seq; a T or EV DONE line refreshes it only when nothing is
  unanswered.
* Resync (§8): a BOOT line, a NOSESSION error or silence -> HELLO with the same
  session; the reply's `done` (and `queued`, when the board kept its queue)
  says where the plan stands; the rest is resent with new seqs and RATE is set
  again. `done` = `-` after waypoints had completed is a power cycle:
  ArmbridgeError.
* Keep-alive (§9): PING when nothing was sent for a quarter of the watchdog
  time (at most 250 ms).
* A board that latches ESTOP/WDOG/FAULT, or refuses a waypoint, stops the run
  with an ArmbridgeError that says why.

Waypoint ids are the plan index mod 65536.
"""
from __future__ import annotations

import math
import random
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from armbridge.errors import ArmbridgeError
from armbridge.link import protocol as P

HELLO_INTERVAL_S = 0.25  # §8: HELLO every 250 ms until answered
READ_WAIT_S = 0.005  # the port's read timeout: the longest the loop waits for a byte
MAX_WINDOW = 24  # unanswered commands at most: the board's replay ring holds 32
# Smallest window after losses. Losses on a serial line are noise, not
# congestion: a few lines in flight keep loss detection fast (the next line's
# ER SEQ or answer reveals a lost line or a lost answer) while a go-back resends
# little. Measured on the emulator at 1% drop+corrupt+dup per byte: windows of
# 1/2/4/8 ran a 200-waypoint plan in 10.2/7.5/4.7/5.1 s.
MIN_WINDOW = 4
ID_MOD = 65536
TICKS_PERIOD = 1 << 30  # board ms wrap (MicroPython ticks_ms)

LATCHED_STATES = ("ESTOP", "WDOG", "FAULT")


@dataclass
class BoardInfo:
    """The board's identity and settings from the HELLO reply and LIM."""

    fw: str
    version: str
    proto: int
    n: int
    qsize: int
    rate: int
    wdog_ms: int
    done: int | None
    queued: int | None
    free: int
    limits_milli: list[tuple[int, int, int]] = field(default_factory=list)  # (min, max, vmax) per joint


@dataclass
class LinkStats:
    """What happened on the link during a session."""

    lines_sent: int = 0  # every line written, retransmissions included
    commands: int = 0  # distinct commands (seqs) issued
    retransmissions: int = 0  # lines written again (any verb)
    waypoints_sent: int = 0  # distinct waypoints sent at least once
    waypoint_lines: int = 0  # W lines written, retransmissions and resends included
    waypoints_acked: int = 0  # distinct waypoints answered OK
    timeouts: int = 0  # retransmission timer expiries
    seq_errors: int = 0  # ER SEQ answers
    board_framing_errors: int = 0  # ER - CRC/PARSE/LONG from the board (our lines damaged)
    host_line_errors: int = 0  # board lines the host could not decode (their lines damaged)
    board_lines_lost: int = 0  # gaps in the board's line counter
    nosession: int = 0
    resyncs: int = 0
    boots: int = 0
    pings: int = 0
    slow_events: int = 0
    window_cuts: int = 0  # congestion window halvings (lines lost on the way to the board)

    @property
    def waypoints_retransmitted(self) -> int:
        return self.waypoint_lines - self.waypoints_sent

    @property
    def line_errors(self) -> int:
        return self.board_framing_errors + self.host_line_errors


class _Cmd:
    __slots__ = ("n", "seq", "verb", "args", "data", "wp", "tx", "last_tx", "arrive_at", "order", "deadline",
                 "answer", "keep", "due")

    def __init__(self, n: int, verb: str, args: tuple, wp: int | None, keep: bool = False) -> None:
        self.n = n  # position in the host's own unbounded command count
        self.seq = n % P.SEQ_MOD
        self.verb = verb
        self.args = args
        self.data = P.encode(self.seq, verb, *args)
        self.wp = wp  # plan index for W
        self.tx = 0
        self.last_tx = 0.0
        self.arrive_at = 0.0  # when the board should have the latest transmission (wall clock)
        self.keep = keep  # keep the answer for command()
        self.due = True  # to be (re)transmitted when the window allows
        self.order = 0  # transmission order of the latest transmission
        self.deadline = math.inf
        self.answer: P.Ok | P.Er | None = None


class BoardClock:
    """Unwraps board milliseconds (mod 2**30) into seconds that never run backwards
    by more than a few ms; a board whose clock restarted (a reset on real hardware)
    is rebased to continue where it was."""

    def __init__(self) -> None:
        self.offset = 0
        self.last_raw: int | None = None

    def __call__(self, ms: int) -> float:
        if self.last_raw is not None:
            back = self.last_raw - ms
            if back > TICKS_PERIOD // 2:
                self.offset += TICKS_PERIOD  # wrapped
            elif back > 1000:
                self.offset += back  # clock restarted: continue from where we were
            elif back < -TICKS_PERIOD // 2:
                self.offset -= TICKS_PERIOD  # a late line from before a wrap
        if self.last_raw is None or ms > self.last_raw or self.last_raw - ms > 1000:
            self.last_raw = ms
        return (ms + self.offset) / 1000.0


def _link_speed(port) -> float:
    emu = getattr(port, "emulator", None)
    speed = getattr(emu, "speed", None) if emu is not None else None
    if isinstance(speed, (int, float)) and speed > 0:
        return float(speed)
    return 1.0


class BoardClient:
    """A protocol v1 session with one board over `port` (read(n), write(b), in_waiting)."""

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
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.port = port
        self.robot = robot
        if hasattr(port, "timeout"):
            port.timeout = READ_WAIT_S
        self.session = int(session) if session is not None else random.randint(1, 65535)
        if not 1 <= self.session <= 65535:
            raise ValueError(f"session {session} outside 1..65535")
        self.on_telemetry = on_telemetry
        self.on_event = on_event
        self.on_error = on_error
        self.now = clock
        self.connect_timeout = connect_timeout
        baud = baud or int(getattr(port, "baudrate", 0) or getattr(port, "baud", 0) or 115200)
        # A clock passed in already runs at the link's speed (open_session passes port.clock).
        self.speed = _link_speed(port) if clock is time.monotonic else 1.0
        self.byte_time = 10.0 / baud / self.speed  # wall seconds per byte (8N1)
        # Retransmission timeout, counted from when a line should have reached
        # the board: 4 x the time of a command line and its answer + 50 ms to
        # start with, then adapted to the measured answer times (Jacobson/Karels,
        # samples only from lines sent once: Karn), never below the time an
        # answer needs when it queues behind a telemetry line.
        line_pair = (P.MAX_COMMAND_LINE + 40) * self.byte_time
        self.rto_initial = 4 * line_pair + 0.050
        self.rto_min = (P.MAX_BOARD_LINE + P.MAX_COMMAND_LINE) * self.byte_time + 0.002
        self.rto = self.rto_initial
        self.rto_max = 0.5  # s: the longest back-off (a board that is rebooting)
        self._backoff = 1.0  # doubles on a timeout while the board is silent, 1 again on any answer
        self._srtt: float | None = None
        self._rttvar = 0.0
        # Time from a line reaching the board to its answer reaching us: the
        # answer may queue behind a telemetry line, plus the board's poll.
        self.answer_time = 2 * P.MAX_BOARD_LINE * self.byte_time + 0.010
        self.silence_timeout = silence_timeout if silence_timeout is not None else max(1.0, 10 * self.rto_initial)
        self.keepalive = 0.25 / self.speed
        self.stats = LinkStats()
        self.board_clock = BoardClock()
        self.info: BoardInfo | None = None
        self.connected = False
        self.state: str | None = None  # last state seen in telemetry or STAT
        self.last_event: str | None = None
        self.fault_reason: str | None = None  # from EV FAULT: joint and following error

        self._splitter = P.LineSplitter(P.MAX_BOARD_LINE)
        self._n = 1  # next command number (seq = n mod 65536)
        self._out: list[_Cmd] = []  # unanswered commands, in seq order
        self._tx_order = 0
        self._lane_free = 0.0  # when the bytes written so far have reached the board (estimate)
        # Window: unanswered commands at most. Halved (down to MIN_WINDOW) when a
        # line is lost, grown by 1/cwnd per answer, up to MAX_WINDOW.
        self.cwnd = float(MAX_WINDOW)
        self._last_cut = -math.inf
        self._last_send = -math.inf
        self._last_rx = self.now()  # latest valid board line
        self._last_bytes = self._last_rx  # latest byte of any kind from the board
        self._bseq: int | None = None
        self._credit_n = 0  # command number of the newest OK
        self._credit = 0  # FREE of that OK
        self._w_sent_n: list[tuple[int, int]] = []  # (command number, plan index) of W lines after _credit_n
        self._need_resync: str | None = None
        self._answers: dict[int, P.Ok | P.Er] = {}  # answers of commands sent with command()
        self._refused: list[tuple[_Cmd, P.Er]] = []  # ER answers not yet reported
        self._rate: int | None = None  # telemetry rate to restore after a resync
        # execute() state
        self._k = 0
        # Waypoint ids run on across the plans of one session, so a board's
        # `done` after a reset can never name a waypoint of an earlier plan.
        self._id_base = 0
        self._next_wp = 0  # next plan index to send
        self._done = -1  # highest plan index known completed
        self._acked: set[int] = set()
        self._sent_once: set[int] = set()
        self._completed_any = False
        self.done_times: dict[int, float] = {}  # plan index -> board time of its DONE
        self.start_times: dict[int, float] = {}  # plan index -> board time of its START
        self._on_progress: Callable[[int], None] | None = None

    # ------------------------------------------------------------------ byte I/O
    def _write(self, data: bytes) -> None:
        try:
            self.port.write(data)
        except OSError as exc:  # serial.SerialException is an OSError
            raise ArmbridgeError(f"cannot write to the port: {exc}") from None

    def _read_some(self, timeout: float) -> bytes:
        """Whatever has arrived, waiting at most about `timeout` s for the first byte
        (the port's own read timeout, set short in __init__, bounds the wait)."""
        port = self.port
        try:
            n = port.in_waiting
            if n:
                return port.read(n)
            if timeout <= 0:
                return b""
            data = port.read(1)
            if data:
                n = port.in_waiting
                if n:
                    data += port.read(n)
            return data
        except OSError as exc:  # serial.SerialException is an OSError
            raise ArmbridgeError(f"cannot read from the port: {exc}") from None

    def _error(self, t: float | None, text: str) -> None:
        if self.on_error is not None:
            self.on_error(t, text)

    # ------------------------------------------------------------------ sending
    def _issue(self, verb: str, *args, wp: int | None = None, keep: bool = False) -> _Cmd:
        cmd = _Cmd(self._n, verb, args, wp, keep)
        self._n += 1
        self.stats.commands += 1
        self._out.append(cmd)
        if wp is not None:
            self._w_sent_n.append((cmd.n, wp))
        self._send_due()
        return cmd

    def _send_due(self) -> None:
        """Transmit due commands, oldest first, while the window has room."""
        window = max(1, int(self.cwnd))
        inflight = sum(1 for c in self._out if not c.due)
        for cmd in self._out:
            if inflight >= window:
                return
            if cmd.due:
                self._transmit(cmd)
                inflight += 1

    def _loss(self) -> None:
        """A line was lost on the way to the board: halve the window (once per round trip)."""
        now = self.now()
        if now - self._last_cut > self.answer_time:
            self._last_cut = now
            self.cwnd = max(float(MIN_WINDOW), self.cwnd / 2)
            self.stats.window_cuts += 1

    def _transmit(self, cmd: _Cmd) -> None:
        now = self.now()
        if cmd.tx:
            self.stats.retransmissions += 1
        cmd.tx += 1
        cmd.due = False
        self._tx_order += 1
        cmd.order = self._tx_order
        cmd.last_tx = now
        self._lane_free = max(now, self._lane_free) + len(cmd.data) * self.byte_time
        cmd.arrive_at = self._lane_free
        cmd.deadline = cmd.arrive_at + min(self.rto_max, self.rto * self._backoff)
        self.stats.lines_sent += 1
        if cmd.wp is not None:
            self.stats.waypoint_lines += 1
            if cmd.wp not in self._sent_once:
                self._sent_once.add(cmd.wp)
                self.stats.waypoints_sent += 1
        self._last_send = now
        self._write(cmd.data)

    def _retransmit_from(self, first: _Cmd) -> None:
        """Go-back-N: send `first` and every later unanswered command again, in order."""
        go = False
        for cmd in self._out:
            if cmd is first:
                go = True
            if go:
                cmd.due = True
        self._loss()
        self._send_due()

    def _find(self, seq: int) -> _Cmd | None:
        for cmd in self._out:
            if cmd.seq == seq:
                return cmd
        return None

    # ------------------------------------------------------------------ receiving
    def _pump(self, timeout: float) -> None:
        """Read what arrives within `timeout` and dispatch every complete line."""
        data = self._read_some(timeout)
        if not data:
            return
        self._last_bytes = self.now()
        for item in self._splitter.feed(data):
            if isinstance(item, P.ProtocolError):
                self.stats.host_line_errors += 1
                self._error(None, f"board line dropped: {item}")
                continue
            if item in (b"\n", b"\r\n"):
                continue  # an empty line (the board starts its BOOT with one): not an error
            try:
                line = P.decode(item)
                msg = P.parse_board_line(line)
            except P.ProtocolError as exc:
                self.stats.host_line_errors += 1
                self._error(None, f"board line dropped: {exc}")
                continue
            self._last_rx = self.now()
            if self._bseq is not None:
                gap = (line.seq - self._bseq - 1) % P.SEQ_MOD
                if 0 < gap < 1000 and not isinstance(msg, P.Boot):
                    self.stats.board_lines_lost += gap
            self._bseq = line.seq
            self._dispatch(msg)

    def _dispatch(self, msg) -> None:
        if isinstance(msg, P.Telemetry):
            t = self.board_clock(msg.ms)
            self.state = msg.state
            if msg.done is not None:
                self._mark_done(msg.done, t, exact=False)
            if not self._unanswered():
                self._refresh_credit(msg.free)
            if self.on_telemetry is not None:
                self.on_telemetry(t, msg)
        elif isinstance(msg, P.Event):
            t = self.board_clock(msg.ms)
            self._on_board_event(t, msg)
            if self.on_event is not None:
                self.on_event(t, msg)
        elif isinstance(msg, P.Ok):
            self._on_answer(msg)
        elif isinstance(msg, P.Er):
            self._on_er(msg)
        elif isinstance(msg, P.Boot):
            self.stats.boots += 1
            self.last_event = "BOOT"
            self._error(None, f"board booted: {msg.fw} {msg.version} protocol {msg.proto}")
            if self.on_event is not None:
                self.on_event(None, P.Event(msg.bseq, -1, "BOOT", (msg.fw, msg.version, str(msg.proto))))
            if self.connected and self._need_resync is None:
                self._need_resync = "the board reset (BOOT)"

    def _unanswered(self) -> bool:
        return bool(self._out)

    def _refresh_credit(self, free: int) -> None:
        self._credit_n = self._n - 1
        self._credit = free
        self._w_sent_n = []

    def _on_board_event(self, t: float, ev: P.Event) -> None:
        self.last_event = ev.kind
        if ev.kind == "DONE" and ev.args:
            try:
                wid = int(ev.args[0])
            except ValueError:
                return
            idx = self._mark_done(wid, t, exact=True)
            if len(ev.args) > 1 and not self._unanswered() and idx is not None:
                try:
                    self._refresh_credit(int(ev.args[1]))
                except ValueError:
                    pass
        elif ev.kind == "START" and ev.args:
            try:
                idx = self._index_of(int(ev.args[0]), self._done + 1, self._next_wp - 1)
            except ValueError:
                idx = None
            if idx is not None:
                self.start_times.setdefault(idx, t)
        elif ev.kind == "SLOW":
            self.stats.slow_events += 1
        elif ev.kind in LATCHED_STATES:
            self.state = ev.kind
            if ev.kind == "FAULT":
                self.fault_reason = self._fault_text(ev.args)

    def _fault_text(self, args) -> str:
        """EV FAULT j err -> 'joint 2 (elbow): following error 412 mrad'."""
        try:
            j, err = int(args[0]), int(args[1])
        except (IndexError, ValueError):
            return "FAULT " + " ".join(args)
        names = list(self.robot.joint_names) if self.robot is not None else []
        name = f" ({names[j - 1]})" if 1 <= j <= len(names) else ""
        return f"joint {j}{name}: following error {err} mrad"

    def _index_of(self, wid: int, lo: int, hi: int) -> int | None:
        """The plan index in [lo, hi] whose id is wid, if any."""
        if hi < lo:
            return None
        i = lo + (wid - self._id_base - lo) % ID_MOD
        return i if i <= hi else None

    def _mark_done(self, wid: int, t: float, exact: bool) -> int | None:
        idx = self._index_of(wid, self._done, self._next_wp - 1)
        if idx is None:
            return None
        if idx > self._done:
            self._done = idx
            self._completed_any = True
            if self._on_progress is not None:
                self._on_progress(idx + 1)
        # From the event: exact; from telemetry: an upper bound (the DONE event was lost).
        self.done_times.setdefault(idx, t)
        return idx

    def _rtt_sample(self, cmd: _Cmd) -> None:
        if cmd.tx != 1:
            return  # Karn: an answer to a retransmitted line cannot be timed
        sample = max(0.0, self.now() - cmd.arrive_at)
        if self._srtt is None:
            self._srtt, self._rttvar = sample, sample / 2
        else:
            self._rttvar = 0.75 * self._rttvar + 0.25 * abs(self._srtt - sample)
            self._srtt = 0.875 * self._srtt + 0.125 * sample
        self.rto = min(self.rto_initial, max(self.rto_min, self._srtt + 4 * self._rttvar))

    def _on_answer(self, ok: P.Ok) -> None:
        cmd = self._find(ok.seq)
        if cmd is None:
            return  # a late duplicate of an answer we already have
        self._rtt_sample(cmd)
        self._settle(cmd, ok)
        if cmd.n > self._credit_n:
            self._credit_n = cmd.n
            self._credit = ok.free
            self._w_sent_n = [(n, i) for n, i in self._w_sent_n if n > cmd.n]
        if cmd.wp is not None and cmd.wp not in self._acked:
            self._acked.add(cmd.wp)
            self.stats.waypoints_acked += 1
        if cmd.tx == 1 or cmd.verb != "W":
            self.cwnd = min(float(MAX_WINDOW), self.cwnd + 1.0 / self.cwnd)
        self._lost_answers_before(cmd)

    def _settle(self, cmd: _Cmd, answer) -> None:
        self._backoff = 1.0  # the board answers
        cmd.answer = answer
        self._out.remove(cmd)
        if cmd.keep:
            self._answers[cmd.n] = answer
        elif isinstance(answer, P.Er):
            self._refused.append((cmd, answer))

    def _lost_answers_before(self, cmd: _Cmd) -> None:
        """Commands before `cmd` that were sent before it and are still unanswered
        were executed (the board answers in order): their answers were lost. Ask
        again; the board replays them."""
        again = False
        for other in self._out:
            if other.n >= cmd.n:
                break
            if other.order < cmd.order and not other.due:
                other.due = True
                again = True
        if again:
            self._send_due()

    def _on_er(self, er: P.Er) -> None:
        if er.seq is None:  # framing error of one of our lines: its seq is unknown
            self.stats.board_framing_errors += 1
            self._error(None, f"board: our line arrived damaged ({er.code} {er.name})")
            now = self.now()
            for c in self._out:
                if c.arrive_at <= now:
                    c.deadline = min(c.deadline, now + self.answer_time)
            return
        cmd = self._find(er.seq)
        if er.code == P.SEQ:
            self.stats.seq_errors += 1
            if cmd is None:
                return
            try:
                expect = int(er.detail[0])
            except (IndexError, ValueError):
                expect = None
            first: _Cmd | None = self._find(expect) if expect is not None else None
            if first is None:
                if expect is not None and expect == self._n % P.SEQ_MOD:
                    return  # the board expects our next new command: nothing is missing
                if not self._out or expect is None:
                    return
                # The board expects a command we do not have in flight: it was
                # answered (answer lost, then replayed?) - confusion; resync.
                if self._need_resync is None:
                    self._need_resync = f"the board expects seq {expect}, which is not in flight"
                return
            if self.now() < first.arrive_at + self.answer_time:
                return  # stale: a retransmission of `first` is on its way already
            # Commands before `first` are executed; ask for their answers again.
            self._lost_answers_before(first)
            self._retransmit_from(first)
            return
        if er.code == P.NOSESSION:
            self.stats.nosession += 1
            if self.connected and self._need_resync is None:
                self._need_resync = "the board has no session (NOSESSION)"
            if cmd is not None and not self.connected:
                self._settle(cmd, er)
            return
        if cmd is None:
            return
        self._settle(cmd, er)
        self._lost_answers_before(cmd)

    # ------------------------------------------------------------------ service
    def _service(self) -> None:
        """Retransmission timers, due commands and keep-alive."""
        self._send_due()
        now = self.now()
        try:
            waiting = self.port.in_waiting
        except OSError:
            waiting = 0
        for cmd in self._out if not waiting else ():  # read what has arrived before timing out
            if not cmd.due and cmd.deadline <= now:
                self.stats.timeouts += 1
                if now - self._last_bytes > self.rto_initial:
                    # Not a byte from the board (rebooting, unplugged): back off.
                    # A noisy link that still delivers bytes keeps the plain RTO.
                    self._backoff = min(self._backoff * 2, 64.0)
                self._error(None, f"no answer to seq {cmd.seq} ({cmd.verb}) in {now - cmd.last_tx:.3f} s: "
                                  "resending from it")
                self._retransmit_from(cmd)
                break
        if self.connected and not self._out and now - self._last_send > self.keepalive:
            self.stats.pings += 1
            self._issue("PING")
        if self.connected and now - self._last_rx > self.silence_timeout and self._need_resync is None:
            self._need_resync = f"the board was silent for {now - self._last_rx:.1f} s"

    def _loop_once(self, timeout: float = 0.005) -> None:
        # Wait no longer than the nearest retransmission deadline.
        if self._out:
            nearest = min((c.deadline for c in self._out if not c.due), default=math.inf) - self.now()
            timeout = max(0.0, min(timeout, nearest))
        self._pump(timeout)
        self._service()

    # ------------------------------------------------------------------ commands
    def command(self, verb: str, *args, timeout: float | None = None) -> P.Ok:
        """Send one command and wait for its answer (retransmitting as needed).
        ER -> ArmbridgeError naming the command and the refusal."""
        if timeout is None:
            timeout = self.connect_timeout
        cmd = self._issue(verb, *args, keep=True)
        end = self.now() + timeout
        while cmd.n not in self._answers:
            if self._need_resync is not None:
                self._resync()
                cmd = self._issue(verb, *args, keep=True)
                end = self.now() + timeout
                continue
            if self.now() > end:
                raise ArmbridgeError(f"the board did not answer {verb} within {timeout:.1f} s")
            self._loop_once()
        ans = self._answers.pop(cmd.n)
        if isinstance(ans, P.Er):
            raise ArmbridgeError(f"the board refused {verb} {' '.join(map(str, args))}: "
                                 f"{ans.code} {ans.name} {' '.join(ans.detail)}".rstrip())
        return ans

    def estop(self) -> None:
        """The out-of-band e-stop byte, written at once."""
        self.port.write(P.ESTOP_BYTE)
        try:
            flush = getattr(self.port, "flush", None)
            if flush is not None:
                flush()
        except Exception:  # noqa: BLE001 - the byte is written; flushing is best effort
            pass

    # ------------------------------------------------------------------ connect
    def _hello(self, timeout: float) -> P.Ok:
        """HELLO session every 250 ms until answered (§8). Everything before the
        answer is ignored except telemetry and events (handed to the callbacks)."""
        self._out.clear()
        self._w_sent_n = []
        cmd = _Cmd(self._n, "HELLO", (self.session,), None, keep=True)
        self._n += 1
        self.stats.commands += 1
        self._out.append(cmd)
        end = self.now() + timeout
        next_send = 0.0
        st = self.stats
        damaged_at_send = 0
        while True:
            now = self.now()
            if now > end:
                self._out.clear()
                raise ArmbridgeError(
                    f"no answer to HELLO from the board in {timeout:.1f} s: is it powered, on this port, "
                    "and speaking armbridge protocol 1?"
                )
            # Every 250 ms; at once when a damaged line arrives after our HELLO
            # reached the board (likely our HELLO or its answer).
            damaged = st.host_line_errors + st.board_framing_errors
            if now >= next_send or (damaged > damaged_at_send and now >= cmd.arrive_at):
                self._transmit(cmd)
                damaged_at_send = damaged
                cmd.deadline = math.inf  # paced by HELLO_INTERVAL_S, not the RTO
                next_send = now + HELLO_INTERVAL_S / self.speed
            self._pump(min(0.01, max(0.0, next_send - self.now())))
            ans = self._answers.pop(cmd.n, None)
            if isinstance(ans, P.Ok):
                self._out.clear()
                self._credit_n = cmd.n
                self._credit = ans.free
                self._w_sent_n = []
                self._last_rx = self.now()
                self._need_resync = None
                return ans
            if isinstance(ans, P.Er):
                self._out.clear()
                raise ArmbridgeError(f"the board refused HELLO {self.session}: {ans.code} {ans.name}")

    def _parse_hello(self, ok: P.Ok) -> BoardInfo:
        p = ok.payload
        if len(p) < 9:
            raise ArmbridgeError(f"the board's HELLO reply has {len(p)} fields, protocol 1 has 9: {' '.join(p)}")
        try:
            return BoardInfo(
                fw=p[0], version=p[1], proto=int(p[2]), n=int(p[3]), qsize=int(p[4]), rate=int(p[5]),
                wdog_ms=int(p[6]), done=None if p[7] == "-" else int(p[7]),
                queued=None if p[8] == "-" else int(p[8]), free=ok.free,
            )
        except ValueError:
            raise ArmbridgeError(f"the board's HELLO reply is malformed: {' '.join(p)}") from None

    def connect(self, timeout: float | None = None) -> BoardInfo:
        """Handshake (§8): HELLO until answered, LIM of every joint, identity and
        limits checked against the robot. ArmbridgeError names what differs."""
        ok = self._hello(timeout if timeout is not None else self.connect_timeout)
        info = self._parse_hello(ok)
        robot = self.robot
        if info.proto != P.PROTOCOL_VERSION:
            raise ArmbridgeError(
                f"the board speaks protocol {info.proto}, this armbridge speaks {P.PROTOCOL_VERSION} "
                f"(firmware {info.fw} {info.version})"
            )
        if robot is None:  # no plan (the board console): learn the limits, check nothing
            self.connected = True
            self.info = info
            self.keepalive = min(0.25, info.wdog_ms / 4000.0) / self.speed
            for j in range(info.n):
                ans = self.command("LIM", j + 1)
                try:
                    lo, hi, vmax = (int(x) for x in ans.payload[1:4])
                except ValueError:
                    raise ArmbridgeError(f"the board's LIM {j + 1} reply is malformed: {' '.join(ans.payload)}") from None
                info.limits_milli.append((lo, hi, vmax))
            self.state = "IDLE" if self.state is None else self.state
            return info
        if info.fw != robot.name:
            raise ArmbridgeError(f"the board runs firmware {info.fw!r} {info.version}, the plan is for robot "
                                 f"{robot.name!r}")
        if info.n != robot.n:
            raise ArmbridgeError(f"the board has {info.n} joints, robot {robot.name} has {robot.n}")
        self.connected = True
        self.info = info
        self.keepalive = min(0.25, info.wdog_ms / 4000.0) / self.speed
        want_lo = P.to_milli(robot.q_min)
        want_hi = P.to_milli(robot.q_max)
        want_v = P.to_milli(robot.v_max)
        problems = []
        for j in range(info.n):
            ans = self.command("LIM", j + 1)
            try:
                jj, lo, hi, vmax = (int(x) for x in ans.payload[:4])
            except ValueError:
                raise ArmbridgeError(f"the board's LIM {j + 1} reply is malformed: {' '.join(ans.payload)}") from None
            info.limits_milli.append((lo, hi, vmax))
            name = robot.joint_names[j]
            for what, board_v, want in (("min", lo, want_lo[j]), ("max", hi, want_hi[j]), ("vmax", vmax, want_v[j])):
                if abs(board_v - want) > 1:
                    unit = "mrad/s" if what == "vmax" else "mrad"
                    problems.append(f"joint {j + 1} ({name}) {what}: board {board_v} {unit}, robot {want} {unit}")
        if problems:
            self.connected = False
            raise ArmbridgeError(f"the board's limits differ from robot {robot.name}: " + "; ".join(problems))
        self.state = "IDLE" if self.state is None else self.state
        return info

    # ------------------------------------------------------------------ resync
    def _resync(self) -> None:
        reason = self._need_resync or "resync"
        self.stats.resyncs += 1
        self._error(None, f"resync: {reason}")
        ok = self._hello(self.connect_timeout)
        info = self._parse_hello(ok)
        if self._k:
            lo = max(self._done, 0)
            if info.done is None:
                if self._completed_any:
                    raise ArmbridgeError(
                        f"the board lost its session state ({reason}; HELLO says no waypoint done, "
                        f"{self._done + 1} had completed): it was power-cycled, so where the plan stands "
                        "is unknown. Stopped."
                    )
                done_idx = -1
            else:
                found = self._index_of(info.done, lo, self._next_wp - 1)
                if found is not None:
                    done_idx = found
                elif info.done == (self._id_base + self._done) % ID_MOD:
                    done_idx = self._done  # nothing new (at -1: the last waypoint of an earlier plan)
                else:
                    raise ArmbridgeError(
                        f"after a resync the board says waypoint id {info.done} is done, which this run "
                        f"has not sent (sent up to index {self._next_wp - 1}). Stopped."
                    )
            if done_idx > self._done:
                self._done = done_idx
                self._completed_any = True
                if self._on_progress is not None:
                    self._on_progress(done_idx + 1)
            resume = self._done + 1
            if info.queued is not None:  # the board kept its queue (no reset): resend after it
                q_idx = self._index_of(info.queued, max(self._done, 0), self._next_wp - 1)
                if q_idx is not None:
                    resume = max(resume, q_idx + 1)
            self._next_wp = resume
        self._error(None, f"resynced: board done={info.done if info.done is not None else '-'}, "
                          f"resuming at waypoint {self._next_wp}")
        if self._rate is not None:
            self.command("RATE", self._rate)

    def set_rate(self, hz: int) -> None:
        """Telemetry rate (0..100 Hz); restored after a resync."""
        self.command("RATE", int(hz))
        self._rate = int(hz)

    # ------------------------------------------------------------------ streaming
    def _credit_left(self) -> int:
        return self._credit - len(self._w_sent_n)

    def execute(
        self,
        durations_ms: Sequence[int],
        q_milli: Sequence[Sequence[int]],
        on_progress: Callable[[int], None] | None = None,
        timeout: float | None = None,
    ) -> None:
        """Stream waypoints (W id dur q...) under credits and return when the
        last one is DONE. Ids continue across the plans of a session: the
        first plan's waypoint i is id i, the next plan's ids follow on (mod 65536)."""
        if not self.connected:
            raise ArmbridgeError("not connected: call connect() first")
        if self.robot is None:
            raise ArmbridgeError("this session has no robot: a plan needs one (open the session with the plan's robot)")
        k = len(durations_ms)
        self._k = k
        self._next_wp = 0
        self._done = -1
        self._completed_any = False
        self._on_progress = on_progress
        planned = sum(durations_ms) / 1000.0
        deadline = self.now() + (timeout if timeout is not None else 30.0 + 5.0 * planned / self.speed)
        try:
            while self._done < k - 1:
                if self._need_resync is not None:
                    self._resync()
                    continue
                self._check_state()
                # Fill the window under credits.
                while (
                    self._next_wp < k
                    and self._credit_left() > 0
                    and len(self._out) < max(1, int(self.cwnd))
                    and self._need_resync is None
                ):
                    i = self._next_wp
                    self._issue("W", (self._id_base + i) % ID_MOD, int(durations_ms[i]), *q_milli[i], wp=i)
                    self._next_wp += 1
                self._check_refusals()
                if self.now() > deadline:
                    raise ArmbridgeError(
                        f"the plan did not finish in time: {self._done + 1} of {k} waypoints done, "
                        f"board state {self.state}"
                    )
                self._loop_once()
        finally:
            self._on_progress = None
            self._id_base = (self._id_base + k) % ID_MOD

    def _check_state(self) -> None:
        if self.state in LATCHED_STATES:
            kind = self.state
            why = {
                "ESTOP": "an e-stop latched",
                "WDOG": "its watchdog fired (no valid line in time)",
                "FAULT": f"FAULT latched, {self.fault_reason or 'a following error'}",
            }[kind]
            raise ArmbridgeError(f"the board stopped: {why}; {self._done + 1} of {self._k} waypoints done")

    def _check_refusals(self) -> None:
        """A refused W is fatal (RANGE, FULL, LATCHED ...): stop and say why."""
        if not self._refused:
            return
        cmd, er = self._refused.pop(0)
        what = f"waypoint {cmd.wp} (W seq {cmd.seq})" if cmd.verb == "W" else f"{cmd.verb} (seq {cmd.seq})"
        why = {
            P.RANGE: "a value is outside the board's limits",
            P.FULL: "its queue was full (host credit error)",
            P.LATCHED: f"it is latched in {self.state or 'ESTOP/WDOG/FAULT'}",
        }.get(er.code, "")
        detail = " ".join(er.detail)
        raise ArmbridgeError(
            f"the board refused {what}: {er.code} {er.name}{' ' + detail if detail else ''}"
            f"{' (' + why + ')' if why else ''}; {self._done + 1} of {self._k} waypoints done"
        )

    def stat(self) -> tuple[str, int | None, int | None, float]:
        """STAT -> (state, done id, queued id, board time s)."""
        ok = self.command("STAT")
        p = ok.payload
        state = p[0]
        self.state = state
        done = None if p[1] == "-" else int(p[1])
        queued = None if p[2] == "-" else int(p[2])
        t = self.board_clock(int(p[3]))
        return state, done, queued, t

    def drain(self, seconds: float, until: Callable[[], bool] | None = None) -> None:
        """Keep the link serviced for `seconds` (telemetry keeps flowing to the
        callbacks), or until `until()` is true."""
        end = self.now() + seconds
        while self.now() < end and not (until is not None and until()):
            self._loop_once(min(0.01, max(0.0, end - self.now())))

    @property
    def done_index(self) -> int:
        return self._done
