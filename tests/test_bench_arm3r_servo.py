"""`armbridge bench arm3r-servo` (bench/arm3r_servo.py): one drawn board per rig, uncalibrated
beside calibrated, judged by the plant's truth; the command writes its JSON. Lockstep: no wall clock."""
from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from armbridge.bench import arm3r_servo as B


@pytest.fixture(scope="module")
def plan():
    return B.drawing_plan("L")


@pytest.mark.parametrize("rig", ["pca9685"])   # the effort rig's calibration: tests/test_calibrate_arm3r.py
def test_calibration_brings_the_true_pen_onto_the_strokes(rig, plan, tmp_path):
    r = B.run_one(rig, 2, plan, tmp_path)
    unc, cal = r["uncalibrated"], r["calibrated"]
    assert unc["completed"] and cal["completed"], r
    assert unc["stroke_mean_mm"] > 3.0                       # the drawn board's offsets show on the paper
    # calibrated: the PWM count (11.5 mrad at 50 Hz) is left, and the servos' dead band and play
    # where the lead cannot foresee a reversal (issue 23's 1.5 mm is the bench's figure over 20
    # boards; on this one board and letter at 50 Hz, mean 0.46 and max 1.76 mm)
    assert cal["stroke_mean_mm"] < min(1.0, unc["stroke_mean_mm"] / 5)
    assert cal["stroke_max_mm"] < 2.5
    assert cal["track_mean_mrad"] < unc["track_mean_mrad"] / 3
    assert set(r["found"]) == ({"gains", "jig"} if rig == "effort" else {"jig"})


def test_the_command_writes_its_json(tmp_path, monkeypatch):
    from armbridge.bench.arm3r_servo import arm3r_servo_cmd
    import typer

    monkeypatch.setattr(B, "RIGS", ("effort",))
    monkeypatch.setattr(B, "run", lambda plants, **kw: {
        "effort": {"runs": [], "uncalibrated": {"runs": plants, "completed": 0},
                   "calibrated": {"runs": plants, "completed": 0}}})
    app = typer.Typer()
    app.command()(arm3r_servo_cmd)
    out = tmp_path / "b.json"
    res = CliRunner().invoke(app, ["--plants", "1", "--rigs", "effort", "--json", str(out)])
    assert res.exit_code == 0, res.output
    assert json.loads(out.read_text())["effort"]["uncalibrated"]["runs"] == 1


def test_the_summary_counts_the_boards_within_the_target_by_mean_and_by_largest_error():
    runs = [{"calibrated": {"completed": True, "stroke_mean_mm": m, "stroke_max_mm": x, "track_mean_mrad": 1.0,
                            "track_max_mrad": 2.0}} for m, x in ((0.2, 1.0), (0.4, 1.6), (1.6, 3.0), (0.3, 1.5))]
    s = B.summarize(runs, "calibrated")
    assert s["completed"] == 4
    assert s["meet_target"] == 0.75 and s["meet_target_max"] == 0.5
    assert s["stroke_max_mm"] == 3.0 and s["stroke_max_mm_median"] == pytest.approx(1.55)
