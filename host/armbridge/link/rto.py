"""The retransmission timer of the session layer (link/arq.py).

How long to wait for an answer, counted from when a line should have reached
the board: 4 x the time of a command line and its answer + 50 ms to start
with, then the measured answer times (Jacobson/Karels: smoothed round trip +
4 x its mean deviation; Karn: only lines sent once give samples, since the
answer to a resent line cannot be told from the answer to its first copy),
never below the time an answer needs when it queues behind a telemetry line,
never above the initial value. While the board sends nothing at all
(rebooting, unplugged) every timeout doubles a back-off, up to 0.5 s; any
answer ends it.
"""
from __future__ import annotations

from armbridge.link import protocol as P

RTO_MAX_S = 0.5  # the longest wait with back-off (a board that is rebooting)
MAX_BACKOFF = 64.0


class RetransmitTimer:
    """RTO for a link of `byte_time` seconds per byte (on the session's clock)."""

    def __init__(self, byte_time: float) -> None:
        line_pair = (P.MAX_HOST_LINE + 40) * byte_time
        self.initial = 4 * line_pair + 0.050
        self.min = (P.MAX_BOARD_LINE + P.MAX_HOST_LINE) * byte_time + 0.002
        self.max = RTO_MAX_S
        self.rto = self.initial
        self.srtt: float | None = None
        self.rttvar = 0.0
        self.backoff = 1.0

    def timeout(self) -> float:
        """The wait for a line sent now."""
        return min(self.max, self.rto * self.backoff)

    def sample(self, seconds: float) -> None:
        """An answer to a line sent once came `seconds` after the line reached the board."""
        if self.srtt is None:
            self.srtt, self.rttvar = seconds, seconds / 2
        else:
            self.rttvar = 0.75 * self.rttvar + 0.25 * abs(self.srtt - seconds)
            self.srtt = 0.875 * self.srtt + 0.125 * seconds
        self.rto = min(self.initial, max(self.min, self.srtt + 4 * self.rttvar))

    def answered(self) -> None:
        self.backoff = 1.0

    def expired_in_silence(self) -> None:
        self.backoff = min(self.backoff * 2, MAX_BACKOFF)
