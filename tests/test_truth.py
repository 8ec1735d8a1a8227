"""Hidden truth (emulator/truth.py): spreads drawn from their own seeded stream,
inside their bounds, one value per joint where asked; a bad `plant=` is one line."""
import os
import subprocess
import sys
from dataclasses import dataclass

import numpy as np
import pytest
from armbridge.emulator.truth import PLANTS, Spread, check_plant, draw, table, truth_rng
from armbridge.errors import ArmbridgeError

ARMBRIDGE = os.path.join(os.path.dirname(sys.executable), "armbridge")


@dataclass(frozen=True)
class Params:
    gain: float = 2.0
    offset: tuple[float, ...] = (0.0, 0.0, 0.0)
    friction: float = 0.1
    fixed: float = 7.0


SPREADS = (
    Spread("gain", "scale", 0.05, lo=1.5, hi=2.5, source="data sheet"),
    Spread("offset", "normal", 0.02, per_joint=True, lo=-0.03, hi=0.03, unit="rad", source="spline"),
    Spread("friction", "uniform", 0.05, lo=0.0, unit="N", source="ours"),
)


def test_the_same_seed_draws_the_same_truth_and_another_seed_another():
    a = draw(Params(), SPREADS, truth_rng(4), 3)
    assert a == draw(Params(), SPREADS, truth_rng(4), 3)
    assert a != draw(Params(), SPREADS, truth_rng(5), 3)
    assert a.fixed == 7.0 and isinstance(a.offset, tuple) and len(a.offset) == 3


def test_draws_stay_inside_their_bounds_and_spread_as_declared():
    many = [draw(Params(), SPREADS, truth_rng(s), 3) for s in range(400)]
    gains = np.array([p.gain for p in many])
    offsets = np.array([p.offset for p in many])
    friction = np.array([p.friction for p in many])
    assert gains.min() >= 1.5 and gains.max() <= 2.5
    assert abs(gains.std() / 2.0 - 0.05) < 0.01          # scale: relative sigma
    assert offsets.min() >= -0.03 and offsets.max() <= 0.03
    assert offsets.min() == -0.03 and offsets.max() == 0.03  # the clip is reached (sigma 0.02, bound 0.03)
    assert abs(np.corrcoef(offsets[:, 0], offsets[:, 1])[0, 1]) < 0.15  # joints drawn independently
    assert friction.min() >= 0.05 and friction.max() <= 0.15


def test_the_truths_stream_is_not_the_noise_stream_of_the_same_seed():
    assert truth_rng(3).standard_normal() != np.random.default_rng(3).standard_normal()


def test_bad_spreads_and_plants_are_one_line():
    with pytest.raises(ArmbridgeError, match="no such field"):
        draw(Params(), (Spread("mass", "normal", 1.0),), truth_rng(0), 3)
    with pytest.raises(ArmbridgeError, match="one value per joint"):
        draw(Params(offset=(0.0, 0.0)), SPREADS, truth_rng(0), 3)
    with pytest.raises(ArmbridgeError, match="nominal, random"):
        check_plant("true")
    assert PLANTS == ("nominal", "random")


def test_the_docs_table_names_every_field_and_its_source():
    rows = table(SPREADS)
    assert len(rows) == 3
    assert rows[1] == "| `offset` | N(0, 0.02 rad) per joint | [-0.03, 0.03] | spline |"
    assert rows[0].startswith("| `gain` | x (1 + N(0, 0.05))")


def test_emulate_refuses_an_unknown_plant_in_one_line():
    r = subprocess.run([ARMBRIDGE, "emulate", "esp32", "--plant", "wobbly", "--for", "0.1"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip() == "error: --plant: plant 'wobbly': expected one of nominal, random" and not r.stdout
