"""The link engine (executor/engine.py, remote.py, wire.py): a session whose timing-critical
work keeps its schedule whatever the caller's thread does.

The caller's thread is kept busy the way bench load keeps it: a call that holds the GIL
for 1.5 s (`hold_gil`: a C call through ctypes.PyDLL keeps the GIL for exactly that long
on any machine), or pure-Python work as long. Each case is run twice where that shows
what the test is worth: with the session in the caller's thread the board's 1 s watchdog
fires, with the engine it does not.
"""
from __future__ import annotations

import signal
import time

import numpy as np
import pytest
from cli_procs import Proc, emulated_board

from armbridge.bench.load import hold_gil, slow_plan
from armbridge.errors import ArmbridgeError
from armbridge.executor.session import open_session
from armbridge.executor.wire import Aborted, decode, encode, restore_snapshot, snapshot
from armbridge.link import protocol as P
from armbridge.link.transport import PortError
from armbridge.robots.catalog import get_robot

ARM3R = get_robot("arm3r")


@pytest.fixture
def board(tmp_path):
    yield from emulated_board(tmp_path)


def hog_once(seconds: float, busy):
    """A telemetry callback that keeps the caller busy once, after the plan has started."""
    state = {"done": False}

    def on_telemetry(t, m):
        if not state["done"] and m.state == "RUN":
            state["done"] = True
            busy(seconds)

    return on_telemetry


def spin(seconds: float) -> None:
    end = time.monotonic() + seconds
    x = 0
    while time.monotonic() < end:
        x += 1


def run_slow_plan(url: str, engine: str, on_telemetry, seconds: float = 4.0):
    durations, q = slow_plan("arm3r", seconds)
    with open_session(url, ARM3R, latched="clear", rate_hz=50, on_telemetry=on_telemetry, engine=engine) as c:
        error = None
        try:
            c.execute(durations, q)
        except ArmbridgeError as exc:
            error = str(exc)
        state = c.stat()[0]
        return error, state, c.stats


# ------------------------------------------------------------------ the messages

def test_messages_cross_as_json_and_come_back_as_what_they_were():
    tel = P.Telemetry(7, 1234, "RUN", 3, 30, np.array([0.1, -0.2, 0.3]), np.array([0.1, -0.2, 0.31]),
                      np.array([0.0, 0.5, -1.0]), (12, 34))
    ev = P.Event(8, 1240, "DONE", ("3", "31"))
    for m in (tel, ev):
        back = decode(encode({"k": "tel", "t": 1.25, "m": m}))["m"]
        assert type(back) is type(m) and back.bseq == m.bseq and back.ms == m.ms
        if isinstance(m, P.Telemetry):
            assert np.array_equal(back.q, m.q) and back.extra == m.extra and back.state == "RUN"
        else:
            assert back.args == m.args
    ok, er = P.Ok(1, 5, 30, ("esp32", "1.0")), P.Er(2, 6, 4, "RANGE", ("j", "2"))
    msg = decode(encode({"k": "ret", "id": 1, "value": (ok, er, np.array([1.0, 2.0]), "default")}))
    assert msg["value"][0] == ok and msg["value"][1] == er and msg["value"][3] == "default"
    assert np.array_equal(msg["value"][2], [1.0, 2.0])
    err = decode(encode({"k": "exc", "id": 2, "error": PortError("port x is busy", usage=True)}))["error"]
    assert isinstance(err, PortError) and err.usage and err.exit_code == 2 and str(err) == "port x is busy"
    assert isinstance(decode(encode({"k": "exc", "id": 3, "error": Aborted("ended")}))["error"], Aborted)
    odd = decode(encode({"k": "exc", "id": 4, "error": ZeroDivisionError("x")}))["error"]
    assert isinstance(odd, ArmbridgeError) and "ZeroDivisionError" in str(odd)


def test_a_snapshot_survives_the_crossing():
    from armbridge.executor.client import BoardClient

    class FakePort:
        timeout = 0.0
        in_waiting = 0

    c = BoardClient(FakePort(), ARM3R, session=9)
    c.state, c.fault_reason = "FAULT", "joint 2 (elbow): following error 412 mrad"
    c.stats.timeouts = 3
    import json

    snap = restore_snapshot(json.loads(json.dumps(snapshot(c))))
    assert snap["state"] == "FAULT" and snap["fault_reason"].startswith("joint 2")
    assert snap["stats"].timeouts == 3 and snap["session"] == 9 and snap["done_index"] == -1


# ------------------------------------------------------------------ a board in another process

@pytest.mark.hil
def test_a_call_holding_the_gil_does_not_trip_a_board_in_another_process(board):
    _, link = board
    error, state, stats = run_slow_plan(link, "process", hog_once(1.5, hold_gil))
    assert error is None and state == "IDLE", error
    assert stats.longest_quiet_s < 0.5 and stats.spurious_timeouts == 0
    # The same with the session in the caller's thread: the board's watchdog fires.
    error, state, _ = run_slow_plan(link, "inline", hog_once(1.5, hold_gil))
    assert state == "WDOG" and "watchdog" in error


@pytest.mark.hil
def test_the_engine_estops_the_board_when_its_caller_is_killed(tmp_path, board):
    from armbridge.plans.format import make_plan, save_plan

    emu, link = board
    plan = tmp_path / "plan.json"
    save_plan(make_plan(ARM3R, [[1.5 + 0.3 * (i % 2), -1.5, 0.0] for i in range(40)], 0.25), plan)
    run = Proc("run", str(plan), "--port", link, "--no-progress", "--rrd", str(tmp_path / "x.rrd"))
    emu.wait_for(" DONE 1 ")
    run.p.send_signal(signal.SIGKILL)  # no handler runs: only the engine's child is left to act
    run.p.wait()
    emu.wait_for(" ESTOP*")


# ------------------------------------------------------------------ an emulator paced in this process

@pytest.mark.hil
def test_a_busy_python_caller_does_not_trip_an_emulator_paced_in_this_process():
    error, state, stats = run_slow_plan("emu:esp32", "thread", hog_once(1.5, spin))
    assert error is None and state == "IDLE", error
    assert stats.spurious_timeouts == 0
    # The control: inline, the caller's own thread keeps the schedule, and a caller away for 1.5 s
    # trips the board. Away asleep, not spinning: a spinning caller would also starve the paced
    # emulator's thread of the GIL on a loaded machine, and a board that cannot keep the wall clock
    # gives the lost time up (board.py MAX_CATCHUP_S), so its watchdog would not see the whole gap.
    error, state, _ = run_slow_plan("emu:esp32", "inline", hog_once(1.5, time.sleep))
    assert state == "WDOG" and "watchdog" in error


@pytest.mark.hil
def test_estop_from_the_caller_ends_the_running_call_and_reaches_the_board():
    durations, q = slow_plan("arm3r", 6.0)
    with open_session("emu:esp32", ARM3R, latched="clear", rate_hz=50, engine="thread") as c:
        emu = c.port.emulator

        def progress(n):
            if n == 2:
                c.estop()

        with pytest.raises(ArmbridgeError):
            c.execute(durations, q, on_progress=progress)
        c.drain(0.5, until=lambda: c.state == "ESTOP", resync=False)
        assert c.state == "ESTOP" and len(emu.estop_byte_at) == 1
        assert c.done_index < len(durations) - 1
        assert c.stat()[0] == "ESTOP"
