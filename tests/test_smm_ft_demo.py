"""`armbridge demo --robot arm3r --fault-tolerant` (demos/arm3r_ft.py): a joint of the
emulated plant stalls on the way to the target; the host detects it, recovers with
the other joints, and the tip still reaches the target. The recording is read back."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import torch
from rerun.chunk import RrdReader

from armbridge.emulator.board import EmulatedBoard
from armbridge.errors import ArmbridgeError
from armbridge.link import protocol as P
from armbridge.robots.catalog import ARM3R
from armbridge.smm import faulttolerant as ft
from armbridge.demos import arm3r_ft as ft_demo

torch.set_num_threads(1)
ARMBRIDGE = Path(sys.executable).with_name("armbridge")
SEED, LATENCY = 0, 0.5  # a fixed latency keeps the plan the same from run to run
PORT = "emu:esp32?speed=0&seed=1"  # lockstep, coupled to the host: no outcome depends on the machine's speed


@pytest.fixture(scope="module")
def scenario():
    return ft_demo.choose_scenario(SEED, ft_demo.learned_method(), latency=LATENCY)  # run_ft_demo's default


def test_the_scenario_stalls_a_joint_inside_its_box(scenario):
    sc = scenario
    plan = sc.plan
    assert ARM3R.within_limits(plan.q).all()
    assert sc.latency == LATENCY and 0 <= sc.joint < 3
    ap = sc.approach
    t_in = sc.stall_after - ft_demo.START_S - sc.latency - ap.entry.duration
    assert 0 < t_in < ap.inside.duration
    q_stall = ap.inside.at(t_in)
    assert ap.box.contains(q_stall)
    # The stalled joint still has far to go, so the stall shows.
    assert abs(ap.inside.goal[sc.joint] - q_stall[sc.joint]) >= ft_demo.MIN_TRAVEL - 1e-9
    # The plan ends on the SMM: the target.
    assert np.linalg.norm(ARM3R.fk(plan.q[-1])[:2] - sc.x) < 1e-4
    # A lock there is recoverable within the limits.
    move = ft.recovery_move(q_stall, sc.joint, ft.locked_configurations(sc.smm, 0, sc.joint, q_stall[sc.joint]),
                            ft_demo.VMAX, ft_demo.limits())
    assert move is not None and ARM3R.within_limits(move.goal)


EPOCH = 1  # the epoch the test's HELLO opens: every later line is framed with it (protocol v2)


def _host(emu):
    """A minimal lockstep host: send(verb, args) and the board's decoded lines."""
    state = {"seq": 0, "buf": b"", "lines": []}

    def send(verb, *args):
        state["seq"] += 1
        emu.inject(P.encode(state["seq"], verb, *args, epoch=EPOCH))

    def lines():
        *done, state["buf"] = (state["buf"] + emu.read_output()).split(b"\n")
        state["lines"] += [P.decode(raw) for raw in done if raw]
        return state["lines"]

    return send, lines


def test_a_stalled_joint_faults_then_the_others_run_on_after_clr():
    """No firmware change is needed to run on with a locked joint: CLR sets the set
    point to the measured position and waypoints that hold the stalled joint run."""
    emu = EmulatedBoard("esp32", speed=0)
    send, lines = _host(emu)
    send("HELLO", P.PROTOCOL_VERSION, 5, EPOCH)
    q0 = emu.positions()
    emu.schedule_stall(1, 0.3)
    send("W", 0, 1000, *P.to_milli(q0 + [1.0, 0.0, 0.0]))
    for _ in range(10):  # PINGs keep the watchdog quiet
        emu.run_for(0.2)
        send("PING")
    assert emu.state == "FAULT"
    assert any(l.verb == "EV" and l.args[1:3] == ("FAULT", "1") for l in lines())
    stuck = emu.positions()[0]
    send("CLR")
    emu.run_for(0.1)
    target = emu.positions() + [0.0, -0.5, 0.6]
    send("W", 1, 800, *P.to_milli(target))
    for _ in range(8):
        emu.run_for(0.2)
        send("PING")
    assert emu.state == "IDLE" and any(l.verb == "EV" and l.args[1:3] == ("DONE", "1") for l in lines())
    q = emu.positions()
    assert q[0] == pytest.approx(stuck, abs=1e-9)
    np.testing.assert_allclose(q[1:], target[1:], atol=0.01)
    with pytest.raises(ArmbridgeError, match="joints 1..3"):
        emu.schedule_stall(4, 1.0)


def read(path: Path) -> dict[str, dict]:
    """entity path -> {"rows": n, "columns": {name: [values]}} of a .rrd."""
    out: dict[str, dict] = {}
    for chunk in RrdReader(path).stream():
        e = out.setdefault(chunk.entity_path, {"rows": 0, "columns": {}})
        e["rows"] += chunk.num_rows
        rb = chunk.to_record_batch()
        for name in rb.schema.names:
            col = rb.column(name)
            if pa.types.is_duration(col.type) or pa.types.is_timestamp(col.type):
                col = col.cast(pa.int64())
            e["columns"].setdefault(name, []).extend(col.to_pylist())
    return out


def _texts(entity: dict) -> list[str]:
    return [str(v) for name, vals in entity["columns"].items() if name.endswith(":text") for v in vals]


@pytest.mark.hil
def test_the_arm_reaches_the_target_despite_the_stall(tmp_path, scenario):
    rrd = tmp_path / "ft.rrd"
    res = ft_demo.run_ft_demo(PORT, rrd, SEED, latency=LATENCY)
    sc = scenario
    assert res.stalled_joint == sc.joint + 1
    assert res.detected_joint == res.stalled_joint and res.detected_by in ("host", "FAULT")
    assert res.reached and res.tip_error_true_m <= ft_demo.TOL_M and res.tip_error_m <= ft_demo.TOL_M
    assert np.isfinite(res.recovery_s) and res.recovery_s > 0
    rec = read(rrd)
    for entity in ("/task/target", "/task/smm", "/task/recovery", "/recovery/path", "/arm/links", "/events"):
        assert entity in rec, entity
    names = ARM3R.joint_names
    assert f"/joint_space/{names[1]}-{names[2]}/box" in rec and f"/joints/{names[0]}/box_lo" in rec
    events = " | ".join(_texts(rec["/events"]))
    assert "target appears" in events and "SMMs ready" in events
    assert f"joint {res.stalled_joint} ({names[sc.joint]}) stalled" in events
    assert "ESTOP" in events or "FAULT" in events
    assert "target reached" in events


@pytest.mark.hil
def test_demo_command_fault_tolerant(tmp_path):
    rrd = tmp_path / "cli.rrd"
    env = dict(os.environ, COLUMNS="120")
    run = subprocess.run([ARMBRIDGE, "demo", "--robot", "arm3r", "--fault-tolerant", "--port", PORT, "--rrd", rrd],
                         capture_output=True, text=True, timeout=300, env=env)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "target reached despite the locked joint" in run.stdout
    verify = subprocess.run([ARMBRIDGE.with_name("rerun"), "rrd", "verify", rrd], capture_output=True, timeout=60)
    assert verify.returncode == 0, verify.stderr


def test_demo_command_refuses_other_robots_and_ports():
    run = subprocess.run([ARMBRIDGE, "demo", "--robot", "planar3r", "--fault-tolerant"], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode != 0 and "--robot 'planar3r': no demo for that robot; demos: arm3r" in run.stdout + run.stderr
    with pytest.raises(ArmbridgeError, match="needs an emu: port"):
        ft_demo.run_ft_demo("/dev/ttyUSB0")
    with pytest.raises(ArmbridgeError, match="choose learned or nullspace"):
        ft_demo.smm_method("grid")
