"""How well a paced emulator keeps the wall clock, and what it says when it cannot.

A paced emulator (speed K > 0) aims its sim clock at K x the wall clock. When the
machine cannot run it that fast (a busy CPU, a board too costly to simulate), it
catches up in bursts, and past a backlog of `EmulatedBoard.MAX_CATCHUP_S` it gives
the backlog up: from then on its board time runs behind the wall clock. A host in
the same process does not mind (its clock is the board's, `host_time`), but a host
on the pty, on the wall clock, sees a slow board: its answers come late and its
watchdog runs slow. So the emulator says it, once per NOTE_EVERY_S of wall time at
most, with the speed it achieved over the stretch since its last note, and
`report()` sums it up for a run's summary and `armbridge emulate`'s last lines.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable

NOTE_EVERY_S = 5.0
RT_PRIORITY = 1  # the lowest SCHED_FIFO priority: above every normal process, below the kernel's own


class PaceLog:
    """The pace of one paced emulator run (wall seconds from time.monotonic, sim us)."""

    def __init__(self, device: str) -> None:
        self.device = device
        self.wall0: float | None = None
        self.sim0 = 0
        self.max_lag_s = 0.0
        self.overruns = 0
        self.given_up_s = 0.0
        self._note_wall: float | None = None
        self._note_sim = 0

    def start(self, wall: float, sim_us: int) -> None:
        self.wall0, self.sim0 = wall, sim_us
        self._note_wall, self._note_sim = wall, sim_us

    def lag(self, seconds: float) -> None:
        if seconds > self.max_lag_s:
            self.max_lag_s = seconds

    def slipped(self, wall: float, sim_us: int, backlog_s: float, say: Callable[[str], None]) -> None:
        """A backlog of `backlog_s` given up at (wall, sim_us); a note when one is due."""
        self.overruns += 1
        self.given_up_s += backlog_s
        if self._note_wall is None:
            return
        if self.overruns > 1 and wall - self._note_wall < NOTE_EVERY_S:
            return  # said lately
        span = wall - self._note_wall
        achieved = (sim_us - self._note_sim) / 1e6 / span if span > 0 else 0.0
        say(f"the {self.device} emulator cannot keep up with the wall clock: it ran at {achieved:.2f}x of real "
            f"time over the last {span:.1f} s and gave up {self.given_up_s:.2f} s of backlog in all "
            f"({self.overruns} times); a host on its pty sees the board's time run slow (free the CPU, or run "
            "it with --speed below 1, or --speed 0 and a host in the same process)")
        self._note_wall, self._note_sim = wall, sim_us

    def report(self, speed: float, wall: float, sim_us: int) -> dict:
        """{speed, achieved, max_lag_s, overruns, given_up_s} (achieved None before a paced start)."""
        span = wall - self.wall0 if self.wall0 is not None else 0.0
        achieved = (sim_us - self.sim0) / 1e6 / span if span > 0 else None
        return {"speed": speed, "achieved": achieved, "max_lag_s": self.max_lag_s, "overruns": self.overruns,
                "given_up_s": self.given_up_s}


def realtime(pids: Iterable[int] = (), this_thread: bool = False) -> str | None:
    """Real-time scheduling (SCHED_FIFO, priority RT_PRIORITY) for the calling thread and
    for the processes `pids` (a runner's children): a board is a chip of its own, and
    this keeps a busy machine from slowing it, as Klipper's Linux MCU process asks for
    with -r. A paced emulator sleeps between ticks, so it takes what it needs and no
    more. Returns None, or what stood in the way (no permission: root or
    CAP_SYS_NICE is needed), for the emulator to say."""
    param = os.sched_param(RT_PRIORITY)
    targets = ([0] if this_thread else []) + list(pids)
    for pid in targets:
        try:
            os.sched_setscheduler(pid, os.SCHED_FIFO, param)
        except PermissionError:
            return ("real-time scheduling was refused (it needs root or CAP_SYS_NICE): the emulator runs at "
                    "normal priority and may fall behind the wall clock on a busy machine")
        except (OSError, AttributeError) as exc:
            return f"real-time scheduling is not available here ({exc}): the emulator runs at normal priority"
    return None
