"""One rich progress bar across all shards of a job: done / total, throughput, where they run."""
from __future__ import annotations

import time
from types import TracebackType
from typing import Any


class ShardBar:
    """label, bar, done/total, shards per minute of this run, the cluster, elapsed, remaining.

    Shards read back from a checkpoint count as done from the start but not
    in the throughput (only shards computed by this run do). Disabled, it
    does nothing (and imports nothing).
    """

    def __init__(self, label: str, total: int, done: int = 0, enabled: bool = True):
        self.total, self.done, self.enabled = total, done, enabled
        self.computed = 0
        self.t0 = time.perf_counter()
        self._bar: Any = None
        self._task: Any = None
        self._label = label

    def __enter__(self) -> ShardBar:
        if self.enabled:
            from rich.console import Console
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                                       TimeRemainingColumn)

            self._bar = Progress(TextColumn("[bold]{task.description}[/]"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("shards  {task.fields[rate]}  [dim]{task.fields[cluster]}[/]"),
                                 TimeElapsedColumn(), TimeRemainingColumn(), console=Console(stderr=True))
            self._bar.start()
            self._task = self._bar.add_task(self._label, total=self.total, completed=self.done, rate="",
                                            cluster="")
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None

    def rate(self) -> float:
        """Shards per minute computed by this run."""
        return self.computed / max(time.perf_counter() - self.t0, 1e-9) * 60

    def advance(self) -> None:
        self.computed += 1
        self.done += 1
        if self._bar is not None:
            self._bar.update(self._task, advance=1, rate=f"{self.rate():.3g}/min")

    def ended(self) -> None:
        """The job stopped early (Runner.map's stop): the bar ends at what was done."""
        self.total = self.done
        if self._bar is not None:
            self._bar.update(self._task, total=self.done, completed=self.done)

    def cluster(self, text: str) -> None:
        """Where the shards run; the throughput's clock starts here (after a cluster's start-up)."""
        self.t0 = time.perf_counter()
        if self._bar is not None:
            self._bar.update(self._task, cluster=text)
