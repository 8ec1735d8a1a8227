"""The host's session layer of protocol v2 (docs/protocol.md): reliable commands
over a lossy byte link, with no knowledge of robots or plans.

`Arq(port, clock=...)` numbers commands, keeps them until answered, retransmits,
matches answers, counts credits and line statistics, and keeps the link alive.
It is synchronous: `loop_once()` reads what has arrived (a short wait on the
port), dispatches board lines, and sends what is due. OK and ER lines are its
own; T (once HELLO told n), EV and BOOT lines go up to `on_line`. Every timer
runs on `clock` (seconds): for an emulator running K times faster than the wall
clock, a clock that does too; the port's read timeout (READ_WAIT_S, wall)
only bounds a wait.

Rules:

* Reliability: every command carries a seq = its command number mod 65536;
  an answer (OK or ER) ends its life. Unanswered commands stay in a list in
  seq order (`out`); which of them are sent again, and how many may be
  unanswered at once (the window, `cwnd`), is link/recovery.py's.
* Credits: at most FREE waypoints (W lines) unacknowledged, FREE from the OK
  with the newest seq; a T or EV DONE line refreshes it (`idle_credit`) only
  when nothing is unanswered.
* Epochs: the HELLO that opens a session or a resync carries a new epoch, and
  every later line is framed with it (its CRC starts from the epoch), so a
  copy of a line from an earlier epoch fails its CRC on the board, however
  late it arrives. Within an epoch no seq may repeat: after
  `max_epoch_commands` (32768) commands the layer issues nothing more, and once
  everything is answered asks for a new epoch (`need_resync = RENEWAL`).
* Keep-alive: PING when nothing was sent for `keepalive` s (the upper layer
  sets it to an eighth of the board's watchdog, at most 250 ms).
* Resync requests (`need_resync`, a reason): a BOOT line, a NOSESSION error,
  silence, no answer to our lines while the board still talks (framing errors
  only: it checks another epoch), a board expecting a seq that is not in
  flight, a full epoch. The
  handshake (executor/handshake.py) acts on them.
* Interruptions: a stop signal reaches the executor as an exception that may
  come between any two bytecodes (executor/signals.py), and the e-stop's drain
  then reads on. Bytes read but not split would be lost, and the line they
  belong to would read as damaged, so the read (bounded by READ_WAIT_S) and
  the split run under `guard` (the executor's `holding`: a signal waits for
  the block's end). Split lines wait in a queue and are dispatched one at a
  time, so an exception from a callback leaves the lines after it for the next
  `pump`. A session served by a link engine (executor/engine.py) has no signals
  to hold off (they land in its caller's thread); its `interrupt` hook, called
  before every wait, ends a call the caller gave up. Writes are not guarded: one can block on a full device, and a line
  cut short is dropped by the board at the e-stop byte that follows it.
"""
from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext

from armbridge.errors import ArmbridgeError
from armbridge.link import protocol as P
from armbridge.link.recovery import Recovery
from armbridge.link.rto import RetransmitTimer
from armbridge.link.stats import LinkStats

READ_WAIT_S = 0.005  # the port's read timeout (wall clock): the longest one wait for a byte
RENEWAL = "a new epoch before seqs repeat"  # need_resync reason of a full epoch: routine, not a fault
_V1_FRAME = re.compile(rb"[\x20-\x7e]*\*[0-9A-F]{4}\r?\n?")  # a protocol 1 line (CRC-16)


class Cmd:
    """One command, from issue to answer."""

    __slots__ = ("n", "seq", "verb", "args", "data", "wp", "tx", "last_tx", "arrive_at", "order", "deadline",
                 "answer", "keep", "due")

    def __init__(self, n: int, verb: str, args: tuple, epoch: int, wp: int | None = None, keep: bool = False):
        self.n = n  # position in the host's own unbounded command count
        self.seq = n % P.SEQ_MOD
        self.verb = verb
        self.args = args
        self.data = P.encode(self.seq, verb, *args, epoch=epoch)  # HELLO: framed with epoch 0 by the codec
        self.wp = wp  # W: the waypoint's key, unique in the session (counted once in LinkStats)
        self.tx = 0
        self.last_tx = 0.0
        self.arrive_at = 0.0  # when the board should have the latest transmission
        self.keep = keep  # keep the answer for the caller (answer_of)
        self.due = True  # to be (re)transmitted when the window allows
        self.order = 0  # transmission order of the latest transmission
        self.deadline = math.inf
        self.answer: P.Ok | P.Er | None = None


class Arq:
    """Reliable, numbered commands to one board over `port` (read(n), write(b), in_waiting)."""

    def __init__(
        self,
        port,
        *,
        clock: Callable[[], float],
        baud: int | None = None,
        on_line: Callable[[object], None] | None = None,
        on_note: Callable[[str], None] | None = None,
        silence_timeout: float | None = None,
        max_epoch_commands: int = P.MAX_EPOCH_COMMANDS,
        guard: Callable[[], AbstractContextManager] = nullcontext,
        interrupt: Callable[[], None] | None = None,
    ) -> None:
        if not 2 <= max_epoch_commands <= P.MAX_EPOCH_COMMANDS:
            raise ValueError(f"max_epoch_commands {max_epoch_commands} outside 2..{P.MAX_EPOCH_COMMANDS}")
        self.port = port
        if hasattr(port, "timeout"):
            port.timeout = READ_WAIT_S
        self.now = clock
        self.on_line = on_line
        self.on_note = on_note
        self.guard = guard
        self.interrupt = interrupt  # called before every wait for the board: may raise to end it
        self.max_epoch_commands = max_epoch_commands
        baud = baud or int(getattr(port, "baudrate", 0) or getattr(port, "baud", 0) or 115200)
        self.byte_time = 10.0 / baud  # clock seconds per byte (8N1)
        self.timer = RetransmitTimer(self.byte_time)
        # From a line reaching the board to its answer reaching us: the answer
        # may queue behind a telemetry line, plus the board's poll.
        self.answer_time = 2 * P.MAX_BOARD_LINE * self.byte_time + 0.010
        self.silence_timeout = silence_timeout if silence_timeout is not None else max(1.0, 10 * self.timer.initial)
        self.keepalive = 0.25
        self.stats = LinkStats()
        self.live = False  # a session is open: keep-alive and silence detection run
        self.need_resync: str | None = None  # why the session must be resynchronised
        self.epoch = 0  # the epoch every non-HELLO line is framed with
        self.out: list[Cmd] = []  # unanswered commands, in seq order (the same list as recovery.out: never rebound)
        self.refused: list[tuple[Cmd, P.Er]] = []  # ER answers of commands nobody waits for
        self.joints: int | None = None  # the board's n, once HELLO said it (T lines' joint columns)

        self._splitter = P.LineSplitter(P.MAX_BOARD_LINE)
        # The first piece the port delivers may be the tail of a line the board
        # was sending when the port was opened: not a damaged line.
        self._first_piece = True
        self._n = 1  # next command number
        self._epoch_n = 1  # command number of the HELLO that opened the epoch
        self._tx_order = 0
        self._lane_free = 0.0  # when the bytes written so far have reached the board (estimate)
        self._last_send = -math.inf
        self.last_rx = self.now()  # latest valid board line
        self.last_answer = self.last_rx  # latest answer naming one of our seqs (OK, or ER with a seq)
        self._last_bytes = self.last_rx  # latest byte of any kind from the board
        self._bseq: int | None = None
        self._credit_n = 0  # command number of the newest OK
        self._credit = 0  # FREE of that OK
        self._w_sent_n: list[int] = []  # command numbers of W lines after _credit_n
        self._answers: dict[int, P.Ok | P.Er] = {}  # answers of keep commands
        self._pending: deque = deque()  # split lines not yet dispatched (after a HELLO answer, an exception)
        self._sent_wp: set[int] = set()  # waypoint keys sent / answered OK at least once
        self._acked_wp: set[int] = set()
        self.recovery = Recovery(self.out, self._transmit, self.now, self.stats, self.answer_time)

    @property
    def cwnd(self) -> float:
        """The window: how many commands may be unanswered (link/recovery.py)."""
        return self.recovery.cwnd

    # ------------------------------------------------------------------ byte I/O
    def write(self, data: bytes) -> None:
        try:
            self.port.write(data)  # unguarded: a write may block (a full device), a stop must not wait
        except OSError as exc:  # serial.SerialException is an OSError
            raise ArmbridgeError(f"cannot write to the port: {exc}") from None

    def _read_some(self, timeout: float) -> bytes:
        """Whatever has arrived, waiting at most about `timeout` for the first byte
        (the port's own short read timeout bounds the wait)."""
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

    def note(self, text: str) -> None:
        if self.on_note is not None:
            self.on_note(text)

    # ------------------------------------------------------------------ epochs
    def epoch_left(self) -> int:
        """Commands that may still be issued in this epoch."""
        return self._epoch_n + self.max_epoch_commands - self._n

    def can_issue(self) -> bool:
        return self.need_resync is None and self.epoch_left() > 0

    def new_hello(self, proto: int, session: int, epoch: int) -> Cmd:
        """A HELLO attempt (framed with epoch 0); everything unanswered is dropped:
        after the HELLO the board's reply says where things stand."""
        self.out.clear()
        self.recovery.settled()
        self._w_sent_n = []
        cmd = Cmd(self._n, "HELLO", (proto, session, epoch), 0, keep=True)
        self._n += 1
        self.stats.commands += 1
        self.out.append(cmd)
        return cmd

    def send_hello(self, cmd: Cmd) -> None:
        """Transmit a HELLO; it is paced by the handshake, not by the RTO."""
        self._transmit(cmd)
        cmd.deadline = math.inf

    def open_epoch(self, hello: Cmd, ok: P.Ok) -> None:
        """The board accepted `hello`: its epoch frames every later line."""
        self.epoch = int(hello.args[2])
        self._epoch_n = hello.n
        self.out.clear()
        self.recovery.settled()
        self._answers.clear()
        self._credit_n = hello.n
        self._credit = ok.free
        self._w_sent_n = []
        self.last_rx = self.last_answer = self.now()
        self.need_resync = None
        self.stats.epochs += 1

    def abandon(self) -> None:
        """Forget every unanswered command (a HELLO that failed)."""
        self.out.clear()
        self.recovery.settled()

    # ------------------------------------------------------------------ sending
    def issue(self, verb: str, *args, wp: int | None = None, keep: bool = False) -> Cmd:
        """A new command, sent as soon as the window allows."""
        if self.epoch_left() <= 0:
            raise RuntimeError("the epoch is full: open a new one (resync) before issuing")
        cmd = Cmd(self._n, verb, args, self.epoch, wp, keep)
        self._n += 1
        self.stats.commands += 1
        self.out.append(cmd)
        if wp is not None:
            self._w_sent_n.append(cmd.n)
        self.recovery.send_due()
        return cmd

    def answer_of(self, cmd: Cmd) -> P.Ok | P.Er | None:
        """The answer of a `keep` command, once (None while unanswered)."""
        return self._answers.pop(cmd.n, None)

    def _transmit(self, cmd: Cmd) -> None:
        now = self.now()
        st = self.stats
        if cmd.tx:
            st.retransmissions += 1
        cmd.tx += 1
        cmd.due = False
        self._tx_order += 1
        cmd.order = self._tx_order
        cmd.last_tx = now
        self._lane_free = max(now, self._lane_free) + len(cmd.data) * self.byte_time
        cmd.arrive_at = self._lane_free
        cmd.deadline = cmd.arrive_at + self.timer.timeout()
        st.lines_sent += 1
        if cmd.wp is not None:
            st.waypoint_lines += 1
            if cmd.wp not in self._sent_wp:  # a waypoint resent after a resync is a new command
                self._sent_wp.add(cmd.wp)
                st.waypoints_sent += 1
        if self.live and now - self._last_send > st.longest_quiet_s:
            st.longest_quiet_s = now - self._last_send
        self._last_send = now
        self.write(cmd.data)

    def _find(self, seq: int) -> Cmd | None:
        for cmd in self.out:
            if cmd.seq == seq:
                return cmd
        return None

    # ------------------------------------------------------------------ credits
    def credit_left(self) -> int:
        """Waypoints the board's queue can still take."""
        return self._credit - len(self._w_sent_n)

    def idle_credit(self, free: int) -> None:
        """FREE from a T or EV DONE line: trusted only when nothing is unanswered
        (otherwise an OK in flight may already count a W this line does not)."""
        if not self.out:
            self._credit_n = self._n - 1
            self._credit = free
            self._w_sent_n = []

    # ------------------------------------------------------------------ receiving
    def pump(self, timeout: float) -> None:
        """Read what arrives within `timeout` and dispatch every complete line.

        Dispatch stops after the answer to a HELLO: the lines after it (a DONE
        the board sent right after its reply) wait for the next call, so the
        handshake judges the reply's `done` before it learns of later news.
        Lines wait in `_pending` until dispatched (see Interruptions above)."""
        if self.interrupt is not None:
            self.interrupt()
        pending = self._pending
        if not pending:
            with self.guard():  # no exception between the bytes read and their split
                data = self._read_some(timeout)
                if data:
                    self._last_bytes = self.now()
                    pending.extend(self._splitter.feed(data))
        st = self.stats
        while pending:
            item = pending.popleft()
            first, self._first_piece = self._first_piece, False
            if isinstance(item, P.ProtocolError):
                st.host_line_errors += 1
                self.recovery.damaged()
                self.note(f"board line dropped: {item}")
                continue
            if item in (b"\n", b"\r\n"):
                continue  # an empty line (the board starts its BOOT with one): not an error
            try:
                line = P.decode(item)  # board lines: epoch 0
                # A T line before HELLO's reply told n: its 3n joint columns cannot be told
                # from the board's own columns after them (the pump's four). A whole line
                # passed its CRC, so it is no damage; it is only not read (msg None).
                early_t = line.verb == "T" and self.joints is None
                msg = None if early_t else P.parse_board_line(line, self.joints)
            except P.ProtocolError as exc:
                if _V1_FRAME.fullmatch(item):
                    st.v1_lines += 1
                if first:
                    self.note(f"the first bytes from the port were not a whole line (opened mid-line): {exc}")
                    continue
                st.host_line_errors += 1
                self.recovery.damaged()
                self.note(f"board line dropped: {exc}")
                continue
            self.last_rx = self.now()
            if self._bseq is not None:
                gap = (line.seq - self._bseq - 1) % P.SEQ_MOD
                if 0 < gap < 1000 and not isinstance(msg, P.Boot):
                    st.board_lines_lost += gap
            self._bseq = line.seq
            if msg is None:
                continue
            if isinstance(msg, P.Ok):
                if self._on_answer(msg) == "HELLO":
                    return
            elif isinstance(msg, P.Er):
                self._on_er(msg)
            else:
                if isinstance(msg, P.Boot):
                    st.boots += 1
                    if self.live and self.need_resync is None:
                        self.need_resync = "the board reset (BOOT)"
                if self.on_line is not None:
                    self.on_line(msg)

    def _rtt_sample(self, cmd: Cmd) -> None:
        if cmd.tx == 1:  # Karn: an answer to a retransmitted line cannot be timed
            self.timer.sample(max(0.0, self.now() - cmd.arrive_at))

    def _on_answer(self, ok: P.Ok) -> str | None:
        """Settle the command `ok` answers; returns its verb (None: no such command)."""
        self.last_answer = self.now()
        cmd = self._find(ok.seq)
        if cmd is None:
            return None  # a late duplicate of an answer we already have
        self._rtt_sample(cmd)
        self.recovery.answered(cmd)
        self._settle(cmd, ok)
        if cmd.n > self._credit_n:
            self._credit_n = cmd.n
            self._credit = ok.free
            self._w_sent_n = [n for n in self._w_sent_n if n > cmd.n]
        if cmd.wp is not None and cmd.wp not in self._acked_wp:
            self._acked_wp.add(cmd.wp)
            self.stats.waypoints_acked += 1
        self.recovery.grow(cmd)
        self.recovery.lost_answers_before(cmd)
        return cmd.verb

    def _settle(self, cmd: Cmd, answer) -> None:
        self.timer.answered()
        cmd.answer = answer
        self.out.remove(cmd)
        self.recovery.settled()
        if cmd.keep:
            self._answers[cmd.n] = answer
        elif isinstance(answer, P.Er):
            self.refused.append((cmd, answer))

    def _on_er(self, er: P.Er) -> None:
        if er.seq is None:  # framing error of one of our lines: its seq is unknown
            self.stats.board_framing_errors += 1
            self.recovery.damaged()
            self.note(f"board: our line arrived damaged ({er.code} {er.name})")
            self.recovery.framing_error()
            return
        self.last_answer = self.now()
        cmd = self._find(er.seq)
        if er.code == P.SEQ:
            self.stats.seq_errors += 1
            self.recovery.damaged()
            if cmd is not None:
                self._on_seq_error(er)
            return
        if er.code == P.NOSESSION:
            self.stats.nosession += 1
            if self.live and self.need_resync is None:
                self.need_resync = "the board has no session (NOSESSION)"
            if cmd is not None and not self.live:
                self._settle(cmd, er)
            return
        if cmd is None:
            return
        self._settle(cmd, er)
        self.recovery.lost_answers_before(cmd)

    def _on_seq_error(self, er: P.Er) -> None:
        try:
            expect = int(er.detail[0])
        except (IndexError, ValueError):
            return
        first = self._find(expect)
        if first is None:
            if expect == self._n % P.SEQ_MOD or not self.out:
                return  # the board expects our next new command: nothing is missing
            # The board expects a command we do not have in flight: confusion; resync.
            if self.need_resync is None:
                self.need_resync = f"the board expects seq {expect}, which is not in flight"
            return
        self.recovery.seq_error(first)

    # ------------------------------------------------------------------ service
    def service(self) -> None:
        """Retransmission timers, due commands, keep-alive, silence and epoch renewal."""
        self.recovery.send_due()
        now = self.now()
        try:
            waiting = len(self._pending) or self.port.in_waiting
        except OSError:
            waiting = 0
        for cmd in self.out if not waiting else ():  # read what has arrived before timing out
            if not cmd.due and cmd.deadline <= now:
                self.stats.timeouts += 1
                if now - self._last_bytes > self.timer.initial:
                    # Not a byte from the board (rebooting, unplugged): back off.
                    # A noisy link that still delivers bytes keeps the plain RTO.
                    self.timer.expired_in_silence()
                self.note(f"no answer to seq {cmd.seq} ({cmd.verb}) in {now - cmd.last_tx:.3f} s: "
                          + ("resending from it" if self.recovery.probing else "resending it"))
                self.recovery.timed_out(cmd)
                break
        if not self.live:
            return
        if not self.out and now - self._last_send > self.keepalive and self.can_issue():
            self.stats.pings += 1
            self.issue("PING")
        if now - self.last_rx > self.silence_timeout and self.need_resync is None:
            self.need_resync = f"the board was silent for {now - self.last_rx:.1f} s"
        talking = now - self.last_rx < 0.5 * self.silence_timeout  # (a silent board is the check above)
        if self.out and talking and now - self.last_answer > self.silence_timeout and self.need_resync is None:
            # Lines arrive but none of ours is answered, only framing errors: the board checks
            # our CRCs from another epoch (it reset and restored an older record, and its BOOT
            # was lost). Only a HELLO (framed from epoch 0) reaches it.
            self.need_resync = (f"no line of ours answered for {now - self.last_answer:.1f} s "
                                "(the board reports them damaged: another epoch?)")
        if self.epoch_left() <= 0 and not self.out and self.need_resync is None:
            self.need_resync = RENEWAL

    def loop_once(self, timeout: float = READ_WAIT_S) -> None:
        """Wait for board lines (no longer than the nearest retransmission deadline),
        dispatch them, then service the timers."""
        if self.out:
            nearest = min((c.deadline for c in self.out if not c.due), default=math.inf) - self.now()
            timeout = max(0.0, min(timeout, nearest))
        self.pump(timeout)
        self.service()
