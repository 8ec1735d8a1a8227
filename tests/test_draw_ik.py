"""`armbridge draw --ik closed|paper`: the drawing planned by the 3R paper's ANN + FABRIK + CBF
(Murai, Vairagi, Semwal), its wrist angle on the paper's samples, run on the emulated arm."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from require import missing
from typer.testing import CliRunner

try:
    import onnxruntime  # noqa: F401
    import qpsolvers  # noqa: F401
except ImportError as exc:
    missing(f"{exc.name} is not installed (`make setup` installs it)")

from armbridge.bench import arm3r as bench  # noqa: E402
from armbridge.cli import build_app  # noqa: E402
from armbridge.draw.build import build  # noqa: E402
from armbridge.draw.samples import SAMPLES, sample_lines  # noqa: E402
from armbridge.errors import ArmbridgeError  # noqa: E402
from armbridge.ik import arm3r_pipeline as pipe  # noqa: E402
from armbridge.ik.analytic3r import ik as closed_form  # noqa: E402
from armbridge.ik.arm3r_ann import Arm3rANN  # noqa: E402
from armbridge.plans.format import load_plan  # noqa: E402
from armbridge.robots import get_robot  # noqa: E402
from armbridge.robots.planar import PlanarChain  # noqa: E402

ARM = get_robot("arm3r")
ARMBRIDGE = str(Path(sys.executable).with_name("armbridge"))
PAPER_THETA_RMSE_DEG = 1.25  # Table 8, "Error in Theta"


@pytest.fixture(scope="module")
def ann():
    return Arm3rANN.load()


@pytest.mark.parametrize("name", ["csv-circle", "image-square", "text-robotics"])
def test_wrist_angle_on_the_papers_samples(ann, name):
    """The paper's samples placed as `bench arm3r` places them: ANN + FABRIK + CBF (`plan_joints`,
    what `draw --ik paper` runs) keeps the wrist angle theta = q1 + q2 + q3 within the paper's
    1.25 deg RMSE of the pen angle and x, y within its Tables 6-7; FABRIK on position alone
    (the old pipeline) reaches the points too but spends the orientation (3.4 deg RMS measured)."""
    s = SAMPLES[name]
    fit = build(sample_lines(name), ARM, name=name, source=s.source)
    d = build(sample_lines(name), ARM, name=name, source=s.source, size=bench.PLACE_FRACTION * fit.placement.size)
    poses = np.c_[d.xy, np.full(len(d.xy), d.phi)]
    q_ref, ok = closed_form(ARM, poses)
    assert ok.all()
    q, report = pipe.plan_joints(ARM, d.xy, d.phi, ann)
    st = bench.stats(bench.errors(ARM, q, poses, q_ref))
    assert st["theta"]["rmse"] <= PAPER_THETA_RMSE_DEG, st["theta"]
    paper = bench.PAPER_PER_SAMPLE[name]
    assert st["x"]["rmse"] <= paper["x"]["rmse"] and st["y"]["rmse"] <= paper["y"]["rmse"]
    assert st["tip_mm"]["max"] <= 1e-3  # FABRIK's tolerance, 1 um
    assert report.oriented == report.waypoints == len(d.xy) and report.cbf_h_min >= 0
    free = pipe.solve(ARM, ann.predict, d.xy, d.phi, orient=False)
    st_free = bench.stats(bench.errors(ARM, free.q, poses, q_ref))
    assert st_free["tip_mm"]["max"] <= 1e-3 and st_free["theta"]["rmse"] > PAPER_THETA_RMSE_DEG


def test_draw_ik_paper_runs_on_the_emulated_arm(tmp_path):
    """`draw --sample text-robotics --ik paper --port emu:esp32?speed=0` (lockstep): a valid plan
    made by the paper's pipeline, in the safe set, the pen angle held, drawn whole."""
    out, js = tmp_path / "paper.json", tmp_path / "sum.json"
    r = CliRunner().invoke(build_app(), ["draw", "--sample", "text-robotics", "--ik", "paper", "--speed", "0.1",
                                         "--out", str(out), "--port", "emu:esp32?speed=0", "--json", str(js),
                                         "--rrd", str(tmp_path / "paper.rrd"), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "joints: the paper's ANN + FABRIK + CBF" in r.output
    plan = load_plan(out)
    info = plan.provenance["drawing"]
    ik = info["ik"]
    assert ik["method"] == "paper" and ik["model"] == "float.onnx" and len(ik["model_sha256"]) == 64
    assert ik["oriented"] == ik["waypoints"] == plan.k
    assert ik["tip_max_mm"] <= 1e-3 and ik["theta_max_deg"] < 1e-9 and ik["cbf"]["h_min"] >= 0
    # the same safety as the closed form: every waypoint's pen inside the safe disc less the margin
    c, radius = np.asarray(info["safe_region"]["center"]), info["safe_region"]["radius"]
    assert np.linalg.norm(plan.ee_path() - c, axis=1).max() <= radius - info["margin"] + 1e-9
    assert np.abs(plan.q.sum(axis=1) - info["phi"]).max() < 1e-9  # the discrete filter keeps the pen angle
    assert ARM.within_limits(plan.q).all()
    # the closed form's plan of the same drawing: the same waypoints, pen flags and (to FABRIK's tolerance) joints
    closed = build(sample_lines("text-robotics"), ARM, name="c", source="s", speed=0.1).plan
    assert closed.provenance["drawing"]["ik"]["method"] == "closed"
    assert closed.k == plan.k and closed.pen.tolist() == plan.pen.tolist()
    assert np.abs(closed.q - plan.q).max() < 1e-4
    s = json.loads(js.read_text())
    assert s["completed"]
    d = s["drawing"]
    assert d["characters"] == 8 and d["trace_points"] > 100
    assert 0 < d["trace_mean_mm"] <= d["trace_max_mm"] < 10


def test_draw_ik_closed_is_the_default(tmp_path):
    out = tmp_path / "c.json"
    r = CliRunner().invoke(build_app(), ["draw", "IO", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "joints: the closed-form IK" in r.output
    assert load_plan(out).provenance["drawing"]["ik"]["method"] == "closed"


@pytest.mark.parametrize("args, msg", [
    (["--ik", "bogus"], "--ik 'bogus': expected closed or paper"),
    (["--ik", ""], "--ik '': expected closed or paper"),
    (["--ik", "paper", "--robot", "soft3"], "--ik paper: the ANN (arm3r-ik) is trained for robot 'arm3r', not 'soft3'"),
])
def test_bad_ik_is_one_clear_error_and_writes_nothing(tmp_path, args, msg):
    out = tmp_path / "o.json"
    r = CliRunner().invoke(build_app(), ["draw", "--shape", "square", *args, "--out", str(out)])
    assert isinstance(r.exception, ArmbridgeError), (r.output, r.exception)
    assert msg in str(r.exception) and "\n" not in str(r.exception)
    assert not out.exists()


def test_bad_ik_exits_2_with_one_line(tmp_path):
    r = subprocess.run([ARMBRIDGE, "draw", "--shape", "square", "--ik", "ANN", "--out", str(tmp_path / "o.json")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr.startswith("error: --ik 'ANN': expected closed or paper") and r.stderr.count("\n") == 1
    assert not (tmp_path / "o.json").exists()


def test_plan_joints_refuses_another_arm(ann):
    other = PlanarChain(name="arm3r-long", link_lengths=np.array([0.2, 0.12, 0.07]), q_min=ARM.q_min,
                        q_max=ARM.q_max, v_max=ARM.v_max, joint_names=ARM.joint_names)
    with pytest.raises(ArmbridgeError, match="trained for robot 'arm3r', not 'arm3r-long'"):
        pipe.plan_joints(other, np.array([[0.076, 0.19]]), 0.0, ann)
