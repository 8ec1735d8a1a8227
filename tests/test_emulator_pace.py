"""A paced emulator that falls behind the wall clock (docs/emulator.md, "Pace").

The board is made slower than real time on purpose, the same on any machine: its
plant sleeps 1.5 ms in every 1 ms tick, so the emulator runs at about 0.6x. It must
still take the host's bytes in at once (it read nothing while it caught up, and a
board just slower than real time let its watchdog fire under a host that kept
sending), and it must say that it cannot keep up.
"""
from __future__ import annotations

import time

import pytest
import serial  # type: ignore[import-untyped]

from armbridge.emulator.board import EmulatedBoard
from armbridge.link import protocol as P

pytestmark = pytest.mark.hil

SLOW_S = 0.0015  # plant time per 1 ms tick: the board runs at about 0.6x of real time


def slow_board(notes: list[str], lines: list[tuple[float, bytes]]) -> EmulatedBoard:
    emu = EmulatedBoard("esp32", speed=1.0, on_note=notes.append, on_line=lambda t, line: lines.append((t, line)))
    real = emu.plant.advance_to

    def advance_to(t: float) -> None:
        time.sleep(SLOW_S)
        real(t)

    emu.plant.advance_to = advance_to  # type: ignore[method-assign]
    return emu


def test_a_board_slower_than_real_time_takes_host_lines_at_once_and_says_it_cannot_keep_up():
    notes: list[str] = []
    lines: list[tuple[float, bytes]] = []
    emu = slow_board(notes, lines).start()
    try:
        with serial.Serial(emu.port, timeout=0.05) as port:
            answered = []
            for seq in range(1, 13):  # HELLOs 0.25 s apart while the board lags further and further
                time.sleep(0.25)
                port.write(P.encode(seq, "HELLO", P.PROTOCOL_VERSION, 7, seq))
                sent = emu.now()  # after the write: a late read can only make the wait look shorter
                end = time.monotonic() + 30  # a hang guard
                while time.monotonic() < end:
                    reply = [t for t, line in lines if line.split()[1:2] in ([b"OK"], [b"ER"])
                             and line.split()[2] == str(seq).encode()]
                    if reply:
                        answered.append(reply[0] - sent)
                        break
                    time.sleep(0.01)
        pace = emu.pace()
    finally:
        emu.stop()
    # each answered in the board's own time of a line and its answer (3 ms), not after sim time the
    # board ran on without reading the pty (15-60 ms here with the pty left unread while catching up)
    assert len(answered) == 12 and max(answered) < 0.01, answered
    assert pace["achieved"] < 0.9 and pace["overruns"] >= 1, pace
    assert any("cannot keep up with the wall clock" in n for n in notes), notes
