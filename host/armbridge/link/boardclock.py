"""Board time: the `ms` of T and EV lines, unwrapped into seconds."""
from __future__ import annotations

from armbridge.link.protodef import TICKS_PERIOD


class BoardClock:
    """Unwraps board milliseconds (mod 2**30, MicroPython's ticks_ms) into seconds
    that never run backwards by more than a few ms; a board whose clock restarted
    (a reset on real hardware) is rebased to continue where it was, so a
    recording's board_time timeline stays monotonic across resets."""

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
