"""`armbridge bench masr-ik` / `masr-plan` in a reduced size, so the benchmarks cannot rot.

Correctness only (no wall-clock targets: CI machines are noisy): every Table I
row is present with finite numbers, success rates are in range, the planning
tables have a row per reported iteration count, the JSON is complete.
"""
import json
import math

from typer.testing import CliRunner

from armbridge.bench import masr_ik, masr_plan
from armbridge.cli import build_app



def _finite(x):
    return isinstance(x, (int, float)) and math.isfinite(x)


def test_bench_masr_ik_quick_cli_writes_json(tmp_path, monkeypatch):
    monkeypatch.setattr(masr_ik, "QUICK", masr_ik.MasrIKBenchSize(trials=30, nr_trials=3, nr_restarts=30,
                                                                  single_queries=10, batch_repeats=1))
    out = tmp_path / "ik.json"
    result = CliRunner().invoke(build_app(), ["bench", "masr-ik", "--quick", "--json", str(out)])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    rows = {r["row"]: r for r in data["rows"]}
    expected = ["IK-NN (11)", "IK-NN (12)", "IK-NN (12) + refinement", "IK-NN (12) + refinement + fallback",
                "int8 IK-NN (12)", "NR m=30"]
    assert list(rows) == expected
    for name in expected:
        r = rows[name]
        if "missing" in r:  # the eq. (11) model is optional
            assert name == "IK-NN (11)"
            continue
        assert r["trials"] == (3 if name.startswith("NR") else 30)
        for key in ("mean_dp_mm", "mean_dphi_deg", "mean_action_time_s", "batched_queries_per_s"):
            assert _finite(r[key]) and r[key] >= 0, (name, key)
        assert 0 <= r["success_rate"] <= 100
        assert _finite(r["single"]["median_ms"]) and r["single"]["median_ms"] > 0
    # refinement never makes a pose worse than the network's own answer
    assert rows["IK-NN (12) + refinement"]["mean_dp_mm"] <= rows["IK-NN (12)"]["mean_dp_mm"] + 1e-9
    assert set(data["targets"]) >= {"iknn12_success_ge_87", "refined_success_ge_99.5", "int8_within_1pt"}
    assert all(isinstance(v, bool) for v in data["targets"].values())
    # the goal check is over the robot's joint margin, and every row's answers hold it
    assert data["d_margin_m"] == 0.005
    for name in expected:
        if "missing" not in rows[name]:
            assert rows[name]["holds_margin"] == 100.0 and rows[name]["margin_mm"] == 5.0, name
    fb = rows["IK-NN (12) + refinement + fallback"]
    assert 0 <= fb["fallback"]["solved"] <= fb["fallback"]["queries"] <= 30
    assert fb["success_rate"] >= rows["IK-NN (12) + refinement"]["success_rate"]


def test_bench_masr_plan_quick_cli_writes_json_and_pngs(tmp_path, monkeypatch):
    monkeypatch.setattr(masr_plan, "QUICK", masr_plan.MasrPlanBenchSize(
        environments=2, fig5_iterations=120, trials=3, fig7_iterations=120, timing_runs=1, ompl_runs=0))
    out = tmp_path / "plan.json"
    png = tmp_path / "png"
    result = CliRunner().invoke(build_app(), ["bench", "masr-plan", "--quick", "--json", str(out),
                                              "--png-dir", str(png)])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    labels = [masr_plan.label(p) for p in masr_plan.P_CS]
    f5 = data["fig5"]
    assert [r["iterations"] for r in f5["rows"]] == [50, 100, 120]
    for row in f5["rows"]:
        for pl in labels:
            assert 0 <= row[pl]["success_rate"] <= 1
            c = row[pl]["mean_cost_own_s"]
            assert c is None or (_finite(c) and c >= 0)
    for pl in labels:
        assert len(f5["curves"][pl]["success_rate"]) == 120
    f7 = data["fig7"]
    assert set(f7["environments"]) == {"E1", "E2", "E3"}
    for e in f7["environments"].values():
        for row in e["rows"]:
            for pl in (labels[0], labels[2]):
                for key in ("success_rate", "below_p15", "below_p25"):
                    assert 0 <= row[pl][key] <= 1
                assert row[pl]["below_p15"] <= row[pl]["below_p25"] <= row[pl]["success_rate"]
    for env in ("E1", "E2", "E3"):
        for pl in (labels[0], labels[2]):
            r = data["timing"][env][pl]
            assert _finite(r["median_s_per_1000"]) and r["median_s_per_1000"] > 0
    assert "skipped" in data["ompl"]
    assert isinstance(data["target_masr_not_worse"]["met"], bool)
    assert (png / "masr-fig5.png").stat().st_size > 0 and (png / "masr-fig7.png").stat().st_size > 0


def test_checkpoints():
    assert masr_plan.checkpoints(1000) == [50, 100, 200, 500, 1000]
    assert masr_plan.checkpoints(12000) == [50, 100, 200, 500, 1000, 2000, 5000, 10000, 12000]
