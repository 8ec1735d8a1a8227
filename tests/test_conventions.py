"""One set of command-line conventions (issue 25 §2): one-line usage errors, `--json FILE|-`,
`--port` with ARMBRIDGE_PORT and `auto` (link/ports.py, `armbridge ports`)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from cli_procs import ARMBRIDGE
from serial.tools.list_ports_common import ListPortInfo

from armbridge.errors import ArmbridgeError
from armbridge.link.ports import describe, resolve_auto, scan
from armbridge.plans.format import make_plan, save_plan
from armbridge.robots import get_robot


def cli(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([ARMBRIDGE, *args], capture_output=True, text=True, timeout=300,
                          stdin=subprocess.DEVNULL, env={**os.environ, **(env or {})})


def usb(device: str, vid: int | None, pid: int | None, description: str = "") -> ListPortInfo:
    """A port as pyserial's list_ports describes one (its own type)."""
    p = ListPortInfo(device)
    p.vid, p.pid, p.description = vid, pid, description
    return p


ESP = usb("/dev/ttyUSB0", 0x10C4, 0xEA60, "CP2102 USB to UART Bridge Controller")
MEGA = usb("/dev/ttyACM0", 0x2341, 0x0042, "Arduino Mega 2560")
MOUSE = usb("/dev/ttyACM1", 0x046D, 0xC52B, "Unifying receiver")
UART = usb("/dev/ttyS0", None, None, "n/a")


# ---------------------------------------------------------------- usage errors


@pytest.mark.parametrize("args, words", [
    (["run", "x.json", "--bogus"], "No such option: --bogus (see 'armbridge run --help')"),
    (["board", "info"], "Missing option '--port'"),
    (["plan", "masr", "--iterations", "many"], "Invalid value for '--iterations'"),
    (["bench", "nonesuch"], "No such command"),
])
def test_a_usage_error_is_one_line_with_where_the_help_is(args, words):
    env = {k: v for k, v in os.environ.items() if k != "ARMBRIDGE_PORT"}
    r = subprocess.run([ARMBRIDGE, *args], capture_output=True, text=True, timeout=120, env=env)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert lines[0].startswith("error: ") and words in lines[0] and "--help')" in lines[0], lines
    assert "Usage:" not in r.stdout + r.stderr and "Traceback" not in r.stdout + r.stderr


# ---------------------------------------------------------------- ports


def test_the_known_bridges_are_the_boards_and_nothing_else_is():
    found = scan([UART, MOUSE, MEGA, ESP])
    assert [p.device for p in found] == ["/dev/ttyACM0", "/dev/ttyUSB0"]
    esp = describe(ESP)
    assert esp.usb_id == "10C4:EA60" and esp.bridge == "Silicon Labs CP210x" and "esp32" in esp.boards
    assert describe(MEGA).boards == "arduino_pump"
    assert describe(UART).usb_id is None and describe(MOUSE).bridge is None
    assert len(scan([UART, MOUSE, ESP], everything=True)) == 3


def test_port_auto_takes_the_one_board_or_says_why_not():
    assert resolve_auto([UART, ESP, MOUSE]) == "/dev/ttyUSB0"
    with pytest.raises(ArmbridgeError, match=r"2 boards found \(/dev/ttyACM0 \(Arduino Mega 2560 R3.*/dev/ttyUSB0"):
        resolve_auto([ESP, MEGA])
    with pytest.raises(ArmbridgeError, match="no board found .*armbridge ports --all"):
        resolve_auto([UART, MOUSE])


def test_armbridge_ports_and_port_auto_on_this_machine():
    r = cli("ports", "--all", "--json", "-")
    assert r.returncode == 0, r.stderr
    listed = json.loads(r.stdout)                                 # stdout: the JSON alone
    assert all({"device", "usb_id", "bridge", "boards"} <= set(p) for p in listed)
    if scan():
        pytest.skip("a board with a known bridge is plugged into this machine: auto would take it")
    r = cli("board", "state", "--port", "auto")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--port auto: no board found" in r.stderr, r.stderr
    assert "no serial port with a known board bridge" in cli("ports").stdout


# ---------------------------------------------------------------- --json and ARMBRIDGE_PORT


def test_run_takes_its_port_from_armbridge_port_and_json_dash_is_stdout_alone(tmp_path):
    robot = get_robot("arm3r")
    q0 = (robot.q_min + robot.q_max) / 2
    plan = make_plan(robot, [q0, q0 + 0.05, q0 + 0.1], [0.1, 0.2, 0.2])
    path = tmp_path / "tiny.json"
    save_plan(plan, path)
    r = cli("run", str(path), "--json", "-", "--rrd", str(tmp_path / "r.rrd"), "--no-progress",
            env={"ARMBRIDGE_PORT": "emu:esp32?speed=0"})
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["completed"] and s["waypoints_done"] == 3 and s["port"] == "emu:esp32?speed=0"
    assert "run of" in r.stderr                                   # the table went to stderr


# ---------------------------------------------------------------- numba's first compile is said


def test_the_first_planning_says_it_compiles_and_the_next_does_not(tmp_path):
    """A fresh numba cache (a fresh install): `compile_note` speaks; once a kernel is cached, it does not."""
    code = ("import sys; from armbridge.planning.base import compile_note; print(compile_note(sys.argv[1]));"
            "from armbridge.robots.masr_kernels import action_cost; import numpy as np;"
            "action_cost(np.zeros(6), np.ones(6), np.array([0.0, .2, .4, .6, .7]), 0.1, 0.28);"
            "print(compile_note('masr'))")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    r = subprocess.run([sys.executable, "-c", code, "masr"], capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stderr
    first, after = r.stdout.splitlines()
    assert first.startswith("compiling the planner's kernels") and after == "None"


def test_plan_soft_json_dash_is_stdout_alone(tmp_path):
    r = cli("plan", "soft", "--env", "two-arm", "--out", str(tmp_path / "s.json"), "--json", "-")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert "margin_mm" in s and "plan:" in r.stderr        # the table and the plan line went to stderr
