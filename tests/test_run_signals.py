"""`armbridge run` as a real process against `armbridge emulate esp32` on a pty
(another real process), stopped as processes are stopped: SIGTERM, SIGHUP,
Ctrl-C; failures (a stalled joint's FAULT, a latched board, no answer, a port
that goes away); a second run on a busy port.

Every case checks what the issue asks of a stop: the e-stop byte reached the
board (the emulator prints its ESTOP event and `armbridge board state` says
ESTOP afterwards), `rerun rrd verify` passes, the JSON summary exists with
`error` and `final_state`, and the exit code is the documented one
(docs/formats.md §7).
"""
from __future__ import annotations

import fcntl
import json
import os
import select
import signal
import subprocess
import termios
from pathlib import Path

import pytest
from cli_procs import ARMBRIDGE, RERUN, Proc, default_signals, emulated_board

from armbridge.plans.format import make_plan, save_plan
from armbridge.robots import get_robot

pytestmark = pytest.mark.hil

@pytest.fixture
def board(tmp_path):
    yield from emulated_board(tmp_path)


def plan_file(tmp_path: Path, k: int, duration: float, name: str = "plan", shoulder: float = 1.5,
              swing: float = 0.3) -> Path:
    robot = get_robot("arm3r")
    q = [[shoulder + swing * (i % 2), -1.5 + 0.1 * (i % 3), 0.0] for i in range(k)]
    path = tmp_path / f"{name}.json"
    save_plan(make_plan(robot, q, duration), path)
    return path


def run(tmp_path: Path, plan: Path, link: str, tag: str, *extra: str, **kw) -> tuple[Proc, Path, Path]:
    js, rrd = tmp_path / f"{tag}.json", tmp_path / f"{tag}.rrd"
    argv = ("run", str(plan), "--port", link, "--json", str(js), "--rrd", str(rrd), "--no-progress", *extra)
    return Proc(*argv, **kw), js, rrd


def verify(rrd: Path) -> None:
    r = subprocess.run([RERUN, "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, (r.stdout, r.stderr)


def board_state(link: str) -> dict:
    r = subprocess.run([ARMBRIDGE, "board", "state", "--port", link, "--json", "-"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_stop_signal_mid_run_estops_and_leaves_complete_files(tmp_path, board, sig):
    emu, link = board
    plan = plan_file(tmp_path, 40, 0.25)
    proc, js, rrd = run(tmp_path, plan, link, "stopped")
    emu.wait_for("EV", timeout=30)  # the plan is running ...
    emu.wait_for(" DONE 1 ")        # ... two waypoints in, 38 to go
    proc.p.send_signal(sig)
    rc, err = proc.finish()
    name = signal.Signals(sig).name
    assert rc == 128 + sig, err
    assert f"stopped by {name}, e-stop sent" in err
    emu.wait_for(" ESTOP*")  # the board got the e-stop byte
    s = json.loads(js.read_text())
    assert s["stopped_by_user"] and s["stopped_by"] == name and s["estop_sent"]
    assert s["error"] is None and s["final_state"] == "ESTOP" and not s["completed"]
    assert 2 <= s["waypoints_done"] < 40
    verify(rrd)
    st = board_state(link)
    assert st["state"] == "ESTOP" and st["latched"]


def test_closing_the_terminal_mid_run_estops_and_leaves_complete_files(tmp_path, board):
    """The run's controlling terminal is a pty; closing its master is what closing
    a terminal window does: the kernel hangs up (SIGHUP) and every later write to
    the terminal fails. The files are written all the same, and the exit code says why."""
    emu, link = board
    js, rrd = tmp_path / "hup.json", tmp_path / "hup.rrd"
    master, slave = os.openpty()

    def on_the_terminal() -> None:
        default_signals()
        os.setsid()
        fcntl.ioctl(0, termios.TIOCSCTTY, 0)

    p = subprocess.Popen([ARMBRIDGE, "run", str(plan_file(tmp_path, 40, 0.25)), "--port", link, "--json", str(js),
                          "--rrd", str(rrd)], stdin=slave, stdout=slave, stderr=slave, preexec_fn=on_the_terminal)
    os.close(slave)
    try:
        emu.wait_for(" DONE 1 ")
        os.read(master, 65536)  # the progress bar so far
    finally:
        os.close(master)  # the terminal goes away
    rc = p.wait(timeout=60)
    assert rc == 128 + signal.SIGHUP
    emu.wait_for(" ESTOP*")
    s = json.loads(js.read_text())
    assert s["stopped_by"] == "SIGHUP" and s["estop_sent"] and s["final_state"] == "ESTOP" and s["error"] is None
    verify(rrd)


def test_under_nohup_a_hangup_does_not_stop_the_run(tmp_path, board):
    """SIGHUP ignored at start (nohup) stays ignored: the run goes on and completes."""
    emu, link = board

    def nohup() -> None:
        default_signals()
        signal.signal(signal.SIGHUP, signal.SIG_IGN)

    proc, js, rrd = run(tmp_path, plan_file(tmp_path, 8, 0.25), link, "nohup", preexec=nohup)
    emu.wait_for(" DONE 1 ")
    proc.p.send_signal(signal.SIGHUP)
    rc, err = proc.finish()
    assert rc == 0, err
    s = json.loads(js.read_text())
    assert s["completed"] and not s["estop_sent"] and s["stopped_by"] is None
    verify(rrd)


def test_a_latched_board_refuses_the_next_run_until_clear(tmp_path, board):
    """After an e-stop the next run fails (exit 1, JSON with the error) and moves
    nothing; `--clear` clears the latch and the run completes (exit 0)."""
    emu, link = board
    proc, _, _ = run(tmp_path, plan_file(tmp_path, 40, 0.25), link, "first")
    emu.wait_for(" DONE 0 ")
    proc.p.send_signal(signal.SIGTERM)
    assert proc.finish()[0] == 143
    short = plan_file(tmp_path, 3, 0.2, "short")
    refused, js, rrd = run(tmp_path, short, link, "refused")
    rc, err = refused.finish()
    assert rc == 1, err
    s = json.loads(js.read_text())
    assert "latched in ESTOP" in s["error"] and "--clear" in s["error"] and s["waypoints_sent"] == 0
    assert err.strip().splitlines()[-1].startswith("error: the board is latched in ESTOP")
    verify(rrd)
    cleared, js, rrd = run(tmp_path, short, link, "cleared", "--clear")
    rc, err = cleared.finish()
    assert rc == 0, err
    s = json.loads(js.read_text())
    assert s["completed"] and s["error"] is None and s["final_state"] == "IDLE"
    verify(rrd)


def test_a_board_fault_names_the_joint_in_the_summary(tmp_path):
    link = str(tmp_path / "arm")
    emu = Proc("emulate", "esp32", "--link", link, "--stall", "1@0", "-v")
    try:
        emu.wait_for("esp32 emulator on /dev/pts/")
        # The shoulder is seized where it starts (pi/2); the plan holds it 0.5 rad or more away.
        plan = plan_file(tmp_path, 40, 0.25, shoulder=0.9, swing=0.15)
        proc, js, rrd = run(tmp_path, plan, link, "fault")
        rc, err = proc.finish()
        assert rc == 1, err
        s = json.loads(js.read_text())
        assert s["final_state"] == "FAULT" and not s["estop_sent"]  # the board stopped itself
        assert s["fault"].startswith("joint 1 (shoulder): following error ")
        assert "joint 1 (shoulder)" in s["error"]
        verify(rrd)
        emu.wait_for(" FAULT 1 ")
    finally:
        emu.stop()


def test_a_board_that_never_answers_fails_with_its_error_line_alone(tmp_path):
    """A pty with nobody behind it: the handshake times out (exit 1) with one error line;
    the JSON asked for says so, and there is neither a table of dashes nor an empty recording."""
    master, slave = os.openpty()
    try:
        proc, js, rrd = run(tmp_path, plan_file(tmp_path, 3, 0.2), os.ttyname(slave), "silent")
        rc, err = proc.finish()
    finally:
        os.close(master)
        os.close(slave)
    assert rc == 1, err
    s = json.loads(js.read_text())
    assert "no answer to HELLO" in s["error"] and s["final_state"] is None and s["waypoints_sent"] == 0
    assert s["rrd"] is None and not rrd.exists()
    assert [ln for ln in err.splitlines() if ln.strip()] == [f"error: {s['error']}"], err


def test_a_stop_while_connecting_still_sends_the_estop_byte(tmp_path):
    """SIGTERM while the host is still sending HELLO to a board that has not answered:
    the e-stop byte goes out all the same (docs/formats.md §2, §3, §7: every stop),
    and the summary says so."""
    master, slave = os.openpty()
    try:
        proc, js, rrd = run(tmp_path, plan_file(tmp_path, 3, 0.2), os.ttyname(slave), "connecting")
        seen = b""
        while seen.count(b"HELLO") < 2:  # the host is in its HELLO loop
            r, _, _ = select.select([master], [], [], 30.0)
            assert r, f"no HELLO from the host; stderr: {proc.p.poll()}"
            seen += os.read(master, 4096)
        proc.p.send_signal(signal.SIGTERM)
        rc, err = proc.finish()
        os.set_blocking(master, False)
        try:
            seen += os.read(master, 4096)
        except BlockingIOError:
            pass
    finally:
        os.close(master)
        os.close(slave)
    assert rc == 143, err
    assert b"\x98" in seen
    s = json.loads(js.read_text())
    assert s["stopped_by_user"] and s["stopped_by"] == "SIGTERM" and s["estop_sent"]
    assert not s["estop_confirmed"] and s["waypoints_sent"] == 0
    verify(rrd)


def test_a_port_that_goes_away_mid_run_says_unplugged(tmp_path, board):
    emu, link = board
    port = os.path.realpath(link)
    proc, js, rrd = run(tmp_path, plan_file(tmp_path, 40, 0.25), port, "gone")
    emu.wait_for(" DONE 1 ")
    emu.p.kill()  # the board's end of the pty vanishes, as a pulled USB adapter's does
    emu.p.wait()
    rc, err = proc.finish()
    assert rc == 1, err
    s = json.loads(js.read_text())
    assert s["error"].startswith(f"the port {port} went away: unplugged?"), s["error"]
    assert err.strip().splitlines()[-1].startswith(f"error: the port {port} went away: unplugged?")
    verify(rrd)


def test_a_second_run_on_a_busy_port_is_told_who_holds_it(tmp_path, board):
    emu, link = board
    plan = plan_file(tmp_path, 80, 0.25)  # 20 s: far longer than this test lets it run
    first, js1, rrd1 = run(tmp_path, plan, link, "first")
    emu.wait_for(" DONE 1 ")
    second, js2, rrd2 = run(tmp_path, plan, link, "second")
    rc2, err2 = second.finish()
    assert first.p.poll() is None  # the first held the port all along
    assert rc2 == 1, err2
    last = err2.strip().splitlines()[-1]
    assert last.startswith(f"error: port {link} is busy: 'armbridge run {plan} --port {link}"), last
    assert f"(pid {first.p.pid}) holds it" in last
    s2 = json.loads(js2.read_text())
    assert "busy" in s2["error"] and s2["waypoints_sent"] == 0 and s2["fw"] is None
    # The first run is unharmed: it goes on streaming on a clean link.
    done = max(int(line.split(" DONE ")[1].split()[0]) for line in emu.lines if " DONE " in line)
    emu.wait_for(f" DONE {done + 3} ")
    first.p.send_signal(signal.SIGTERM)
    rc1, err1 = first.finish()
    assert rc1 == 143, err1
    s = json.loads(js1.read_text())
    assert s["error"] is None and s["waypoints_done"] >= done + 4
    assert s["resyncs"] == 0 and s["line_errors"] == 0 and s["seq_errors"] == 0
    verify(rrd1)


def test_json_dash_writes_the_summary_to_stdout_alone(tmp_path, board):
    emu, link = board
    r = subprocess.run([ARMBRIDGE, "run", str(plan_file(tmp_path, 3, 0.2)), "--port", link, "--json", "-",
                        "--rrd", str(tmp_path / "x.rrd"), "--no-progress"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)  # nothing but the JSON on stdout ...
    assert s["completed"] and s["waypoints_done"] == 3
    assert "run of" in r.stderr  # ... the table went to stderr
    assert not (Path.cwd() / "-").exists()


@pytest.mark.parametrize("args, code, words", [
    (["run", "missing.json", "--port", "emu:esp32"], 2, "no such plan file"),
    (["run", "PLAN", "--port", "/dev/does-not-exist-armbridge"], 2, "no such device"),
    (["run", "PLAN", "--port", "emu:esp99"], 2, "esp99"),
    (["run", "PLAN", "--port", "/etc/passwd"], 2, "not a serial device"),
    (["run", "PLAN", "--port", "emu:esp32", "--rate", "500"], 2, "outside [1, 100]"),
    (["run", "PLAN", "--bogus"], 2, "No such option"),
])
def test_bad_input_exits_2_and_writes_nothing(tmp_path, args, code, words):
    plan = str(plan_file(tmp_path, 3, 0.2))
    js, rrd = tmp_path / "never.json", tmp_path / "never.rrd"
    argv = [plan if a == "PLAN" else a for a in args] + ["--json", str(js), "--rrd", str(rrd)]
    r = subprocess.run([ARMBRIDGE, *argv], capture_output=True, text=True, timeout=120)
    assert r.returncode == code, r.stderr
    assert words in r.stderr
    assert not js.exists() and not rrd.exists()
