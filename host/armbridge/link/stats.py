"""What happened on the link during a session (kept by link/arq.py, shown in run summaries)."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass
class LinkStats:
    """What happened on the link during a session."""

    lines_sent: int = 0  # every line written, retransmissions included
    commands: int = 0  # distinct commands (seqs) issued
    retransmissions: int = 0  # lines written again (any verb)
    waypoints_sent: int = 0  # distinct waypoints sent at least once
    waypoint_lines: int = 0  # W lines written, retransmissions and resends included
    waypoints_acked: int = 0  # distinct waypoints answered OK
    timeouts: int = 0  # retransmission timer expiries
    spurious_timeouts: int = 0  # of those, shown by a later answer to be the board being late (F-RTO)
    seq_errors: int = 0  # ER SEQ answers
    board_framing_errors: int = 0  # ER - CRC/PARSE/LONG from the board (our lines damaged)
    host_line_errors: int = 0  # board lines the host could not decode (their lines damaged)
    v1_lines: int = 0  # of those, lines framed as protocol 1 (CRC-16): an old firmware
    board_lines_lost: int = 0  # gaps in the board's line counter
    nosession: int = 0
    resyncs: int = 0  # resyncs after a fault (BOOT, NOSESSION, silence, confusion)
    epochs: int = 0  # epochs opened (HELLOs accepted), renewals included
    epoch_renewals: int = 0  # routine new epochs before seqs would repeat
    boots: int = 0
    pings: int = 0
    slow_events: int = 0
    window_cuts: int = 0  # congestion window halvings (lines lost on the way to the board)
    # The longest the host sent nothing while the session was open (session clock, s): keep-alives
    # every `keepalive` s hold it near that; what the board's watchdog would see of a host that stalls.
    longest_quiet_s: float = 0.0

    @property
    def waypoints_retransmitted(self) -> int:
        return self.waypoint_lines - self.waypoints_sent

    @property
    def line_errors(self) -> int:
        return self.board_framing_errors + self.host_line_errors
