"""`armbridge report RUN.rrd`: a run's picture and numbers from its recording alone (report/), on a
real short run of each emulated board (emu:esp32, emu:masr_ma, emu:arduino_pump, all at speed 0),
and the run's summary that `run_plan` logs into the recording (run/summary).

Checked: the PNG and the self-contained HTML page exist and hold the summary's numbers; `--json -`
carries the recording's summary exactly as `armbridge run --json` writes it; the numbers the
report draws come from the recording (joints, the plan's last waypoint against the measured tip);
a recording without the summary (an older one) says what it lacks; every bad file is one line and
exit 2. No wall-clock assertion anywhere.
"""
from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from armbridge.executor.run import run_plan
from armbridge.plans.format import make_plan
from armbridge.robots import ARM3R, SOFT3
from armbridge.telemetry.recording import Recording

ARMBRIDGE = str(Path(sys.executable).parent / "armbridge")
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def cli(*argv: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([ARMBRIDGE, *argv], capture_output=True, text=True, timeout=timeout)


def arm3r_run(tmp: Path):
    q = [[1.4, -1.5, 0.0], [1.7, -1.3, 0.2], [1.5, -1.6, 0.1]]
    return run_plan(make_plan(ARM3R, q, 0.5), "emu:esp32?speed=0", tmp / "arm3r.rrd", progress=False)


def masr5_run(tmp: Path):
    """Onto joint 2 and along it (test_masr_exec's line plan) beside one obstacle, from an unhomed MA."""
    from armbridge.planning.masr.environment import load_environment
    from armbridge.planning.masr.plan_file import save_masr_plan

    env0 = load_environment("E2")
    q0, q1 = np.array([0, 0, 0, 0, 0, 0.1]), np.array([0, 0.3, 0, 0, 0, 0.35])
    box = np.array([[-0.5, -0.5], [-0.4, -0.5], [-0.4, -0.4], [-0.5, -0.4]])  # behind the base, out of the way
    env = replace(env0, name="line", obstacles=[box], start=q0, goal_pose=np.asarray(env0.arm.fk(q1)), goal_q=q1)
    path = save_masr_plan(env, np.array([q0, q1]), tmp / "line.json", {"tool": "tests"})
    return run_plan(path, "emu:masr_ma?speed=0&seed=3", tmp / "masr5.rrd", progress=False, home=True)


def soft3_run(tmp: Path):
    from require import missing

    if shutil.which("avr-gcc") is None or not Path("/usr/include/simavr/sim_avr.h").is_file():
        missing("the AVR toolchain or libsimavr-dev is missing (scripts/setup.sh as root installs them)")
    plan = make_plan(SOFT3, [[0.2, 0.3, 0.3], [0.2, 0.3, 0.3]], [1.0, 1.0], {"tool": "armbridge tests"})
    return run_plan(plan, "emu:arduino_pump?speed=0", tmp / "soft3.rrd", progress=False, timeout=120)


RUNS = {"arm3r": arm3r_run, "masr5": masr5_run, "soft3": soft3_run}


@pytest.fixture(scope="module", params=list(RUNS))
def run(request, tmp_path_factory):
    """A real short run of one robot on its emulated board: its summary and recording."""
    tmp = tmp_path_factory.mktemp(request.param)
    summary = RUNS[request.param](tmp)
    assert summary.completed, summary
    return {"robot": request.param, "summary": summary, "rrd": Path(summary.rrd), "tmp": tmp}


@pytest.mark.hil
def test_a_report_of_a_real_run_holds_its_summary_in_png_html_and_json(run):
    s, rrd, tmp = run["summary"], run["rrd"], run["tmp"]
    png, html, js = tmp / "r.png", tmp / "r.html", tmp / "r.json"
    r = cli("report", str(rrd), "--png", str(png), "--html", str(html), "--json", str(js))
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    image = png.read_bytes()
    assert image.startswith(PNG_MAGIC) and len(image) > 50_000
    from PIL import Image

    with Image.open(png) as im:
        w, h = im.size
        pixels = np.asarray(im.convert("RGB"))
    assert w >= 1500 and h >= 1000
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 200  # drawn, not blank
    doc = json.loads(js.read_text())
    expected = json.loads(json.dumps(s.to_dict()))
    assert doc["summary"] == expected                  # the summary, from the recording alone
    assert doc["status"] == "completed" and doc["robot"] == s.robot and doc["missing"] == []
    assert doc["link"]["lines_sent"] == s.lines_sent and doc["link"]["line_errors"] == s.line_errors
    assert list(doc["joints"]) == list(s.joint_units)
    assert doc["telemetry"]["samples"] == s.telemetry_samples
    for name, j in doc["joints"].items():
        assert j["unit"] == s.joint_units[name] and j["samples"] == s.telemetry_samples
        assert math.isfinite(j["final_q"]) and math.isfinite(j["setpoint_error_max"])
    # the measured tip ended near the plan's last waypoint (each arm tracks within mm here)
    assert doc["tip"]["end_off_plan_mm"] is not None and doc["tip"]["end_off_plan_mm"] < 20.0
    if run["robot"] == "masr5":
        assert doc["obstacles"] == 1                   # the plan's obstacle is in the recording and the report
    page = html.read_text()
    assert page.startswith("<!DOCTYPE html>") and "data:image/png;base64," in page
    assert "<script" not in page and "src=\"http" not in page      # self-contained
    assert f"{s.waypoints_done} / {s.waypoints_total}" in page
    assert f"{s.waypoints_sent} / {s.waypoints_acked}" in page
    assert f"{s.lines_sent} / {s.waypoints_retransmitted}" in page
    assert f"{s.telemetry_samples} / " in page
    assert "DONE" in page and "completed" in page


@pytest.mark.hil
def test_json_to_stdout_is_the_recordings_summary_alone(run):
    r = cli("report", str(run["rrd"]), "--json", "-")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)                         # stdout carries the JSON alone
    assert doc["summary"] == json.loads(json.dumps(run["summary"].to_dict()))
    assert "report of" in r.stderr                     # the table went to stderr


def test_a_recording_without_its_summary_says_what_it_lacks(tmp_path):
    """A recording made before the summary went into it: the report is still made from the
    telemetry and the plan, and says, in words and in the JSON, that the summary is not there."""
    plan = make_plan(ARM3R, [[1.4, -1.5, 0.0], [1.7, -1.3, 0.2]], 0.5)
    rrd = tmp_path / "old.rrd"
    with Recording(rrd, ARM3R, plan, flush_every=5) as rec:
        for i in range(20):
            q = plan.q[0] + (plan.q[1] - plan.q[0]) * i / 19
            rec.telemetry(0.05 * i, q, q, [0, 0, 0], done=0)
        rec.event(0.0, "START 0")
        rec.event(0.9, "FAULT elbow stall", "error")
    r = cli("report", str(rrd), "--json", "-", "--png", str(tmp_path / "old.png"))
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["summary"] is None and doc["status"] is None and doc["link"] is None
    assert any("summary" in m for m in doc["missing"])
    assert "not in this recording: the run's summary" in " ".join(r.stderr.split())
    assert doc["telemetry"]["samples"] == 20 and list(doc["joints"]) == list(ARM3R.joint_names)
    assert doc["faults"] == [{"t": pytest.approx(0.9), "log": "events", "text": "FAULT elbow stall"}]
    assert doc["tip"]["end_off_plan_mm"] == pytest.approx(0.0, abs=1e-3)
    assert (tmp_path / "old.png").read_bytes().startswith(PNG_MAGIC)


def test_the_summary_is_in_the_recording_as_json(tmp_path):
    from armbridge.report.data import load

    plan = make_plan(ARM3R, [[1.4, -1.5, 0.0], [1.7, -1.3, 0.2]], 0.5)
    rrd = tmp_path / "s.rrd"
    with Recording(rrd, ARM3R, plan) as rec:
        rec.telemetry(0.0, plan.q[0], plan.q[0], [0, 0, 0])
        rec.summary({"plan": "p", "robot": "arm3r", "waypoints_done": 2, "completed": True})
        rec.close()
        rec.summary({"plan": "late"})                  # after close: nothing (the file is done)
    assert load(rrd).summary == {"plan": "p", "robot": "arm3r", "waypoints_done": 2, "completed": True}


def _bad_files(tmp: Path) -> dict[str, tuple[Path, str]]:
    text = tmp / "notes.rrd"
    text.write_text("not a recording\n")
    empty = tmp / "empty.rrd"
    empty.write_bytes(b"")
    good = tmp / "good.rrd"
    with Recording(good, ARM3R, make_plan(ARM3R, [[1.4, -1.5, 0.0], [1.7, -1.3, 0.2]], 0.5)) as rec:
        for i in range(200):
            rec.telemetry(0.01 * i, [1.4, -1.5, 0.0], [1.4, -1.5, 0.0], [0, 0, 0])
    cut = tmp / "cut.rrd"
    cut.write_bytes(good.read_bytes()[:100])  # inside the first message: nothing can be read
    header = tmp / "header.rrd"
    header.write_bytes(b"RRF2" + b"\0" * 8)
    return {"text": (text, "is not a Rerun recording"), "empty": (empty, "is empty"),
            "cut": (cut, "cannot read the recording"), "header": (header, "cannot read the recording"),
            "missing": (tmp / "nope.rrd", "no such recording"), "folder": (tmp, "is not a file")}


def test_bad_files_are_one_line_and_exit_2(tmp_path):
    for name, (path, says) in _bad_files(tmp_path).items():
        r = cli("report", str(path), "--png", str(tmp_path / f"{name}.png"))
        assert r.returncode == 2, (name, r.stdout, r.stderr)
        lines = [x for x in r.stderr.splitlines() if x.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: ") and says in lines[0], (name, r.stderr)
        assert not (tmp_path / f"{name}.png").exists()


def test_a_recording_cut_short_is_reported_as_far_as_it_reads_or_refused_in_one_line(tmp_path):
    """A run killed before it closed its file leaves a recording without its footer, cut anywhere:
    what can be read is reported, and the report says the file is cut; else one line, exit 2."""
    good = tmp_path / "good.rrd"
    plan = make_plan(ARM3R, [[1.4, -1.5, 0.0], [1.7, -1.3, 0.2]], 0.5)
    with Recording(good, ARM3R, plan, flush_every=10) as rec:
        for i in range(300):
            rec.telemetry(0.01 * i, plan.q[0], plan.q[0], [0, 0, 0])
    data = good.read_bytes()
    for frac in (0.3, 0.5, 0.8):
        cut = tmp_path / f"cut{frac}.rrd"
        cut.write_bytes(data[: int(len(data) * frac)])
        r = cli("report", str(cut), "--json", "-")
        assert "Traceback" not in r.stderr
        if r.returncode == 0:
            doc = json.loads(r.stdout)
            assert any("cut" in m for m in doc["missing"]), doc["missing"]
        else:
            lines = [x for x in r.stderr.splitlines() if x.strip()]
            assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: "), r.stderr


def test_an_unwritable_output_is_one_line(tmp_path):
    from armbridge.errors import ArmbridgeError
    from armbridge.report.command import make_report

    rrd = tmp_path / "ok.rrd"
    with Recording(rrd, ARM3R, make_plan(ARM3R, [[1.4, -1.5, 0.0], [1.7, -1.3, 0.2]], 0.5)) as rec:
        rec.telemetry(0.0, [1.4, -1.5, 0.0], [1.4, -1.5, 0.0], [0, 0, 0])
    (tmp_path / "file").write_text("x")
    with pytest.raises(ArmbridgeError, match="cannot write the picture"):
        make_report(rrd, png=tmp_path / "file" / "r.png")


def test_the_trace_distance_is_to_the_polyline():
    from armbridge.report.numbers import polyline_distance

    line = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    pts = np.array([[0.5, 0.2], [1.3, 0.5], [2.0, 2.0], [-1.0, 0.0]])
    assert polyline_distance(pts, line) == pytest.approx([0.2, 0.3, math.hypot(1, 1), 1.0])


def test_a_failed_run_shows_its_fault(tmp_path):
    """A stalled joint latches FAULT: the report of its recording has the failure, the fault in the
    summary and the ERROR-level lines on the board's clock."""
    from armbridge.executor.run import RunFailed
    from armbridge.report.command import make_report
    from plan_runs import wave_plan

    rrd = tmp_path / "f.rrd"
    with pytest.raises(RunFailed) as failed:
        run_plan(wave_plan(60), "emu:esp32?speed=0&stall=1@0", rrd, progress=False)
    doc = make_report(rrd, png=tmp_path / "f.png")
    s = failed.value.summary
    assert doc["summary"] == json.loads(json.dumps(s.to_dict()))
    assert doc["status"].startswith("failed: ") and "FAULT" in doc["status"]
    assert doc["summary"]["fault"].startswith("joint 1 (shoulder)")
    assert any(f["text"].startswith("FAULT") for f in doc["faults"]), doc["faults"]
    assert (tmp_path / "f.png").read_bytes().startswith(PNG_MAGIC)


def test_a_spatial_arm_is_drawn_in_its_x_y_projection(tmp_path):
    from armbridge.report.command import make_report
    from armbridge.robots import get_robot

    robot = get_robot("spatial4r")
    q0 = np.zeros(robot.dof)
    q1 = np.full(robot.dof, 0.3)
    plan = make_plan(robot, [q0, q1], 0.5)
    rrd = tmp_path / "s.rrd"
    with Recording(rrd, robot, plan, flush_every=5) as rec:
        for i in range(10):
            q = q0 + (q1 - q0) * i / 9
            rec.telemetry(0.05 * i, q, q, np.zeros(robot.dof))
    doc = make_report(rrd, png=tmp_path / "s.png", html=tmp_path / "s.html")
    assert len(doc["tip"]["plan_end"]) == 3 and doc["tip"]["end_off_plan_mm"] == pytest.approx(0.0, abs=1e-3)
    assert (tmp_path / "s.png").read_bytes().startswith(PNG_MAGIC)
