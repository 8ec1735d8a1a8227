"""A scripted board for the session-layer tests: the session rules of protocol v2
(docs/protocol.md) in plain Python, behind a port-like object, on a fake clock.

No threads and no sleeping: the host's write() is handled at once (answers go
to the host's receive buffer, or are dropped, doubled or held as the script
says), and a read() that finds nothing advances the fake clock by the port's
read timeout, so time passes exactly when the host waits. The peer's own
codec is the host codec (link/protocol.py) with the board's limits and epoch.
"""
from __future__ import annotations

from armbridge.link import protocol as P

READ_ONLY = set(P.READ_ONLY)


class FakeClock:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


class Peer:
    """Board side: session, epoch, hello_seq, expect, replay ring, a queue that
    completes a waypoint per `step()`; `executed` holds (id, values)."""

    def __init__(self, clock: FakeClock, *, n: int = 3, qsize: int = 8, fw: str = "arm3r", proto: int = 2,
                 limits=((0, 3142, 3000), (-3142, 0, 3000), (-1571, 1571, 3000))) -> None:
        self.clock = clock
        self.timeout = 0.005
        self.baudrate = 115200
        self.n, self.qsize, self.fw, self.proto, self.limits = n, qsize, fw, proto, list(limits)
        self.session: int | None = None
        self.epoch = 0
        self.hello_seq = -1
        self.expect = 0
        self.ring: dict[int, bytes] = {}  # seq -> answer line
        self.order: list[int] = []
        self.queue: list[tuple[int, tuple[int, ...]]] = []
        self.done: int | None = None
        self.state = "IDLE"
        self.reason = "-"  # the latch's reason token, as STAT's fifth field says it
        self.executed: list[tuple[int, tuple[int, ...]]] = []
        self.seen: list[tuple[int, int, str]] = []  # (epoch, seq, verb) of every line executed or HELLO
        self.bseq = 0
        self.rx = bytearray()  # bytes for the host
        self.held: list[bytes] = []
        self.lines_in = 0  # host lines received
        self.answers_out = 0  # answers produced
        self.drop_in: set[int] = set()  # indices (lines_in) of host lines lost on the way
        self.drop_out: set[int] = set()  # indices (answers_out) of answers lost
        self.hold_out: set[int] = set()  # answers held back until release()
        self.answer_delay = 0.0  # fake seconds before an answer can be read
        self._later: list[tuple[float, bytes]] = []
        self._buf = b""
        self.auto_complete = True  # a waypoint completes as soon as it is queued

    # ------------------------------------------------------------ port side
    @property
    def in_waiting(self) -> int:
        self._due()
        return len(self.rx)

    def _due(self) -> None:
        while self._later and self._later[0][0] <= self.clock.t:
            self.rx += self._later.pop(0)[1]

    def read(self, n: int = 1) -> bytes:
        self._due()
        if not self.rx:
            self.clock.t += self.timeout  # the host waited for a byte
            self._due()
            if not self.rx:
                return b""
        out, self.rx = bytes(self.rx[:n]), self.rx[n:]
        return out

    def write(self, data: bytes) -> int:
        if data == P.ESTOP_BYTE:
            self.state = "ESTOP"
            return 1
        self._buf += data
        while b"\n" in self._buf:
            line, self._buf = self._buf.split(b"\n", 1)
            idx = self.lines_in
            self.lines_in += 1
            if idx not in self.drop_in:
                self._handle(line + b"\n")
        return len(data)

    def send(self, verb: str, *args) -> bytes:
        """A board line (epoch 0) to the host, now."""
        line = P.encode(self.bseq % P.SEQ_MOD, verb, *args)
        self.bseq += 1
        self.rx += line
        return line

    def release(self) -> None:
        for line in self.held:
            self.rx += line
        self.held.clear()

    # ------------------------------------------------------------ board side
    def _answer(self, verb: str, *args) -> bytes:
        line = P.encode(self.bseq % P.SEQ_MOD, verb, *args)
        self.bseq += 1
        idx = self.answers_out
        self.answers_out += 1
        if idx in self.hold_out:
            self.held.append(line)
        elif idx not in self.drop_out:
            if self.answer_delay:
                self._later.append((self.clock.t + self.answer_delay, line))
            else:
                self.rx += line
        return line

    def free(self) -> int:
        return self.qsize - len(self.queue)

    def hello_payload(self) -> tuple:
        done = "-" if self.done is None else self.done
        queued = self.queue[-1][0] if self.queue else "-"
        return (self.fw, "0.1.0", self.proto, self.n, self.qsize, 25, 1000, done, queued, self.state)

    def _handle(self, raw: bytes) -> None:
        try:
            line = P.decode(raw, P.MAX_HOST_LINE, epoch=self.epoch)
        except P.ProtocolError as exc:
            if exc.code in (P.PARSE, P.CRC, P.LONG):
                self._answer("ER", "-", exc.code, exc.name)
            return
        seq, verb, args = line.seq, line.verb, line.args
        if verb == "HELLO":
            self._hello(seq, [int(a) for a in args])
            return
        if self.session is None:
            self._answer("ER", seq, P.NOSESSION, "NOSESSION")
            return
        if seq == self.expect:
            self.seen.append((self.epoch, seq, verb))
            ans = self._execute(seq, verb, args)
            self.ring[seq] = ans
            self.order.append(seq)
            if len(self.order) > P.RING:
                self.ring.pop(self.order.pop(0), None)
            self.expect = (seq + 1) % P.SEQ_MOD
            return
        if seq in self.ring and 0 < (self.expect - seq) % P.SEQ_MOD <= P.RING:
            if verb in READ_ONLY:
                self._execute(seq, verb, args)
            else:
                self.rx += self.ring[seq]  # the stored answer, replayed
            return
        self._answer("ER", seq, P.SEQ, "SEQ", self.expect)

    def _hello(self, seq: int, args: list[int]) -> None:
        proto, session, epoch = args
        if proto != self.proto:
            self._answer("ER", seq, P.PROTO, "PROTO", self.proto)
        elif epoch == self.epoch + 1:   # only the next epoch opens (docs/protocol.md §6)
            if session != self.session:
                self.session, self.queue, self.done = session, [], None
            self.epoch, self.hello_seq, self.expect = epoch, seq, (seq + 1) % P.SEQ_MOD
            self.ring.clear()
            self.order.clear()
            self.seen.append((epoch, seq, "HELLO"))
            self._answer("OK", seq, self.free(), *self.hello_payload())
        elif epoch == self.epoch and session == self.session and seq == self.hello_seq:
            self._answer("OK", seq, self.free(), *self.hello_payload())
        else:
            self._answer("ER", seq, P.STALE, "STALE", self.epoch)

    def _execute(self, seq: int, verb: str, args: tuple[str, ...]) -> bytes:
        if verb == "W":
            if self.state in ("ESTOP", "WDOG", "FAULT"):
                return self._answer("ER", seq, P.LATCHED, "LATCHED")
            if not self.free():
                return self._answer("ER", seq, P.FULL, "FULL")
            vals = tuple(int(a) for a in args)
            self.queue.append((vals[0], vals[2:]))
            ans = self._answer("OK", seq, self.free())
            if self.auto_complete:
                self.step()
            return ans
        if verb == "LIM":
            j = int(args[0])
            return self._answer("OK", seq, self.free(), j, *self.limits[j - 1])
        if verb == "STAT":
            done = "-" if self.done is None else self.done
            queued = self.queue[-1][0] if self.queue else "-"
            reason = self.reason if self.state in ("ESTOP", "WDOG", "FAULT") else "-"
            return self._answer("OK", seq, self.free(), self.state, done, queued, int(self.clock.t * 1000), reason)
        if verb == "PING":
            return self._answer("OK", seq, self.free(), int(self.clock.t * 1000))
        if verb == "CLR":
            self.state, self.queue = "IDLE", []
        return self._answer("OK", seq, self.free())

    def step(self) -> None:
        """The oldest queued waypoint completes: logged, EV DONE id free."""
        if self.queue:
            wid, values = self.queue.pop(0)
            self.executed.append((wid, values))
            self.done = wid
            self.send("EV", int(self.clock.t * 1000), "DONE", wid, self.free())
