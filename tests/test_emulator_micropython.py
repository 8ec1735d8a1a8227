"""The firmware under the real MicroPython interpreter (`interpreter=micropython`).

The emulator boots the same firmware files in the MicroPython WebAssembly port
(npm @micropython/micropython-webassembly-pyscript, run by Node), bridged to
the emulator's plant and UART one round trip per tick
(armbridge.emulator.micropython). Here the executor streams plans to it, with
and without link faults and a reset, and the e-stop byte stops it; the checks
read the board's own log (`executed`: board ms, id, the values the W line
carried), never the wall clock. The executor's runs are in lockstep (speed 0,
coupled to the host): paced at speed 1 the bridge's 0.3 ms of CPU per
millisecond of board time left a loaded 2-core machine little room, and a board
that falls behind the wall clock, or a host starved of the CPU, made outcomes
depend on the machine's speed.

Without node or the package these tests skip, or fail under
ARMBRIDGE_REQUIRE_HIL=1 (tests/require.py); the clear errors a user gets then
are tested without either.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from armbridge.emulator.board import EmulatedBoard
from armbridge.emulator.micropython import ENV_PACKAGE
from armbridge.errors import ArmbridgeError
from armbridge.robots import ARM3R
from emu_host import Codec, is_reply
from plan_runs import assert_executed_once_with_values, crashing_firmware, wave_plan
from require import require_micropython

ARMBRIDGE = Path(sys.executable).with_name("armbridge")


@pytest.fixture
def micropython():
    """Node and the npm package, or skip (fail under ARMBRIDGE_REQUIRE_HIL=1)."""
    require_micropython()


class Host:
    """A v2 host over the lockstep emulator's inject()/read_output()."""

    def __init__(self, emu):
        self.emu = emu
        self.codec = Codec()
        self.lines: list[tuple] = []

    def pump(self):
        self.lines += self.codec.feed(self.emu.read_output())

    def wait(self, pred, max_s=2.0):
        found = []

        def check():
            self.pump()
            found[:] = [line for line in self.lines if pred(line)]
            return bool(found)

        assert self.emu.run_until(check, max_s), self.lines[-5:]
        return found[0]

    def request(self, verb, *args):
        data = self.codec.hello(*args) if verb == "HELLO" else self.codec.line(verb, *args)
        self.emu.inject(data)
        seq = self.codec.seq
        return self.wait(lambda line: is_reply(line, seq))


# ---------------------------------------------------------------- without node or the package

def test_a_missing_package_is_one_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv(ENV_PACKAGE, str(tmp_path / "nowhere"))
    with pytest.raises(ArmbridgeError, match=f"{ENV_PACKAGE}=.*nowhere.*make setup"):
        EmulatedBoard("esp32", speed=0, interpreter="micropython")


def test_missing_node_is_one_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(ArmbridgeError, match="needs Node.js.*make setup"):
        EmulatedBoard("esp32", speed=0, interpreter="micropython")


def test_emulate_cli_says_what_to_install_in_one_line(tmp_path):
    env = dict(os.environ, **{ENV_PACKAGE: str(tmp_path / "nowhere")})
    proc = subprocess.run([str(ARMBRIDGE), "emulate", "esp32", "--interpreter", "micropython", "--for", "1"],
                          capture_output=True, text=True, timeout=60, env=env, cwd=tmp_path)
    assert proc.returncode != 0
    err = proc.stderr.strip().splitlines()
    assert len(err) == 1 and "make setup" in err[0] and "Traceback" not in proc.stderr, proc.stderr
    assert "emulator on" not in proc.stdout  # no pty was offered


# ---------------------------------------------------------------- lockstep, under MicroPython

def test_the_firmware_runs_in_the_micropython_interpreter(micropython):
    emu = EmulatedBoard("esp32", speed=0, interpreter="micropython")
    try:
        h = Host(emu)
        boot = h.wait(lambda line: line[1] == "BOOT")
        assert boot[2][:3] == ["arm3r", emu.cfg.FW_VERSION, "2"]
        assert emu.interpreter == "micropython" and emu.modules == {}  # nothing of it in this process
        assert emu.runner.version.startswith("1.")  # sys.implementation.version, in there
        assert h.request("HELLO", 7)[1] == "OK"
        target = [1771, -1471, 100]
        assert h.request("W", 0, 200, *target)[1] == "OK"
        h.wait(lambda line: line[1] == "EV" and line[2][1] == "DONE" and line[2][2] == "0")
        assert [(wid, list(v)) for _, wid, v in emu.executed] == [(0, target)]
        emu.run_for(0.5)
        assert np.allclose(emu.positions(), np.array(target) / 1000.0, atol=0.02)  # the plant followed
    finally:
        emu.stop()


# Each MicroPython board's HAL as the bridge carries it: the arm's effort rig, the paper's
# PCA9685 rig (the firmware's own driver on the bridged I2C bus), the MASR actuator.
BOARDS = {"esp32": "esp32", "pca9685": "esp32?servos=pca9685", "masr_ma": "masr_ma"}


def spec_of(board: str):
    from armbridge.emulator.registry import board_spec, rig_spec

    return rig_spec(board_spec("esp32"), "pca9685") if board == "pca9685" else board_spec(board)


def writes(hal) -> int:
    """How many output writes the emulator's HAL has seen (efforts, set points, motor efforts)."""
    if hasattr(hal, "loco_log"):
        return len(hal.loco_log) + len(hal.rot_log)
    return len(hal.positions) if hasattr(hal, "positions") else len(hal.efforts)


def start_moving(h: Host, board: str) -> None:
    """A long move under way (RUN, outputs on): a 2 s W on the arm's rigs; HOME and a 300 mm MV on the MA."""
    emu = h.emu
    if board != "masr_ma":
        free = int(h.request("STAT")[2][1])
        for i in range(free):
            assert h.request("W", i, 2000, 1571 + (300 if i % 2 == 0 else -300), -1571, 0)[1] == "OK"
        emu.run_for(0.05)
        return
    assert h.request("HOME", 0)[1] == "OK" and h.request("MV", 1, 300)[1] == "OK"
    for _ in range(40):             # the watchdog (1 s) is fed by the STATs
        emu.run_for(0.05)
        h.request("STAT")
        if len(emu.executed) == 1 and abs(emu.plant.v) > 0.05:
            return
    raise AssertionError(f"the MA did not start its MV: {emu.executed}, {h.lines[-3:]}")


@pytest.mark.parametrize("board", sorted(BOARDS))
def test_estop_byte_turns_the_outputs_off_and_the_latch_survives_a_reset(micropython, board):
    emu = EmulatedBoard(spec_of(board), speed=0, interpreter="micropython")
    try:
        h = Host(emu)
        h.request("HELLO", 5)
        start_moving(h, board)
        assert emu.state == "RUN" and emu.hal.outputs_enabled
        emu.inject(b"\x98")
        h.wait(lambda line: line[1] == "EV" and line[2][1] == "ESTOP")
        assert len(emu.estop_byte_at) == 1
        latency = emu.outputs_off_at[-1] - emu.estop_byte_at[-1]
        assert 0 <= latency <= 0.002  # sim time: the board polls every millisecond
        n_out = writes(emu.hal)
        emu.run_for(0.3)
        assert emu.state == "ESTOP" and not emu.hal.outputs_enabled and writes(emu.hal) == n_out
        move = ("MV", 99, 100) if board == "masr_ma" else ("W", 99, 100, 1571, -1571, 0)
        refused = h.request(*move)
        assert refused[1] == "ER" and refused[2][2] == "LATCHED"

        emu.reset()  # a fresh interpreter boots from the persisted memory
        h.wait(lambda line: line[1] == "BOOT" and line[2][3] == "ESTOP")
        assert len(emu.boots) == 2 and emu.state == "ESTOP"
        assert h.request("HELLO", 5)[2][-1] == "ESTOP"  # no HELLO releases a latch
        emu.run_for(0.2)
        assert not emu.hal.outputs_enabled and writes(emu.hal) == n_out
        assert h.request("CLR")[1] == "OK"
        emu.run_for(0.05)
        assert emu.state == "IDLE" and emu.crash is None
    finally:
        emu.stop()


def test_a_firmware_exception_shows_the_micropython_traceback(micropython, tmp_path):
    crashing_firmware(tmp_path)
    emu = EmulatedBoard("esp32", speed=0, firmware_root=tmp_path, interpreter="micropython")
    try:
        with pytest.raises(RuntimeError, match="boom"):
            emu.step(1)
        assert emu.state == "CRASHED"
        assert "under MicroPython" in emu.crash and "arm.py" in emu.crash and "boom" in emu.crash
        emu.reset()
        emu.run_for(0.255)
        assert emu.state == "IDLE" and len(emu.boots) == 2
    finally:
        emu.stop()


# ---------------------------------------------------------------- the executor, in lockstep

@pytest.mark.hil
@pytest.mark.parametrize("board", sorted(BOARDS))
def test_a_plan_runs_every_waypoint_once_with_its_values(micropython, board, tmp_path, ports):
    """One whole plan per MicroPython board, the executor against the firmware under the real
    interpreter: every waypoint (the MA: every action) done once, in order, with its values."""
    from armbridge.executor.run import run_plan

    url = f"emu:{BOARDS[board]}" + ("&" if "?" in BOARDS[board] else "?") + "interpreter=micropython&speed=0&seed=3"
    if board == "masr_ma":
        from armbridge.executor.masr import masr_commands
        from armbridge.planning.masr.plan_file import load_masr_plan
        from test_masr_exec import assert_each_action_once, line_plan

        path = line_plan(tmp_path)   # HOME, onto joint 2, turn it, 150 mm along link 2
        s = run_plan(path, url, tmp_path / "mp.rrd", progress=False, home=True)
        emu = ports[0].emulator
        commands = masr_commands(load_masr_plan(path), home=True)[1]
        assert_each_action_once(emu, commands)
        assert len(emu.hal.hall_log) >= 2 and emu.plant.d == pytest.approx(0.35, abs=0.005)  # the goal's d
        # the same plan and seed under CPython: the same run, bit for bit (the bridge hands the firmware
        # the same counts and hall edges at the same clock, and replays its efforts exactly)
        run_plan(path, url.replace("micropython", "cpython"), tmp_path / "cp.rrd", progress=False, home=True)
        cp = ports[1].emulator
        assert cp.interpreter == "cpython" and cp.executed == emu.executed
        assert cp.plant.q.tolist() == emu.plant.q.tolist() and list(cp.hal.hall_log) == list(emu.hal.hall_log)
    else:
        plan = wave_plan(40)
        s = run_plan(plan, url, tmp_path / "mp.rrd", progress=False)
        emu = ports[0].emulator
        assert_executed_once_with_values(emu, plan)
        assert np.allclose(emu.positions(), plan.q[-1], atol=0.03)   # the plant followed
        if board == "pca9685":   # the firmware's own driver drove the simulated chip
            assert emu.hal.bus.transfers > 40 and emu.hal.positions
    assert emu.interpreter == "micropython" and emu.crash is None
    assert s.completed and s.final_state == "IDLE", s


def reset_after(ports, n: int, stop: threading.Event) -> threading.Thread:
    """Resets the board of the first port opened once its own log holds n
    completed waypoints: mid-plan whatever the handshake took on a busy machine."""
    def watch():
        while not stop.wait(0.005):
            if ports and len(ports[0].emulator.executed) >= n:
                ports[0].emulator.reset()
                return

    t = threading.Thread(target=watch, daemon=True)
    t.start()
    return t


@pytest.mark.hil
def test_link_faults_and_a_reset_every_waypoint_once_in_order(micropython, tmp_path, ports):
    """1% of bytes dropped, 1% with a bit flipped, 1% doubled, both directions, and
    a board reset (a fresh MicroPython interpreter) mid-plan."""
    from armbridge.executor.run import run_plan

    plan = wave_plan(60)
    url = "emu:esp32?interpreter=micropython&speed=0&drop=0.01&corrupt=0.01&dup=0.01&seed=11"
    stop = threading.Event()
    watcher = reset_after(ports, 20, stop)
    try:
        s = run_plan(plan, url, tmp_path / "faults.rrd", progress=False)
    finally:
        stop.set()
        watcher.join()
    emu = ports[0].emulator
    assert emu.crash is None
    assert s.completed and s.waypoints_done == 60, s
    assert_executed_once_with_values(emu, plan)
    assert emu.counters["resets"] == 1 and len(emu.boots) == 2 and s.resyncs >= 1
    before = [wid for ms, wid, _ in emu.executed if ms < emu.resets[0] * 1000]
    assert 0 < len(before) < 60  # the reset fell mid-plan
    c = emu.counters
    assert c["rx"]["corrupt"] > 0 and c["rx"]["drop"] > 0 and c["tx"]["dup"] > 0
    assert s.waypoints_retransmitted > 0 and s.line_errors > 0


@pytest.mark.hil
def test_the_hosts_estop_stops_a_moving_board(micropython, ports):
    from armbridge.executor.session import open_session

    with open_session("emu:esp32?interpreter=micropython&speed=0", ARM3R) as client:
        emu = ports[0].emulator
        client.command("W", 0, 3000, 2471, -1171, 400)  # a 3 s move
        assert client.stat()[0] == "RUN" and emu.hal.outputs_enabled
        client.estop()
        state = client.stat()[0]
        for _ in range(20):
            if state == "ESTOP":
                break
            state = client.stat()[0]
        assert state == "ESTOP" and emu.state == "ESTOP"
        assert len(emu.estop_byte_at) == 1 and not emu.hal.outputs_enabled
        assert 0 <= emu.outputs_off_at[-1] - emu.estop_byte_at[0] <= 0.002  # sim time
        assert emu.executed == []  # the move never finished


# ---------------------------------------------------------------- the cost bench

def test_bench_firmware_measures_every_item_in_both_interpreters(micropython, tmp_path):
    """Every MicroPython board (the esp32 on both rigs, the MA): each item answered as it
    must be in both interpreters, the heap per poll, the live heap and its headroom."""
    from armbridge.bench import firmware_cost
    from armbridge.emulator.mpbridge import fwcost

    out = tmp_path / "bench.json"
    proc = subprocess.run([str(ARMBRIDGE), "bench", "firmware", "--reps", "30", "--json", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    doc = json.loads(out.read_text())
    assert set(doc["boards"]) == {"esp32", "esp32 pca9685", "masr_ma"}
    assert doc["chip_free_heap_bytes"] == firmware_cost.CHIP_FREE_HEAP and "mem_free" in doc["chip_free_heap_source"]
    for key, r in doc["boards"].items():
        verb = "MV" if key == "masr_ma" else "W"
        names = fwcost.items("ma" if key == "masr_ma" else "arm")
        for who in ("micropython", "cpython"):
            res = r[who]
            assert set(res["lines"]) | set(res["ticks"]) | set(res["codec"]) == set(names)
            for group in ("lines", "ticks", "codec"):
                for name, st in res[group].items():
                    assert st["n"] == 30 and st["answers"] == {fwcost.EXPECT[name]: 30}, (key, who, name, st)
                    assert st["median_us"] <= st["p99_us"]
            assert res["ticks"]["idle"]["state"] == "IDLE" and res["ticks"]["RUN"]["state"] == "RUN"
            b = r["tick_budget"][who]
            assert b["w_lines_per_tick"] == 3.0
            assert b["w_us_per_tick"] == pytest.approx(3 * res["lines"][verb]["median_us"], abs=0.1)
        mp, m = r["micropython"], r["memory"]
        assert mp["interpreter"].startswith("MicroPython")
        assert mp["lines"][verb]["alloc_bytes"] > 0  # the heap a waypoint line costs
        assert m["alloc_per_tick_bytes"] == max(st["alloc_bytes"] for st in mp["ticks"].values()) > 0
        assert 20_000 < m["live_heap_after_boot_bytes"] <= m["live_heap_after_run_bytes"] < mp["heap_live_after_bench"]
        assert m["headroom_bytes"] == doc["chip_free_heap_bytes"] - m["live_heap_after_run_bytes"]
    assert "W lines/s" in proc.stdout and "MV lines/s" in proc.stdout and "headroom" in proc.stdout


def test_bench_firmware_names_its_boards_in_one_line(tmp_path):
    proc = subprocess.run([str(ARMBRIDGE), "bench", "firmware", "--device", "arduino_pump", "--json", "-"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    err = proc.stderr.strip().splitlines()
    assert len(err) == 1 and "--device masr_ma" in err[0] and "--servos pca9685" in err[0], err
