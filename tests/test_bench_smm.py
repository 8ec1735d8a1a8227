"""`armbridge bench smm` in a reduced size, so the benchmark cannot rot.

Correctness only (no wall-clock targets): every method row is there with
finite numbers, correction lowers the learned FK error, realtime-smm (the
paper's code) ran on the same locations, the simulation compared the methods.
"""
import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from armbridge.bench import smm as bench
from armbridge.cli import build_app
from armbridge.smm.arms import get_smm_arm
from armbridge.smm.manifold import SmmSet


def test_location_fk_error_averages_each_locations_points():
    arm = get_smm_arm("planar3r")
    q = np.zeros((2, 2, 4, 3))
    q[0, 0] = [0.0, 0.0, 0.0]  # tip at (3, 0): error 0
    q[0, 1] = [0.0, 0.0, np.pi]  # tip at (1, 0): 2 m off, 2/3 of the reach
    q[1] = np.nan
    smm = SmmSet(q, np.array([2, 0]), np.zeros(2, bool))
    err = bench.location_fk_error(arm, smm, np.array([[3.0, 0.0], [3.0, 0.0]]))
    assert err[0] == pytest.approx(100 * (2 / 3) / 2)
    assert math.isnan(err[1])


def test_bench_smm_quick_cli_writes_json(tmp_path):
    out = tmp_path / "smm.json"
    png = tmp_path / "fig3.png"
    result = CliRunner().invoke(build_app(), ["bench", "smm", "--quick", "--robots", "planar3r", "--json", str(out),
                                              "--png", str(png)])
    assert result.exit_code == 0, result.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    data = json.loads(out.read_text())
    (t3,) = data["table3"]
    rows = {r["method"]: r for r in t3["rows"]}
    assert set(rows) == {"nullspace (ours)", "learned, before correction", "learned, after correction (3)",
                         "realtime-smm 0.1.2 (paper's code, nullspace)"}
    for name, r in rows.items():
        assert r["single_ms"] > 0 and math.isfinite(r["fk_error_pct"]["mean"]), name
    before, after = rows["learned, before correction"], rows["learned, after correction (3)"]
    assert after["fk_error_pct"]["mean"] < before["fk_error_pct"]["mean"]
    assert 0 <= after["branch_count_mismatch_pct"] <= 100
    by = after["mismatch_by_true_count"]
    assert sum(v["locations"] for v in by.values()) == after["locations"]
    assert sum(v["mismatched"] for v in by.values()) / after["locations"] * 100 == pytest.approx(
        after["branch_count_mismatch_pct"])
    peer = rows["realtime-smm 0.1.2 (paper's code, nullspace)"]
    assert peer["locations"] == bench.QUICK.peer_locations and sum(peer["statuses"].values()) == peer["locations"]
    assert len(data["fig3"]["mean_abs_error_rad"]["planar3r"]) == len(data["fig3"]["K"])
    errs = data["fig3"]["mean_abs_error_rad"]["planar3r"]
    assert errs == sorted(errs, reverse=True)  # more components, less error
    sim = data["simulation"]
    assert {"nullspace (ours)", "learned"} <= set(sim)
    assert all(0 <= sim[k]["success"] <= sim["trials"] for k in ("nullspace (ours)", "learned"))
    assert set(data["targets"]) >= {"planar3r_fk_before_le_0.29pct", "planar3r_mismatch_le_0.7pct"}


def test_mismatch_by_true_count_splits_the_mismatch_by_the_reference_count():
    ref = np.array([1, 1, 2, 2, 2, 3, 3, 0])
    got = np.array([1, 2, 2, 2, 1, 2, 2, 0])
    by = bench.mismatch_by_count(got, ref)
    assert by["3"] == {"locations": 2, "mismatched": 2, "mismatch_pct": 100.0, "got": {"2": 2}}
    assert by["2"]["mismatched"] == 1 and by["2"]["got"] == {"1": 1}
    assert by["1"]["mismatch_pct"] == 50.0 and by["0"]["mismatched"] == 0 and by["0"]["got"] == {}


def test_bench_smm_rejects_unknown_robot(tmp_path):
    result = CliRunner().invoke(build_app(), ["bench", "smm", "--robots", "planar9r", "--json", str(tmp_path / "x")])
    assert result.exit_code != 0 and "unknown SMM robot" in str(result.exception)


def test_peer_targets_are_the_fk_of_the_locations():
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (5, 7))
    arm = get_smm_arm("spatial7r")
    np.testing.assert_allclose(bench.target_matrix(arm, np.asarray(arm.task(q))), arm.fk(q), atol=1e-12)
    arm = get_smm_arm("spatial4r")
    t = bench.target_matrix(arm, np.asarray(arm.task(q[:, :4])))
    np.testing.assert_allclose(t[:, :3, 3], arm.fk(q[:, :4])[:, :3, 3], atol=1e-12)
    np.testing.assert_array_equal(t[:, :3, :3], np.tile(np.eye(3), (5, 1, 1)))


def test_7r_locations_lie_in_the_models_region(tmp_path):
    from armbridge.smm.learned import CARD_NAME, CARD_VERSION, KIND

    arm = get_smm_arm("spatial7r")
    lo, hi = (2.9, -0.4, 0.0, -np.pi), (3.1, -0.2, np.pi, np.pi)
    card = {"kind": KIND, "card_version": CARD_VERSION, "robot": arm.name, "fourier": {"K": 40},
            "clusters": {"branches": [0]}, "files": {"classifier": {}, "regressors": {}},
            "dataset": {"grid_lo": lo, "grid_hi": hi, "grid_shape": [3, 3, 16, 32]}}
    (tmp_path / CARD_NAME).write_text(json.dumps(card))
    x, where = bench.bench_locations(arm, 400, tmp_path)
    c, shift = arm.canonical(x)
    assert x.shape == (400, 6) and "region" in where
    assert (c[:, 0] >= lo[0] - 1e-9).all() and (c[:, 0] <= hi[0] + 1e-9).all()
    assert (c[:, 1] >= lo[1] - 1e-9).all() and (c[:, 1] <= hi[1] + 1e-9).all()
    # tool directions uniform on the sphere: the axis's z component has mean ~0 and spread ~1/sqrt(3)
    assert abs(np.cos(c[:, 2]).mean()) < 0.1 and abs(np.cos(c[:, 2]).std() - 3**-0.5) < 0.05
    x4, where4 = bench.bench_locations(get_smm_arm("spatial4r"), 10, tmp_path / "none")
    assert x4.shape == (10, 3) and "random configurations" in where4
