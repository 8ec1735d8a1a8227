"""Margin sampling (smm/margin.py, `train smm-7r --margin`) and `armbridge bench smm-data`, which
measures it, in reduced sizes.

Correctness only (no wall-clock targets): the margin rule picks the least
sure rows, points take the nearest cluster of their own count, the build
traces what it picked, the power law recovers a known one, and the bench
traces, trains and writes every row with the counts it traced.
"""
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from armbridge.bench.smm_data import power_law
from armbridge.cli import build_app
from armbridge.errors import ArmbridgeError
from armbridge.smm.margin import least_certain


def test_margin_sampling_picks_the_rows_whose_two_likeliest_classes_are_closest():
    logits = np.array([[5.0, 0.0, 0.0],    # sure
                       [1.0, 1.0, -3.0],   # a tie: least sure
                       [2.0, 1.0, 0.0],    # unsure
                       [0.0, 0.0, 9.0]])   # sure
    assert least_certain(logits, 2).tolist() == [1, 2]
    assert least_certain(logits, 0).tolist() == []
    with pytest.raises(ArmbridgeError, match="0 to 4 rows"):
        least_certain(logits, 5)
    with pytest.raises(ArmbridgeError, match="classes >= 2"):
        least_certain(logits[:, :1], 1)


def test_power_law_recovers_a_known_exponent_and_extrapolates():
    n = np.array([1000, 2000, 4000, 8000])
    law = power_law(n, 300 * n ** -0.5)
    assert law["b"] == pytest.approx(0.5) and law["a"] == pytest.approx(300)
    assert law["locations_for_paper_pct"] == pytest.approx((300 / 6.02) ** 2)
    assert power_law([1000], [30.0]) is None and power_law([1000, 2000], [30.0, 0.0]) is None


def test_bench_smm_data_tiny_cli_writes_every_row(tmp_path):
    out = tmp_path / "data.json"
    res = CliRunner().invoke(build_app(), ["bench", "smm-data", "--sizes", "12,24", "--test", "10", "--active", "12",
                                           "--candidates", "3", "--epochs", "2", "--json", str(out)])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    rows = [(r["sampling"], r["locations"], r["azimuth"]) for r in data["rows"]]
    assert rows == [("uniform", 12, "cos, sin"), ("uniform", 24, "cos, sin"), ("uniform", 24, "raw"),
                    ("uniform 12 + margin 12", 24, "cos, sin")]
    for r in data["rows"]:
        assert 0 <= r["held_out_mismatch_pct"] <= 100 and 0 <= r["train_mismatch_pct"] <= 100
    assert sum(data["held_out_count_histogram"].values()) == 10
    assert sum(data["rows"][-1]["picked_count_histogram"].values()) == 12  # traced, not assumed
    bad = CliRunner().invoke(build_app(), ["bench", "smm-data", "--sizes", "12", "--active", "5", "--json", str(out)])
    assert bad.exit_code != 0 and "--active must be one of --sizes" in str(bad.exception or bad.output)


def test_margin_points_take_the_nearest_cluster_of_their_own_count_across_the_azimuth_seam():
    from armbridge.smm.dataset import SmmDataset
    from armbridge.smm.grid import PERIODIC, GridSpec
    from armbridge.smm.margin import add_points

    grid = GridSpec((0.0, 0.0, 0.0, -np.pi), (1.0, 1.0, np.pi, np.pi), (1, 1, 2, 8))
    canon = np.array([[0.5, 0.5, 1.0, -3.0], [0.5, 0.5, 1.0, 0.0], [0.5, 0.5, 1.0, 2.9]])
    ds = SmmDataset(robot="spatial7r", canon=canon, cluster=np.array([0, 1, 2]), label=np.array([0, 1, 2]),
                    coeffs=np.zeros((3, 1, 7, 2), complex), cluster_branches=np.array([2, 3, 2]),
                    boundary_canon=np.zeros((0, 4)), boundary_label=np.zeros(0, np.int64), K=2, N=8)
    pts = np.array([[0.5, 0.5, 1.0, 3.1],    # count 2: cluster 0 at -3.0 is 0.18 rad away across the seam, 2 is 0.2
                    [0.5, 0.5, 1.0, 2.8],    # count 2: cluster 2, 0.1 rad away
                    [0.5, 0.5, 1.0, 3.1],    # count 3: only cluster 1, 3.1 rad (3.9 cells) away: beyond a reach of 2
                    [0.5, 0.5, 1.0, 0.5]])   # count 3: cluster 1, 0.5 rad away
    out = add_points(ds, grid, pts, np.array([2, 2, 3, 3]), 2.0, PERIODIC[4])
    assert out.boundary_label.tolist() == [0, 2, -1, 1]
    assert out.boundary_canon.shape == (4, 4) and len(out.canon) == 3  # classifier-only: no new grid rows
    with pytest.raises(ArmbridgeError, match="do not fit"):
        add_points(ds, grid, pts[:, :3], np.array([2, 2, 3, 3]), 2.0, PERIODIC[4])


def test_grow_traces_the_least_sure_candidates_and_stops_at_its_deadline():
    import time

    from armbridge.smm.arms import get_smm_arm
    from armbridge.smm.dataset import SmmDataset
    from armbridge.smm.grid import region_grid
    from armbridge.smm.margin import grow

    arm = get_smm_arm("spatial7r")
    grid = region_grid(arm, (1, 1, 2, 4))
    ds = SmmDataset(robot="spatial7r", canon=grid.centres(), cluster=np.zeros(8, np.int64), label=np.zeros(8, np.int64),
                    coeffs=np.zeros((8, 1, 7, 2), complex), cluster_branches=np.array([3]),
                    boundary_canon=np.zeros((0, 4)), boundary_label=np.zeros(0, np.int64), K=2, N=8)
    seen = []

    def logits(c):
        seen.append(c)
        z = np.zeros((len(c), 2))
        z[:, 1] = c[:, 3]  # least sure where the azimuth is nearest 0
        return z

    out, info = grow(arm, ds, grid, logits, 2, 5, None, 1, seeds=12, step=0.05, sing_tol=0.005)
    assert info["candidates"] == 10 and info["traced"] == 2 and sum(info["count_histogram"].values()) == 2
    cand = np.concatenate(seen)
    assert np.allclose(np.sort(np.abs(out.boundary_canon[:, 3])), np.sort(np.abs(cand[:, 3]))[:2])
    late, info = grow(arm, ds, grid, logits, 2, 5, time.monotonic() - 1, 1, seeds=12, step=0.05)
    assert info["traced"] == 0 and len(late.boundary_canon) == 0
    with pytest.raises(ArmbridgeError, match=r"at most 4000000 at once \(n <= 200000\)"):
        grow(arm, ds, grid, logits, 200_001, 20, None, 1)


def test_train_smm_7r_margin_adds_traced_classifier_only_locations(tmp_path):
    from armbridge.smm.arms import get_smm_arm
    from armbridge.train.smm_data import load_or_build

    arm = get_smm_arm("spatial7r")
    ds, info = load_or_build(arm, tmp_path / "ds.npz", "1x1x4x8", 8, 32, 0, False, None, per_cell=0, sing_tol=0.005,
                             margin=5)
    assert len(ds.canon) == 32 and len(ds.boundary_canon) == 5  # the grid's rows, and the margin's points
    m = info["margin"]
    assert m["traced"] == 5 and m["candidates"] == 100 and sum(m["count_histogram"].values()) == 5
    assert (ds.boundary_label >= -1).all() and int((ds.boundary_label >= 0).sum()) == m["labelled"]
    with pytest.raises(ArmbridgeError, match="no labelled cell"):
        load_or_build(arm, tmp_path / "tiny.npz", "1x1x2x4", 8, 32, 0, False, None, per_cell=0, sing_tol=0.005, margin=5)
    with pytest.raises(ArmbridgeError, match="--margin must be at most 200000"):
        load_or_build(arm, tmp_path / "big.npz", "1x1x4x8", 8, 32, 0, False, None, margin=200_001)
    assert not (tmp_path / "big.npz").exists()
    with pytest.raises(ArmbridgeError, match="--margin samples the 7R"):
        load_or_build(get_smm_arm("planar3r"), tmp_path / "3r.npz", "", 8, 32, 0, False, None, margin=5)
