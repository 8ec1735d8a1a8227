"""armbridge.shards' process pool (Runner(workers=N, pool="process")): the serial results from spawned
worker processes, a shard's error named, and `bench shards --pool process` reporting the parallel
efficiency with the load beside it (the numbers themselves are the machine's, never asserted)."""
import json

import numpy as np
import pytest

from armbridge.errors import ArmbridgeError
from armbridge.shards import Job, Runner, Shard
from armbridge.smm.arms import get_smm_arm
from armbridge.smm.grid import random_locations
from armbridge.smm.trace import trace_smms


def _fails(params, shard):
    if shard.id == 1:
        raise ArmbridgeError("no such location")
    return {"id": np.asarray(shard.id)}


def test_process_pool_gives_the_serial_smms_and_names_a_failing_shard():
    arm = get_smm_arm("planar3r")
    x = random_locations(arm, 12, seed=2)
    opts = dict(seeds=8, step=0.05, device="cpu")
    serial = trace_smms(arm, x, 32, 3, **opts)
    with Runner(workers=2, pool="process") as runner:
        assert runner.backend == "process"
        runner.start()
        pooled = trace_smms(arm, x, 32, 3, runner=runner, **opts)
        with pytest.raises(ArmbridgeError, match="job boom, shard 1: no such location"):
            runner.map(Job("boom", _fails), [Shard(i) for i in range(3)])
    np.testing.assert_array_equal(serial.count, pooled.count)
    np.testing.assert_array_equal(serial.points, pooled.points)
    with pytest.raises(ArmbridgeError, match="--pool must be one of ray, process"):
        Runner(workers=2, pool="threads")


def test_bench_shards_process_pool_reports_efficiency_and_load(tmp_path):
    from typer.testing import CliRunner

    from armbridge.cli import build_app

    out = tmp_path / "shards.json"
    res = CliRunner().invoke(build_app(), ["bench", "shards", "--robot", "planar3r", "--locations", "8", "--shard",
                                           "2", "--workers", "1,2", "--pool", "process", "--json", str(out)])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    one, two = data["rows"]
    assert (one["backend"], two["backend"]) == ("serial", "process") and two["identical_to_first"]
    assert two["efficiency"] == pytest.approx(one["wall_s"] / (2 * two["wall_s"]))
    assert all(r["load_average_1min_before"] >= 0 and r["load_average_1min"] >= 0 for r in data["rows"])
    assert data["pool"] == "process"
    assert data["parallel_efficiency_all_cores"] == (two["efficiency"] if data["machine"]["cores"] == 2 else None)
    bad = CliRunner().invoke(build_app(), ["bench", "shards", "--pool", "threads", "--json", str(out)])
    assert isinstance(bad.exception, ArmbridgeError) and "--pool must be ray or process" in str(bad.exception)
