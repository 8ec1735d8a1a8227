"""Exactly-once against any delay (docs/protocol.md, issue 9 §1): a stateful
property test.

The board is the real ESP32 firmware in the emulator, in lockstep (no wall
clock). The host is a small model of a correct host that follows the protocol
(HELLO `2 session epoch`, a new epoch per resync, each waypoint id under one
seq per epoch, after a resync the waypoints after the board's `queued`/`done`
sent again under new seqs). Between them sits an adversary: every line the
host has ever written stays in a pool, and at any later step the adversary may
deliver any of them again, any number of times, in any order, whole or damaged
(bits flipped, bytes dropped or doubled, a line cut short and run into the
next), interleaved with board resets, e-stops, watchdog stops and new sessions.
The host reads the board's answers undamaged: what is proven is the board's
side, with the board's own completion log (`EmulatedBoard.executed`, from the
firmware's hook) as the ground truth.

Invariants after every step:
  * every waypoint id completes at most once, ids complete in increasing order,
    and with exactly the values the host sent for that id;
  * a latch (ESTOP, WDOG, FAULT) is released only when a CLR line that the
    host wrote after the latch began is delivered; no reset, no HELLO and no
    copy of an older line releases it.
"""
from __future__ import annotations

import random

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from armbridge.emulator.board import EmulatedBoard
from armbridge.link import protocol as P

LATCHED = ("ESTOP", "WDOG", "FAULT")
# Joint targets well inside arm3r's ranges (mrad): near mid-range, so the
# waypoints are feasible and short.
MID = (1571, -1571, 0)
joint_offsets = st.tuples(*[st.integers(-300, 300)] * 3)


class AdversarialLink(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        self.emu = EmulatedBoard("esp32", speed=0, seed=1, boot_ms=20.0)
        self.splitter = P.LineSplitter(P.MAX_BOARD_LINE)
        self.rng = random.Random(0)
        self.session = 1
        self.epoch = 0
        self.n = 1                       # host command counter (seq = n mod 65536)
        self.pool: list[tuple[bytes, str]] = []   # (line, verb) of every line ever written
        self.values: dict[int, tuple[int, ...]] = {}   # id -> the values sent for it
        self.session_ids: list[int] = []  # ids of the current session, in order
        self.next_id = 0                 # ids are unique over the whole test
        self.answers: dict[int, P.Ok | P.Er] = {}
        self.open = False
        self.latched_at: int | None = None   # pool size when the current latch began
        self.last_state = self.emu.state
        self._run(30)

    def teardown(self) -> None:
        self.emu.stop()

    # ------------------------------------------------------------ plumbing
    def _run(self, ms: float, delivered: int | None = None) -> None:
        """Run the board for `ms` of sim time and read what it said; `delivered`:
        the pool index of the line just delivered whole (None: nothing, or damaged)."""
        self.emu.advance(ms / 1000.0)
        for item in self.splitter.feed(self.emu.read_output()):
            if isinstance(item, P.ProtocolError) or item in (b"\n", b"\r\n"):
                continue
            try:
                msg = P.parse_board_line(P.decode(item))
            except P.ProtocolError:
                continue  # a line a reset cut short
            if isinstance(msg, (P.Ok, P.Er)) and msg.seq is not None:
                self.answers[msg.seq] = msg
            if isinstance(msg, P.Boot):
                self.open = False       # the host resyncs before it sends more
        self._watch_latch(delivered)

    def _watch_latch(self, delivered: int | None) -> None:
        """The latch rule, checked at every state change the test sees."""
        state = self.emu.state
        was = self.last_state
        if state in LATCHED and was not in LATCHED:
            self.latched_at = len(self.pool)
        elif was in LATCHED and state not in LATCHED and state not in ("RESET", "CRASHED"):
            assert delivered is not None, f"{was} released without a line (state {state})"
            line, verb = self.pool[delivered]
            assert verb == "CLR", f"{was} released by {line!r}"
            assert self.latched_at is not None and delivered >= self.latched_at, (
                f"{was} released by a CLR written before the latch: {line!r}")
            self.latched_at = None
        if state not in ("RESET", "CRASHED"):
            self.last_state = state

    def _write(self, verb: str, *args: object) -> int:
        """A new host line (framed with the current epoch; HELLO with 0), kept in the pool."""
        seq = self.n % P.SEQ_MOD
        self.n += 1
        self.pool.append((P.encode(seq, verb, *args, epoch=self.epoch), verb))
        return seq

    def _deliver(self, k: int, data: bytes | None = None) -> None:
        line = self.pool[k][0] if data is None else data
        self.emu.inject(line)
        self._run(2 + len(line) * 0.087, k if data is None else None)

    def _send(self, verb: str, *args: object) -> P.Ok | P.Er | None:
        """Write a new line, deliver it and wait (up to 60 ms of sim time) for its answer."""
        seq = self._write(verb, *args)
        self._deliver(len(self.pool) - 1)
        for _ in range(30):
            if seq in self.answers:
                break
            self._run(2)
        return self.answers.get(seq)

    # ------------------------------------------------------------ the host
    @rule(new_session=st.booleans())
    def hello(self, new_session: bool) -> None:
        """Open a session or resync: a new epoch; on STALE, the board's epoch + 1."""
        if new_session:
            self.session = self.session % 65535 + 1
        for _ in range(3):
            self.epoch += 1
            ans = self._send("HELLO", P.PROTOCOL_VERSION, self.session, self.epoch)
            if isinstance(ans, P.Er) and ans.code == P.STALE:
                self.epoch = int(ans.detail[0])
                continue
            break
        else:
            raise AssertionError("three HELLOs refused STALE in a row")
        self.open = isinstance(ans, P.Ok)
        if new_session:
            self.session_ids = []  # a new session starts a new plan
        if not isinstance(ans, P.Ok):
            return  # the board was booting: no session until a later HELLO
        done, queued = (P.optional_id(x) for x in ans.payload[7:9])
        # Resend, under new seqs of this epoch, what the board has not taken.
        last = max(x for x in (done, queued, -1) if x is not None)
        for wid in [i for i in self.session_ids if i > last]:
            self._send_waypoint(wid)

    def _send_waypoint(self, wid: int) -> None:
        self._send("W", wid, 40, *self.values[wid])

    @precondition(lambda self: self.open)
    @rule(offsets=joint_offsets)
    def waypoint(self, offsets) -> None:
        wid = self.next_id
        self.next_id += 1
        self.values[wid] = tuple(m + o for m, o in zip(MID, offsets))
        self.session_ids.append(wid)
        self._send_waypoint(wid)

    @precondition(lambda self: self.open)
    @rule()
    def clear(self) -> None:
        self._send("CLR")

    @precondition(lambda self: self.open)
    @rule(verb=st.sampled_from(["PING", "STAT", "HOLD", "RESUME"]))
    def other(self, verb: str) -> None:
        self._send(verb)

    # ------------------------------------------------------------ the adversary
    @precondition(lambda self: self.pool)
    @rule(k=st.integers(0, 10**6), copies=st.integers(1, 3))
    def replay(self, k: int, copies: int) -> None:
        """Any line ever written, again, at any delay, any number of times."""
        for _ in range(copies):
            self._deliver(k % len(self.pool))

    @precondition(lambda self: self.pool)
    @rule(h=st.integers(0, 10**6), length=st.integers(1, 8))
    def replay_stretch(self, h: int, length: int) -> None:
        """A stretch of the old conversation, in its order, from one of the host's
        HELLOs on: what a link that buffered and then released it would deliver
        (the sharpest test of a HELLO copy rewinding the session)."""
        hellos = [i for i, (_, verb) in enumerate(self.pool) if verb == "HELLO"]
        start = hellos[h % len(hellos)] if hellos else 0
        for k in range(start, min(len(self.pool), start + length)):
            self._deliver(k)

    @precondition(lambda self: self.pool)
    @rule(k=st.integers(0, 10**6), seed=st.integers(0, 2**32 - 1))
    def damaged(self, k: int, seed: int) -> None:
        """A copy with bits flipped, bytes dropped or doubled (the LF kept)."""
        rng = random.Random(seed)
        line = bytearray(self.pool[k % len(self.pool)][0][:-1])
        for _ in range(rng.randint(1, 3)):
            i = rng.randrange(len(line))
            what = rng.randrange(3)
            if what == 0:
                line[i] ^= 1 << rng.randrange(7)
            elif what == 1:
                del line[i]
            else:
                line.insert(i, line[i])
        self._deliver(k % len(self.pool), bytes(line) + b"\n")

    @precondition(lambda self: len(self.pool) >= 2)
    @rule(a=st.integers(0, 10**6), b=st.integers(0, 10**6), cut=st.floats(0.05, 0.95))
    def cut_short(self, a: int, b: int, cut: float) -> None:
        """The front of one line run into another (its LF lost)."""
        first = self.pool[a % len(self.pool)][0]
        second = self.pool[b % len(self.pool)][0]
        self._deliver(a % len(self.pool), first[: max(1, int(len(first) * cut))] + second)

    @rule(ahead=st.sampled_from([2, 1000, 1 << 29, None]))
    def foreign_hello(self, ahead: int | None) -> None:
        """Another host's HELLO (another session) at an epoch more than one ahead of the
        board's, up to the last one (None: EPOCH_MAX): refused STALE, as only E + 1 opens
        an epoch (docs/protocol.md §6), so no HELLO can use up the epochs this host needs
        (issue 21: one at 1073741823 left none for a resync)."""
        e = self._board_epoch()
        e = self.epoch if e is None else e
        epoch = P.EPOCH_MAX if ahead is None else min(e + ahead, P.EPOCH_MAX)
        self.emu.inject(P.encode(0, "HELLO", P.PROTOCOL_VERSION, (self.session + 999) % 65535 + 1, epoch))
        self._run(5)

    def _board_epoch(self) -> int | None:
        board = self.emu.board
        return None if board is None else board.link.session.epoch

    @rule(ms=st.integers(5, 300))
    def run(self, ms: int) -> None:
        self._run(ms)

    @rule()
    def reset(self) -> None:
        self.emu.reset()
        self._run(60)

    @rule()
    def estop(self) -> None:
        self.emu.inject(P.ESTOP_BYTE)
        self._run(2)

    # ------------------------------------------------------------ invariants
    @invariant()
    def each_waypoint_once_in_order_with_its_values(self) -> None:
        ids = [wid for _, wid, _ in self.emu.executed]
        assert ids == sorted(set(ids)), f"completed out of order or twice: {ids}"
        for _, wid, values in self.emu.executed:
            assert tuple(values) == self.values[wid], f"waypoint {wid}: ran {values}, sent {self.values[wid]}"

    @invariant()
    def the_board_epoch_is_one_this_host_opened(self) -> None:
        e = self._board_epoch()
        assert e is None or e <= self.epoch, f"the board is at epoch {e}, this host at {self.epoch}"

    @invariant()
    def firmware_alive(self) -> None:
        assert self.emu.crash is None, self.emu.crash


AdversarialLink.TestCase.settings = settings(
    max_examples=50, stateful_step_count=40, deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)
test_exactly_once_against_an_adversarial_link = AdversarialLink.TestCase
