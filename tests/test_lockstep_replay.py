"""A lockstep run repeats bit for bit (issue 21, section 3): a failing hardware-in-the-loop
run can be replayed from its seed.

The MA's own firmware (firmware/masr_ma) on its emulator at speed 0, driven by the real
host (BoardClient: the session layer, retransmissions, keep-alives) through the lockstep
port (emulator/lockstep.py: host and board take turns in one thread, the host's clock is
the sim clock). The same actions, seed and session give the same bytes, telemetry, events,
link statistics and plant truth: with link faults and a slip burst (every random draw of
the emulator), with a host that is slow on the wall clock at random moments, and in
another process with another hash seed (no set or dict order leaks in).

Before the lockstep port, the same seed over the `emu:` pty (the emulator in a thread of
its own, coupled to its host's reads) gave another run each time: the host's lines landed
on the board's clock wherever the two threads happened to be.
"""
from __future__ import annotations

import hashlib
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import pytest

from armbridge.emulator.lockstep import lockstep_port
from armbridge.emulator.url import open_lockstep_port
from armbridge.emulator import EmulatedBoard
from armbridge.errors import ArmbridgeError
from armbridge.executor.client import BoardClient
from armbridge.robots import get_robot

URL = "emu:masr_ma?speed=0&seed=11&drop=0.002&corrupt=0.002&dup=0.002&slip=3:0.4:0.005"
SESSION = 4242
# HOME, turns, moves over magnets both ways (the board's ids are the list's indices)
COMMANDS = [("HOME", []), ("ROT", [1, 300]), ("ROT", [3, -250]), ("MV", [650]), ("ROT", [4, 200]),
            ("MV", [150])]


def run_once(busy_host: bool = False) -> dict:
    """The actions on a fresh lockstep board -> everything either side recorded."""
    port = open_lockstep_port(URL)
    emu = port.emulator
    rec: dict = {"telemetry": [], "events": [], "errors": []}
    wall = random.Random(5)

    def on_telemetry(t, m) -> None:
        rec["telemetry"].append((t, m.state, m.done, m.free, tuple(m.q), tuple(m.target), tuple(m.effort),
                                 tuple(m.extra)))
        if busy_host and wall.random() < 0.05:
            time.sleep(wall.random() * 0.003)           # the host's thread is slow now and then

    try:
        client = BoardClient(port, get_robot("masr5"), SESSION, on_telemetry=on_telemetry,
                             on_event=lambda t, ev: rec["events"].append((t, ev.kind, tuple(ev.args))),
                             on_error=lambda t, text: rec["errors"].append((t, text)))
        client.connect()
        client.execute([1000] * len(COMMANDS), [], commands=COMMANDS)
        client.drain(0.3)
        rec["stats"] = dict(vars(client.stats))
        rec["done_times"] = dict(client.done_times)
    finally:
        port.close()
    rec.update(board_telemetry=list(emu.hal.telemetry), executed=list(emu.executed), hall=list(emu.hal.hall_log),
               faults=list(emu.hal.faults_applied), counters=emu.counters, truth=emu.plant.q.tolist(),
               t_end=emu.now())
    return rec


def digest(rec: dict) -> str:
    return hashlib.sha256(repr(sorted(rec.items())).encode()).hexdigest()


@pytest.fixture(scope="module")
def first():
    return run_once()


def test_the_run_exercises_the_link_faults_and_the_plant(first):
    """What the replay repeats is a run worth replaying: every action done once, lines damaged and
    resent, the slip burst applied, the MA where the actions put it."""
    assert [wid for _, wid, _ in first["executed"]] == list(range(len(COMMANDS)))
    c = first["counters"]
    assert c["rx"]["drop"] + c["rx"]["corrupt"] > 0 and c["tx"]["corrupt"] + c["tx"]["dup"] > 0
    st = first["stats"]
    assert st["board_framing_errors"] + st["host_line_errors"] > 0 and st["retransmissions"] > 0
    assert ("slip", 0.005) in [(k, v) for _, k, v in first["faults"]]
    assert abs(first["truth"][-1] - 0.150) < 0.005 and abs(first["truth"][2] + 0.250) < 0.005
    assert len(first["telemetry"]) > 100 and first["events"]


def test_a_second_run_with_the_same_seed_is_identical(first):
    second = run_once()
    for key in first:
        assert second[key] == first[key], key
    assert digest(second) == digest(first)


def test_a_slow_host_does_not_change_the_run(first):
    """The host's thread stalls on the wall clock at random samples: nothing on the sim clock moves."""
    assert run_once(busy_host=True) == first


def test_another_process_with_another_hash_seed_repeats_the_run(first):
    code = ("import sys; sys.path.insert(0, 'tests'); import test_lockstep_replay as t; "
            "print(t.digest(t.run_once()))")
    root = Path(__file__).resolve().parent.parent
    proc = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONHASHSEED": "12345"})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split()[-1] == digest(first)


def test_another_seed_gives_another_run(first):
    """The seed does reach the emulator's draws (a replay that ignored it would pass the tests above)."""
    port = open_lockstep_port(URL.replace("seed=11", "seed=12"))
    try:
        client = BoardClient(port, get_robot("masr5"), SESSION)
        client.connect()
        client.execute([1000] * len(COMMANDS), [], commands=COMMANDS)
        truth = port.emulator.plant.q.tolist()
    finally:
        port.close()
    assert truth != first["truth"]


def test_the_lockstep_port_runs_the_board_on_sim_time_only():
    """A read runs the board until its first byte (no further), or for `timeout` seconds of sim time
    when it sends nothing, however long either takes on the wall clock; the port refuses a paced or
    running emulator."""
    emu = EmulatedBoard("masr_ma", speed=0, seed=1)
    port = lockstep_port(emu, "emu:masr_ma?speed=0")
    try:
        assert port.clock() == emu.now() == 0.0
        assert port.read(100) == b"\n"                        # the BOOT line's leading newline, sent at 0
        assert port.read(1) == b"0" and 0 < port.clock() <= 0.0011      # the next byte: within one 1 ms tick
        client = BoardClient(port, None, SESSION)
        client.connect()
        client.set_rate(0)                                     # no telemetry: the board falls silent
        client.drain(0.1)
        port.timeout = 0.25
        t0 = port.clock()
        assert port.read(1) == b"" and port.clock() - t0 == pytest.approx(0.25, abs=0.0011)
        assert port.in_waiting == 0 and port.clock() - t0 < 0.252   # in_waiting does not run the board
    finally:
        port.close()
    with pytest.raises(ArmbridgeError, match="speed=0"):
        open_lockstep_port("emu:masr_ma?speed=2")
    paced = EmulatedBoard("masr_ma", speed=1.0)
    try:
        with pytest.raises(ArmbridgeError, match="speed 0"):
            lockstep_port(paced, "emu:masr_ma")
    finally:
        paced.stop()
