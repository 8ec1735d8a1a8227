"""`armbridge bench soft-exec`: the soft demo's plan on the nominal pump board and on a
board of hidden truth, judged by the demo's own report (simavr: the real .elf)."""
import json
import os
import subprocess
import sys

import pytest

ARMBRIDGE = os.path.join(os.path.dirname(sys.executable), "armbridge")


@pytest.mark.hil
def test_bench_soft_exec_runs_the_demo_on_a_nominal_and_a_random_plant(tmp_path):
    out = tmp_path / "soft.json"
    proc = subprocess.run([ARMBRIDGE, "bench", "soft-exec", "--plants", "1", "--uncalibrated-only", "--json", str(out)],
                          capture_output=True, text=True, timeout=900, env={**os.environ, "COLUMNS": "200"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "target (issue 23)" in proc.stdout and "1 random" in proc.stdout
    r = json.loads(out.read_text())
    assert r["targets"] == {"joint_mean_deg": 1.0, "joint_max_deg": 2.0, "tip_max_mm": 10.0}
    (nominal,) = r["nominal"]["runs"]
    (drawn,) = r["random"]["runs"]
    assert nominal["plant"] == "nominal" and drawn["plant"] == "random" and drawn["seed"] == 0
    for run in (nominal, drawn):
        assert "error" not in run, run
        assert run["completed"] and 0 <= run["joint_mean_deg"] <= run["joint_max_deg"]
        assert 0 <= run["tip_mean_mm"] <= run["tip_max_mm"] and run["planned_s"] > 0
        assert run["goal_reached"] == (run["goal_mm"] <= run["goal_tol_mm"])
    # The nominal board's sensors read the truth; a drawn one's read it through their offset and gain.
    assert nominal["true_joint_max_deg"] == pytest.approx(nominal["joint_max_deg"], abs=1e-3)
    assert nominal["true_tip_max_mm"] == pytest.approx(nominal["tip_max_mm"], abs=0.05)
    assert drawn["true_joint_max_deg"] != pytest.approx(drawn["joint_max_deg"], abs=1e-3)
    # Another board is another run: the hidden truth changed what the arm did.
    assert (drawn["joint_mean_deg"], drawn["tip_max_mm"]) != (nominal["joint_mean_deg"], nominal["tip_max_mm"])
    s = r["random"]["summary"]
    assert s["runs"] == s["completed"] == 1 and s["joint_max_deg"] == drawn["joint_max_deg"]


def test_true_errors_read_through_the_boards_bend_and_found_against_truth():
    """A calibrated board reads through its own BEND: the bench turns its readings back into ADC
    counts and then through the drawn sensor (pure: no simulator); what a calibration found is
    compared with the drawn truth."""
    import numpy as np

    from armbridge.bench.soft_exec import found_vs_truth, true_errors
    from armbridge.boards import config
    from armbridge.emulator.pump_plant import hidden_truth
    from armbridge.emulator.truth import truth_rng

    class Checker:
        def tip(self, q):
            return np.asarray(q, float)[:2] * 0.1

    cfg = config("arduino_pump")
    t = hidden_truth(cfg, truth_rng(4))
    target = np.array([0.2, 0.4, 0.5])
    # what the drawn sensor reads (through the default BEND) at the true target
    read_default = np.asarray(t.offset_mrad) / 1000.0 + np.asarray(t.gain) * target
    poses = [{"settled": list(read_default), "target": list(target)}]
    assert true_errors(poses, "random", 4, Checker())["true_joint_max_deg"] < 1e-9
    # a calibrated BEND that makes the board read the truth: the same true error (none)
    bends = []
    for j, d in enumerate(cfg.BEND_DEFAULT):
        per = (d[3] - d[1]) / (d[2] - d[0])                    # mrad per count, default
        adc0 = d[0] + (t.offset_mrad[j] - d[1]) / per          # count at the true 0
        per_true = per / t.gain[j]
        bends.append([0, -adc0 * per_true, 1023, (1023 - adc0) * per_true])
    read_cal = [target.tolist()]
    got = true_errors([{"settled": read_cal[0], "target": list(target)}], "random", 4, Checker(), bends)
    assert got["true_joint_max_deg"] < 1e-6, got
    joints = [{"offset_mrad": t.offset_mrad[j] + 1.0, "sensor_gain": t.gain[j] * 1.005,
               "motor_mm_s_push": t.v_motor[j]} for j in range(3)]
    f = found_vs_truth({"pump": {"joints": joints}}, "random", 4)
    assert f["cal_offset_err_mrad"] == pytest.approx(1.0) and f["cal_gain_err"] == pytest.approx(0.005)
    assert f["cal_motor_err"] == pytest.approx(0.0, abs=1e-12)
