"""`armbridge bench arm3r --quick`: Tables 5-8 of the 3R drawing-arm paper, end to end
through the command (real onnxruntime, FABRIK, CBF, roboticstoolbox)."""
from __future__ import annotations

import json

from require import missing

try:
    import onnxruntime  # noqa: F401
    import qpsolvers  # noqa: F401
    import roboticstoolbox  # noqa: F401
except ImportError as exc:
    missing(f"{exc.name} is not installed (`make setup` installs it)")

from armbridge.bench import arm3r  # noqa: E402


def test_bench_arm3r_quick(bench_arm3r_quick):
    """The run (with --lyapunov-png, which only adds the PNG) is shared with test_lyapunov:
    tests/bench_runs.py."""
    r, out, _ = bench_arm3r_quick
    assert r.exit_code == 0, r.output
    res = json.loads(out.read_text())
    assert [s["name"] for s in res["samples"]] == list(arm3r.QUICK.samples)
    for s in res["samples"]:
        assert s["points"] > 100 and s["fabrik_converged_pct"] == 100.0 and s["fabrik_oriented_pct"] == 100.0
        assert set(s["rows"]) == set(arm3r.ROWS)
        for row in arm3r.ROWS:
            for c in arm3r.COLS:
                m = s["rows"][row][c]
                assert m["rmse"] ** 2 == m["mse"] or abs(m["rmse"] ** 2 - m["mse"]) <= 1e-12 * max(m["mse"], 1)
                assert m["mae"] <= m["rmse"] + 1e-12
        assert s["rows"]["ann_fabrik"]["tip_mm"]["mean"] < 0.1
        assert s["rows"]["ann_fabrik_cbf"]["tip_mm"]["mean"] < 0.1   # the filter passes in-region references
        assert s["rows"]["ann"]["tip_mm"]["mean"] > 1.0                  # the net alone is mm-coarse
        assert s["rows"]["closed_form"]["tip_mm"]["max"] < 1e-6
        # the wrist angle (theta = q1 + q2 + q3 against the pen angle) within the paper's 1.25 deg RMSE
        # (Table 8), and x, y within its per-sample Tables 6 and 7; FABRIK on position alone spends it
        paper = arm3r.PAPER_PER_SAMPLE[s["name"]]
        assert s["paper"] == paper
        for row in ("ann_fabrik", "ann_fabrik_cbf"):
            assert s["rows"][row]["theta"]["rmse"] <= arm3r.PAPER["overall_theta"]["rmse"]
            assert all(s["rows"][row][c]["rmse"] <= paper[c]["rmse"] for c in ("x", "y"))
        assert s["rows"]["ann_fabrik_position_only"]["theta"]["rmse"] > arm3r.PAPER["overall_theta"]["rmse"]
        assert s["rows"]["ann_fabrik_position_only"]["tip_mm"]["mean"] < 0.1
        assert s["rows"]["rtb_lm"]["tip_mm"]["mean"] < 0.01
        assert s["cbf"]["h_min"] >= 0 and s["cbf"]["limit_margin_min_rad"] >= 0
        assert {"single_ms", "batched_ms"} <= set(s["timing"]["ann_fabrik"])
    rc = res["random_cbf"]
    assert rc["targets"] == arm3r.QUICK.random_targets and rc["outside_region"] > rc["targets"] // 2
    assert rc["region_violations"] == rc["limit_violations"] == rc["final_unsafe"] == rc["lyapunov_rises"] == 0
    assert res["targets"]["ann_fabrik_mean_under_0.1mm_every_sample"] and res["targets"]["zero_cbf_violations"]
    assert res["targets"]["theta_rmse_at_most_paper_1.25deg_every_sample"]
    assert res["targets"]["xy_rmse_at_most_papers_every_sample"]
    assert res["overall"]["ann_fabrik_cbf"]["theta"]["rmse"] <= 1.25
    assert "per sample, RMSE" in r.output and "ROBOTICS" in r.output
    for net in res["int8"].values():
        assert net["vs_float_tip_mean_mm"] > 0 and net["with_fabrik_tip_mean_mm"] < 0.1
    assert set(res["overall"]) == set(arm3r.ROWS)
    assert res["safe_region"]["radius_m"] > 0.08
    assert "overall (Tables 5, 8)" in r.output
    # ROBOTICS on the emulated arm: both rigs, the board's own IK and planned by --ik paper, each drawn whole
    dr = res["drawing"]
    assert set(dr["runs"]) == {"effort", "pca9685", "effort, board IK (--cartesian)", "effort, --ik paper"}
    assert dr["runs"]["effort, --ik paper"]["plan_ik"] == "paper"
    for name, run in dr["runs"].items():
        assert run["completed"] and run["pen"] == "servo", (name, run)
        assert run["characters"] == 8 and run["trace_points"] > 100
        assert 0 < run["trace_mean_mm"] <= run["trace_max_mm"] < 10, (name, run)
    assert dr["runs"]["effort, board IK (--cartesian)"]["ik"] == "board"
    assert res["targets"]["robotics_drawn_on_every_rig"]
    assert "ROBOTICS at 0.1 m/s on pca9685" in r.output
