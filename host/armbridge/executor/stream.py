"""Streaming one plan's waypoints: which are sent, which are done, where to resume.

A `Stream` is the plan side of a session: it issues `W id dur q...` lines
(or Cartesian `X id dur x y theta` lines, which the board solves itself)
through the session layer (link/arq.py) while the board's queue has credit,
follows START and DONE (events, or the `done` column of telemetry when an
event was lost), and after a resync maps the board's `done`/`queued` ids back
to plan indices, so the rest is resent and nothing runs twice.

A drawing plan's pen flags go down as `PEN down` lines, modal like G-code's
M3/M5: one before the first waypoint and before each waypoint whose flag
differs from the last sent; the board applies it to the waypoints queued after
it (docs/protocol.md §3). After a resync the next waypoint sent is preceded by
its PEN again, so a board that rebooted (its pen state back to up) draws the
rest as planned. PEN takes no queue slot, so it costs no credit.

Waypoint ids run on across the plans of one session (`base`, the count of
waypoints streamed before this plan, mod 65536): a board's `done` after a
reset can never name a waypoint of an earlier plan as one of this plan.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

from armbridge.errors import ArmbridgeError
from armbridge.link import protocol as P
from armbridge.link.arq import Arq, Cmd

ID_MOD = 65536


class Stream:
    """One plan's waypoints in flight. Plan indices 0..k-1; ids (base + i) mod 65536."""

    def __init__(self, durations_ms: Sequence[int], q_milli: Sequence[Sequence[int]], base: int = 0,
                 on_progress: Callable[[int], None] | None = None, *, verb: str = "W",
                 pen: Sequence[int] | None = None,
                 commands: Sequence[tuple[str, Sequence[int]]] | None = None) -> None:
        """`q_milli`: the arguments after `id dur` of each `verb` line; or `commands`,
        one (verb, arguments after the id) per waypoint (the MASR actuator's actions,
        MV d / ROT j angle, which take no duration), with q_milli unused."""
        if commands is None:
            if len(durations_ms) != len(q_milli):
                raise ValueError(f"{len(durations_ms)} durations for {len(q_milli)} waypoints")
            commands = [(verb, [int(d), *(int(v) for v in row)]) for d, row in zip(durations_ms, q_milli)]
        if len(commands) != len(durations_ms):
            raise ValueError(f"{len(durations_ms)} durations for {len(commands)} commands")
        if pen is not None and len(pen) != len(durations_ms):
            raise ValueError(f"{len(pen)} pen flags for {len(durations_ms)} waypoints")
        self.durations = [int(d) for d in durations_ms]
        self.commands = [(v, [int(x) for x in args]) for v, args in commands]
        self.pen = None if pen is None else [int(x) for x in pen]
        self._pen_sent: int | None = None  # the board's modal pen state as last sent
        self.k = len(self.durations)
        self.base = base
        self.on_progress = on_progress
        self.next_wp = 0  # next plan index to send
        self.done = -1  # highest plan index known completed
        self.completed_any = False
        self.done_times: dict[int, float] = {}  # plan index -> board time of its DONE
        self.start_times: dict[int, float] = {}  # plan index -> board time of its START

    @property
    def finished(self) -> bool:
        return self.done >= self.k - 1

    def progress(self) -> str:
        return f"{self.done + 1} of {self.k} waypoints done"

    def wid(self, i: int) -> int:
        return (self.base + i) % ID_MOD

    def index_of(self, wid: int, lo: int, hi: int) -> int | None:
        """The plan index in [lo, hi] whose id is wid, if any."""
        if hi < lo:
            return None
        i = lo + (wid - self.base - lo) % ID_MOD
        return i if i <= hi else None

    # ------------------------------------------------------------------ sending
    def fill(self, arq: Arq) -> None:
        """Issue waypoints while the board has credit, the window has room and
        the epoch has seqs left."""
        while (self.next_wp < self.k and arq.credit_left() > 0 and len(arq.out) < max(1, int(arq.cwnd))
               and arq.can_issue()):
            i = self.next_wp
            if self.pen is not None and self.pen[i] != self._pen_sent:
                arq.issue("PEN", self.pen[i])
                self._pen_sent = self.pen[i]
                continue
            verb, args = self.commands[i]
            arq.issue(verb, self.wid(i), *args, wp=self.base + i)
            self.next_wp += 1

    # ------------------------------------------------------------------ board news
    def mark_done(self, wid: int, t: float) -> int | None:
        """DONE of id `wid` at board time t (from an EV DONE: exact; from telemetry:
        an upper bound, the event was lost). Returns the plan index, if in flight."""
        idx = self.index_of(wid, self.done, self.next_wp - 1)
        if idx is None:
            return None
        self._advance(idx)
        self.done_times.setdefault(idx, t)
        return idx

    def mark_start(self, wid: int, t: float) -> None:
        idx = self.index_of(wid, self.done + 1, self.next_wp - 1)
        if idx is not None:
            self.start_times.setdefault(idx, t)

    def _advance(self, idx: int) -> None:
        if idx > self.done:
            self.done = idx
            self.completed_any = True
            if self.on_progress is not None:
                self.on_progress(idx + 1)

    def resume(self, done: int | None, queued: int | None, reason: str) -> None:
        """After a resync: the board's `done` and `queued` ids (HELLO reply) say
        where the plan stands; the rest is resent from there. `done` = `-` after
        waypoints had completed means the board lost its persisted memory (a power
        cycle): where the arm is in the plan is unknown, so stop."""
        if done is None:
            if self.completed_any:
                raise ArmbridgeError(
                    f"the board lost its session state ({reason}; HELLO says no waypoint done, "
                    f"{self.done + 1} had completed): it was power-cycled, so where the plan stands "
                    "is unknown. Stopped."
                )
            done_idx = -1
        else:
            # Any index sent (the newest 65535 are unambiguous): the reply may be
            # older news than a DONE read with it in the same batch of bytes.
            found = self.index_of(done, max(0, self.next_wp - ID_MOD + 1), self.next_wp - 1)
            if found is not None:
                done_idx = found
            elif done == self.wid(self.done):
                done_idx = self.done  # nothing new (at -1: the last waypoint of an earlier plan)
            else:
                raise ArmbridgeError(
                    f"after a resync the board says waypoint id {done} is done, which this run "
                    f"has not sent (sent up to index {self.next_wp - 1}). Stopped."
                )
        self._advance(done_idx)
        self._pen_sent = None  # the board may have rebooted: say the pen state again
        resume = self.done + 1
        if queued is not None:  # the board kept its queue (no reset): resend after it
            q_idx = self.index_of(queued, max(self.done, 0), self.next_wp - 1)
            if q_idx is not None:
                resume = max(resume, q_idx + 1)
        self.next_wp = resume

    def refusal(self, cmd: Cmd, er: P.Er, state: str | None) -> ArmbridgeError:
        """A refused W (RANGE, FULL, LATCHED ...) is fatal: the error says why."""
        if cmd.wp is not None:
            what = f"waypoint {cmd.wp - self.base} ({cmd.verb} seq {cmd.seq})"
        else:
            what = f"{cmd.verb} (seq {cmd.seq})"
        why = {
            P.RANGE: "a value is outside the board's limits",
            P.FULL: "its queue was full (host credit error)",
            P.LATCHED: f"it is latched in {state or 'ESTOP/WDOG/FAULT'}",
            P.VERB: f"this board cannot do {cmd.verb} (a capability its firmware or rig lacks)",
            P.REACH: "the target is outside the board's safe region or its IK did not reach it",
            P.UNHOMED: "the mobile actuator does not know where it is (a power on, a reset while it moved, or a "
                       "localisation fault), so the rest of the plan is not run: run with --home to drive it to the "
                       "base and back to the plan's start",
        }.get(er.code, "")
        detail = " ".join(er.detail)
        return ArmbridgeError(
            f"the board refused {what}: {er.code} {er.name}{' ' + detail if detail else ''}"
            f"{' (' + why + ')' if why else ''}; {self.progress()}"
        )


class Streaming:
    """A client's view of the plan it streams, the same for every client: `_stream`
    is the current (or last) plan's Stream, None before the first."""

    _stream: Stream | None = None

    @property
    def done_index(self) -> int:
        return self._stream.done if self._stream is not None else -1

    @property
    def done_times(self) -> dict[int, float]:
        return self._stream.done_times if self._stream is not None else {}

    @property
    def start_times(self) -> dict[int, float]:
        return self._stream.start_times if self._stream is not None else {}
