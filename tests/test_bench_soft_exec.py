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
    proc = subprocess.run([ARMBRIDGE, "bench", "soft-exec", "--plants", "1", "--json", str(out)],
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
