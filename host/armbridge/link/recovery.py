"""Loss recovery of the session layer (link/arq.py): the window, and which lines go again.

`Arq` numbers commands and keeps the unanswered ones in a list in seq order
(`out`); this module decides how many of them may be unanswered at once and
which of them are sent again when a line or an answer is lost. Unanswered
commands are sent again when
  (a) their retransmission timer runs out (link/rto.py: Jacobson/Karels,
      Karn, back-off while the board is silent): first that line alone, the
      later ones held until its new deadline (F-RTO, RFC 5682): an answer to a
      line sent once shows the board was only late, and nothing more is sent
      again; a second timeout is a real loss: go-back-N from it;
  (b) the board answers `ER SEQ E`: go-back-N from E, unless a retransmission
      of E is already on its way (answers to lines sent before it are stale);
  (c) the board reports a framing error (CRC/PARSE/LONG with seq `-`): the
      timers of the lines that have reached the board are cut to the time an
      answer needs (fast retransmit);
  (d) a later command is answered while an earlier one is not: its answer was
      lost; it is sent again and the board replays the answer from its ring
      without executing it a second time.

Window: at most `cwnd` commands unanswered, `cwnd` <= MAX_WINDOW (below the
board's 32-entry replay ring). A lost line halves it (not below MIN_WINDOW),
a timeout found real sets it to MIN_WINDOW, each answer grows it by 1/cwnd.

Apart from `Arq` (the commands, the byte link, answers, credits, epochs,
keep-alive, resync requests) because this is the policy of a lossy link, and
its numbers were measured (MIN_WINDOW, the F-RTO probe, NOISY_S): it changes
without touching how lines are framed, sent or read. It works on the Arq's own
list of unanswered commands and sends through the Arq's `transmit`.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from armbridge.link.stats import LinkStats

if TYPE_CHECKING:
    from armbridge.link.arq import Cmd

MAX_WINDOW = 24  # unanswered commands at most: the board's replay ring holds 32
# Smallest window after losses. Losses on a serial line are noise, not
# congestion: a few lines in flight keep loss detection fast (the next line's
# ER SEQ or answer reveals a lost line or a lost answer) while a go-back resends
# little. Measured on the emulator at 1% drop+corrupt+dup per byte: windows of
# 1/2/4/8 ran a 200-waypoint plan in 10.2/7.5/4.7/5.1 s.
MIN_WINDOW = 4
NOISY_S = 2.0  # a timeout this soon after a damaged line is taken as a real loss (no F-RTO probe)


class Recovery:
    """The window of one Arq and what it sends again.

    out: the Arq's unanswered commands, in seq order (the same list, kept by
    the Arq); transmit(cmd): the Arq's send; clock, stats: the Arq's;
    answer_time: from a line reaching the board to its answer reaching us.
    """

    def __init__(self, out: list[Cmd], transmit: Callable[[Cmd], None], clock: Callable[[], float],
                 stats: LinkStats, answer_time: float) -> None:
        self.out = out
        self.transmit = transmit
        self.now = clock
        self.stats = stats
        self.answer_time = answer_time
        self.cwnd = float(MAX_WINDOW)
        self._last_cut = -math.inf
        self.probing = False  # a timeout's line was sent alone; the rest wait (F-RTO)
        self._last_damage = -math.inf  # latest sign of a noisy link (a damaged line either way, ER SEQ)

    def send_due(self) -> None:
        """Transmit due commands, oldest first, while the window has room."""
        window = max(1, int(self.cwnd))
        inflight = sum(1 for c in self.out if not c.due)
        for cmd in self.out:
            if inflight >= window:
                return
            if cmd.due:
                self.transmit(cmd)
                inflight += 1

    def damaged(self) -> None:
        """A sign of a noisy link: a damaged line either way, an ER SEQ."""
        self._last_damage = self.now()

    def settled(self) -> None:
        """A command left `out` (or all did): with nothing unanswered no probe runs."""
        if not self.out:
            self.probing = False

    def _loss(self) -> None:
        """A line was lost on the way to the board: halve the window (once per round trip)."""
        now = self.now()
        if now - self._last_cut > self.answer_time:
            self._last_cut = now
            self.cwnd = max(float(MIN_WINDOW), self.cwnd / 2)
            self.stats.window_cuts += 1

    def go_back(self, first: Cmd, *, timed_out: bool = False) -> None:
        """Go-back-N: send `first` and every later unanswered command again, in
        order, as the window allows. After a timeout (a real loss, see
        `timed_out`) the window restarts at MIN_WINDOW, TCP's rule after an
        RTO, floored as `_loss` is."""
        self.probing = False
        go = False
        for cmd in self.out:
            go = go or cmd is first
            if go:
                cmd.due = True
        if timed_out:
            self._last_cut = self.now()
            self.cwnd = float(MIN_WINDOW)
            self.stats.window_cuts += 1
        else:
            self._loss()
        self.send_due()

    def timed_out(self, cmd: Cmd) -> None:
        """`cmd`'s retransmission timer ran out. The first time (F-RTO, RFC
        5682) only `cmd` goes again and the later lines wait until its new
        deadline: when the host or the board's process was descheduled past
        the RTO, the answers to the first copies arrive meanwhile, an answer
        to a line sent once ends the probe (`answered`) and nothing more is
        resent (go-back-N at once resent 14-19 W lines per such timeout on a
        clean link, 2 cores shared). Another timeout while probing is a real
        loss: go-back-N from `cmd`, as is any timeout within NOISY_S of a
        damaged line: on a noisy link a timeout is mostly a real loss, and
        probing first cost the soak's fault mix 30 % of its waypoints/s."""
        if self.probing or self.now() - self._last_damage < NOISY_S:
            self.go_back(cmd, timed_out=True)
            return
        self.probing = True
        self.transmit(cmd)
        for other in self.out:
            if other.n > cmd.n and not other.due:
                other.deadline = max(other.deadline, cmd.deadline)

    def answered(self, cmd: Cmd) -> None:
        """An OK for `cmd` arrived (before it is settled): an answer to a line
        sent once ends a probe, the board executes the lines as sent, the
        timeout was spurious."""
        if cmd.tx == 1 and self.probing:
            self.probing = False
            self.stats.spurious_timeouts += 1

    def grow(self, cmd: Cmd) -> None:
        """An OK settled `cmd`: the window grows by 1/cwnd (a resent W line's answer does not count)."""
        if cmd.tx == 1 or cmd.wp is None:
            self.cwnd = min(float(MAX_WINDOW), self.cwnd + 1.0 / self.cwnd)

    def lost_answers_before(self, cmd: Cmd) -> None:
        """Commands before `cmd` that were sent before it and are still unanswered
        were executed (the board answers in order): their answers were lost. Ask
        again; the board replays them."""
        again = False
        for other in self.out:
            if other.n >= cmd.n:
                break
            if other.order < cmd.order and not other.due:
                other.due = True
                again = True
        if again:
            self.send_due()

    def framing_error(self) -> None:
        """One of our lines reached the board damaged (its seq unknown): the timers of
        the lines that have reached the board are cut to the time an answer needs."""
        now = self.now()
        for c in self.out:
            if c.arrive_at <= now:
                c.deadline = min(c.deadline, now + self.answer_time)

    def seq_error(self, first: Cmd) -> None:
        """The board answered ER SEQ expecting `first`, which is in flight."""
        if self.now() < first.arrive_at + self.answer_time:
            return  # stale: a retransmission of `first` is on its way already
        # Commands before `first` are executed; ask for their answers again.
        self.lost_answers_before(first)
        self.go_back(first)
