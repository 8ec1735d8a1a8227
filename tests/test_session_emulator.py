"""Sessions against the emulated ESP32 board (real firmware, real pty): epochs
renewed mid-plan under link faults, a second host with the same session (STALE,
then the next epoch), a copy of an old epoch's line, and open_session's latch
policies across sessions and a reset. Truth is the board's own log of executed
waypoints (board ms, id, values)."""
from __future__ import annotations

import math

import numpy as np
import pytest

import armbridge.link.transport as transport
from armbridge.emulator.board import EmulatedBoard
from armbridge.errors import ArmbridgeError
from armbridge.executor.client import BoardClient
from armbridge.executor.session import open_session
from armbridge.link import protocol as P
from armbridge.robots import ARM3R

MID = np.array([math.pi / 2, -math.pi / 2, 0.0])
SPEED = 0  # emu: ports in lockstep, coupled to the host: nothing here depends on the machine's speed


def wave(k: int, offset: int = 0) -> tuple[list[int], list[list[int]]]:
    """k waypoints 50 ms apart, a gentle wave around the middle of arm3r's ranges (mrad)."""
    t = 0.05 * np.arange(offset + 1, offset + k + 1)
    q = MID + np.outer((1 - np.cos(2 * np.pi * 0.5 * t)) / 2, (0.3, 0.2, 0.3))
    return [50] * k, [P.to_milli(row) for row in q]


def log(emu) -> list[tuple[int, tuple[int, ...]]]:
    return [(wid, values) for _, wid, values in emu.executed]


@pytest.mark.hil
def test_epochs_renewed_mid_plan_under_link_faults():
    port = transport.open_port(f"emu:esp32?speed={SPEED}&drop=0.005&corrupt=0.005&dup=0.005&seed=5")
    try:
        client = BoardClient(port, ARM3R, max_epoch_commands=40)
        client.connect()
        durs, q = wave(150)
        client.execute(durs, q)
        assert log(port.emulator) == [(i, tuple(q[i])) for i in range(150)]
        s = client.stats
        assert s.epoch_renewals >= 150 // 40  # a new epoch at least every 40 commands
        assert s.epochs >= s.epoch_renewals + 1 and client.arq.epoch >= s.epochs
        assert port.emulator.state == "IDLE"
    finally:
        port.close()


@pytest.mark.hil
def test_a_second_host_with_the_same_session_starts_past_the_first():
    port = transport.open_port(f"emu:esp32?speed={SPEED}")
    try:
        emu = port.emulator
        first = BoardClient(port, ARM3R, session=77)
        first.connect()
        for _ in range(2):
            first.arq.need_resync = "test: two resyncs move the epoch on"
            first._resync()
        durs, q1 = wave(20)
        first.execute(durs, q1)
        old_epoch = first.arq.epoch
        assert old_epoch == 3
        late_copy = P.encode(5, "W", 20, 50, *q1[-1], epoch=old_epoch)

        second = BoardClient(port, ARM3R, session=77)  # starts at epoch 1: STALE 3, then 4
        second.connect()
        assert second.arq.epoch == old_epoch + 1
        _, q2 = wave(20, offset=20)
        second.execute(durs, q2)
        # Its ids follow on from the board's newest (19), so the board's `done` of
        # the first host's plan never counts as one of the second's.
        want = [(i, tuple(q1[i])) for i in range(20)] + [(20 + i, tuple(q2[i])) for i in range(20)]
        assert log(emu) == want
        # A line of the first host's epoch, however late, fails the board's CRC.
        errors = second.stats.board_framing_errors
        port.write(late_copy)
        second.drain(0.3)
        assert log(emu) == want and second.stats.board_framing_errors == errors + 1
    finally:
        port.close()


@pytest.mark.hil
def test_open_session_latch_policies_across_sessions_and_a_reset():
    # By its pty's path, as a serial device: the host on the wall clock, so the board paced to it (its
    # waits are hang guards; the board's 1 s watchdog wants a keep-alive within 0.75 s of wall time).
    emu = EmulatedBoard("esp32", speed=1).start()
    try:
        with open_session(emu.port, ARM3R, rate_hz=0) as c:
            assert c.state == "IDLE" and c.info.limits_milli[0] == (0, 3142, 3000)
            c.estop()
            c.drain(30.0, until=lambda: c.state == "ESTOP")  # it comes at once: 30 s is a hang guard
            assert c.state == "ESTOP"
        with pytest.raises(ArmbridgeError, match="latched in ESTOP from before.*--clear"):
            with open_session(emu.port, ARM3R):
                pass
        emu.reset()  # the latch survives a reset
        with open_session(emu.port, None, latched="allow", connect_timeout=30.0) as c:  # a hang guard
            assert c.state == "ESTOP" and c.info.fw == "arm3r" and c.info.n == 3
        with open_session(emu.port, ARM3R, latched="clear", rate_hz=10) as c:
            assert c.state == "IDLE"
            durs, q = wave(5)
            c.execute(durs, q)
        assert log(emu) == [(i, tuple(q[i])) for i in range(5)]
        with pytest.raises(ArmbridgeError, match="latch policy 'maybe'"):
            with open_session(emu.port, ARM3R, latched="maybe"):
                pass
    finally:
        emu.stop()


@pytest.mark.hil
def test_a_fault_is_named_in_the_run_and_in_the_next_session():
    """The shoulder seizes; the board latches FAULT (following error): the run's
    error names the joint and the error, and a later session, which never saw the
    event, still names the joint from STAT's latch reason."""
    emu = EmulatedBoard("esp32", speed=1).start()
    try:
        with open_session(emu.port, ARM3R, rate_hz=10) as c:
            emu.schedule_stall(1, emu.now())
            durs, q = wave(60)
            q = [[v + 400 * (i + 1) // 60 if j == 0 else v for j, v in enumerate(row)] for i, row in enumerate(q)]
            with pytest.raises(ArmbridgeError, match=r"FAULT latched, joint 1 \(shoulder\): following error \d+ mrad"):
                c.execute(durs, q)
        assert emu.state == "FAULT"
        with pytest.raises(ArmbridgeError, match=r"latched in FAULT \(joint 1 \(shoulder\): following error\) from "
                                                 r"before.*--clear"):
            with open_session(emu.port, ARM3R):
                pass
    finally:
        emu.stop()
