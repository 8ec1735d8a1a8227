"""`armbridge bench smm-data` in a reduced size, and the pieces it is made of.

Correctness only (no wall-clock targets): the margin rule picks the least
sure rows, the power law recovers a known one, and the CLI traces, trains
and writes every row with the counts it traced.
"""
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from armbridge.bench.smm_data import power_law
from armbridge.cli import build_app
from armbridge.errors import ArmbridgeError
from armbridge.smm.refine import least_certain


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
