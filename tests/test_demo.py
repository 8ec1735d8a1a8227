"""`armbridge demo` end to end: the real program, the emulator on a pty, a .rrd."""
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from armbridge.demos.arm3r import square_plan
from armbridge.plans.format import load_plan
from armbridge.robots.catalog import get_robot

ARMBRIDGE = Path(sys.executable).with_name("armbridge")


@pytest.fixture(scope="module", autouse=True)
def demo_run(request, tmp_path_factory):
    """`armbridge demo --rrd demo.rrd` (its own emulator, on the wall clock: about 10 s,
    mostly waiting for the arm), started with the module when
    test_demo_runs_to_the_end_and_records is to run, so the module's other tests run
    beside it; that test, last, reads what it did. (the process, the .rrd) or None."""
    wanted = any(item.name == "test_demo_runs_to_the_end_and_records" and item.module is request.module
                 for item in request.session.items)
    if not wanted:
        yield None
        return
    rrd = tmp_path_factory.mktemp("demo") / "demo.rrd"
    env = dict(os.environ, COLUMNS="120")
    proc = subprocess.Popen([ARMBRIDGE, "demo", "--rrd", rrd], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)
    try:
        yield proc, rrd
    finally:
        if proc.returncode is None:   # the test did not read it
            proc.kill()
            proc.communicate()


def test_square_plan_traces_the_square():
    robot = get_robot("arm3r")
    plan = square_plan(robot)
    tip = robot.fk(plan.q)
    assert robot.within_limits(plan.q).all()
    np.testing.assert_allclose(tip[:, 2], np.pi / 12, atol=1e-9)  # pen angle held
    xs, ys = tip[:, 0], tip[:, 1]
    assert xs.min() == pytest.approx(0.10) and xs.max() == pytest.approx(0.20)
    assert ys.min() == pytest.approx(0.15) and ys.max() == pytest.approx(0.25)
    np.testing.assert_allclose(tip[0, :2], tip[-1, :2], atol=1e-12)  # closed


def test_write_plan_only(tmp_path):
    out = tmp_path / "square.json"
    subprocess.run([ARMBRIDGE, "demo", "--write-plan", out], check=True, capture_output=True, timeout=60)
    plan = load_plan(out)
    assert plan.k == square_plan(get_robot("arm3r")).k and plan.provenance["shape"] == "square"


@pytest.mark.hil
def test_demo_refuses_a_latched_board_unless_clear(tmp_path):
    """The demo opens its session like `armbridge run`: a board latched from before
    is refused (nothing moves) unless the user passes --clear."""
    import serial

    from armbridge.emulator.board import EmulatedBoard
    from armbridge.link import protocol as P

    emu = EmulatedBoard("esp32").start()  # real time: a host on a pty runs on the wall clock
    try:
        with serial.Serial(emu.port, timeout=0.1) as s:  # the e-stop byte, as a panicking user would send it
            s.write(P.ESTOP_BYTE)
        end = time.monotonic() + 60  # the emulator thread reads the pty at once: a hang guard
        while emu.state != "ESTOP" and time.monotonic() < end:
            time.sleep(0.02)
        assert emu.state == "ESTOP"
        q0 = emu.positions()
        env = dict(os.environ, COLUMNS="120")
        cmd = [ARMBRIDGE, "demo", "--port", emu.port, "--rrd", tmp_path / "a.rrd"]
        refused = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
        assert refused.returncode == 1, refused.stdout + refused.stderr
        assert "latched in ESTOP" in refused.stdout + refused.stderr and "--clear" in refused.stdout + refused.stderr
        np.testing.assert_array_equal(emu.positions(), q0)  # nothing moved
        assert emu.state == "ESTOP"
        cleared = subprocess.run([*cmd, "--clear"], capture_output=True, text=True, timeout=120, env=env)
        assert cleared.returncode == 0, cleared.stdout + cleared.stderr
        assert "83 / 83" in cleared.stdout
    finally:
        emu.stop()


# last: it waits for demo_run, which ran beside the tests above
@pytest.mark.hil
def test_demo_runs_to_the_end_and_records(demo_run):
    proc, rrd = demo_run
    stdout, stderr = proc.communicate(timeout=120)
    run = subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "completed" in run.stdout and "83 / 83" in run.stdout
    assert rrd.stat().st_size > 10_000
    verify = subprocess.run([ARMBRIDGE.with_name("rerun"), "rrd", "verify", rrd], capture_output=True, timeout=60)
    assert verify.returncode == 0, verify.stderr
