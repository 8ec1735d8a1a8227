"""A run's side of pause and resume (executor/run.py `run_plan(..., pause_keys=True)`).

`PauseView` puts the pieces together for one run: the keyboard (executor/keys.py
`PauseKeys`, on a terminal only) around `execute`, its keys handed to the session
client's `request_hold` (executor/hold.py: HOLD / RESUME at the streaming loop's next
turn); what the board then reports (its HOLD / RESUME events) shown on the progress
bar ("held (space resumes)") or, without one, as a line; and the hold count and
board time held for the summary (`holds`, `held_s`; the measured duration leaves
the held time out, docs/formats.md).
"""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from armbridge.executor.hold import HoldLog, hold_unsupported
from armbridge.executor.keys import PauseKeys

HELD = "held"
RUNNING = "running"
KEYS_LINE = "space or p: hold / resume the arm; Ctrl-C: e-stop"


class PauseView:
    """Pause for one run: `keys(client)` around execute; `on_event` / `on_telemetry` from the
    run's callbacks; `bar` (an object with `status(text)`) once there is one; `close(summary)`."""

    def __init__(self, console: Any = None, enabled: bool = False) -> None:
        self.console = console
        self.enabled = enabled
        self.bar: Any = None
        self.keys_active = False
        self.log = HoldLog(self._changed)

    def on_event(self, t: float | None, ev: Any) -> None:
        self.log.on_event(t, ev)

    def on_telemetry(self, t: float) -> None:
        self.log.note_time(t)

    @property
    def intervals(self) -> list[tuple[float, float]]:
        return self.log.intervals

    @contextmanager
    def keys(self, client: Any) -> Iterator[None]:
        """Space or p toggles the hold while inside (a terminal only; `enabled` False: nothing)."""
        if not self.enabled:
            yield
            return
        request = getattr(client, "request_hold", None)
        if request is None:
            self._say(hold_unsupported(type(client).__name__))
            yield
            return
        with PauseKeys(request) as keys:
            self.keys_active = keys.active
            if keys.active:
                self._say(KEYS_LINE)
            try:
                yield
            finally:
                self.keys_active = False

    def _changed(self, held: bool) -> None:
        text = (HELD + " (space resumes)" if self.keys_active else HELD) if held else RUNNING
        if self.bar is not None:
            self.bar.status(text)
        elif self.keys_active:
            self._say(text if held else "resumed")

    def _say(self, text: str) -> None:
        if self.console is None:
            return
        try:
            self.console.print(text, style="yellow", highlight=False)
        except OSError:
            pass  # the terminal is gone (SIGHUP)

    def close(self, summary: Any) -> None:
        """A hold still open ends at the last board time seen; the count and time to the summary."""
        self.log.close()
        summary.holds = self.log.holds
        summary.held_s = self.log.held_s
