"""armbridge.shards: sharded jobs (SMM data, IK-NN data, bench masr-plan, bench wjrrt) give the serial
results, on a real local Ray cluster of two workers too, and a killed job resumes from its checkpoints
without redoing finished shards.

The cluster (ray.init(num_cpus=2) in this process, its own temp folder) is started once for
the module and shut down by a finalizer; the killed job runs in a child process that connects
to it, as a driver on another machine would.
"""
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from armbridge.bench import masr_plan
from armbridge.bench.masr_shards import decode_curves, encode_curves
from armbridge.errors import ArmbridgeError
from armbridge.ik.masr_data import GridSpec as MasrGrid
from armbridge.ik.masr_data import generate
from armbridge.robots import get_masr
from armbridge.shards import Runner
from armbridge.shards.store import DONE_LOG, ShardStore
from armbridge.smm import dataset
from armbridge.smm.arms import get_smm_arm
from armbridge.smm.grid import GridSpec
from require import missing

ROOT = Path(__file__).resolve().parents[1]
# A small SMM data job: 64 cells of the planar 3R, 4 per shard (16 grid shards, then the boundary's).
SMM_JOB = "dict(grid=GridSpec((0.0,), (3.3,), (64,)), batch=4, seeds=8, device='cpu', step=0.1, per_cell=1, N=64, K=16)"
SWEEP = masr_plan.MasrPlanBenchSize(environments=0, fig5_iterations=60, trials=3, fig7_iterations=150,
                                    timing_runs=1, ompl_runs=0)  # Fig. 7: E1-E3 x 2 planners, 3 trials each


def smm_job() -> dict:
    return eval(SMM_JOB, {"GridSpec": GridSpec})  # the same text runs in the killed job's driver


def build(runner=None):
    job = smm_job()
    return dataset.build_dataset(get_smm_arm("planar3r"), job.pop("grid"), runner=runner, **job).dataset


def same_dataset(a, b):
    for f in dataset.FIELDS:
        x, y = np.asarray(getattr(a, f)), np.asarray(getattr(b, f))
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=x.dtype.kind in "fc"), f


def costs_only(result):
    """A bench result without what measures the machine (seconds) or says where it ran."""
    if isinstance(result, dict):
        return {k: costs_only(v) for k, v in result.items()
                if "time" not in k and k not in ("wall_s", "environment_generation_s", "shards")}
    if isinstance(result, list):
        return [costs_only(v) for v in result]
    return result


# ------------------------------------------------------------------ without a cluster


def test_store_refuses_another_job_and_other_specs(tmp_path):
    store = ShardStore(tmp_path, "job", {"a": 1})
    store.write(0, "key0", {"x": np.arange(3)}, {"seconds": 0.1})
    assert store.done(0, "key0") and not store.done(1, "key1")
    assert np.array_equal(np.load(store.path(0), allow_pickle=False)["x"], np.arange(3))  # no pickles
    with pytest.raises(ArmbridgeError, match="other parameters"):
        ShardStore(tmp_path, "job", {"a": 2})
    with pytest.raises(ArmbridgeError, match="another spec"):
        store.done(0, "other")
    with pytest.raises(ArmbridgeError, match="object array"):
        store.write(1, "key1", {"x": np.array([{}, None])}, {})
    assert [r["shard"] for r in ShardStore(tmp_path, "job", {"a": 1}).log()] == [0]
    assert not list(tmp_path.glob("*.tmp*"))  # written through a temporary file, moved into place


def test_best_cost_curves_round_trip_exactly():
    rng = np.random.default_rng(0)
    c = np.full((4, 50), np.inf)
    for r, first in enumerate((0, 7, 49)):
        c[r, first:] = np.minimum.accumulate(rng.uniform(1, 2, 50 - first))
    got = decode_curves(**encode_curves(c), iterations=50)  # the last row never finds a path
    assert np.array_equal(got, c)


def test_ik_nn_data_set_in_checkpointed_shards_equals_the_serial_run_and_resumes(tmp_path):
    arm = get_masr("masr5")
    spec = MasrGrid(nx=60, ny=30, rho=3, batch=2000, max_samples=400_000, seed=1)
    ref = generate(arm, spec)
    assert ref.converged and ref.samples < spec.max_samples  # the stop check ended it early
    ck = Runner(checkpoint=tmp_path)
    got = generate(arm, spec, runner=ck)
    assert np.array_equal(got.poses, ref.poses) and got.info() == ref.info()
    log = tmp_path / "masr-dataset" / DONE_LOG
    before = log.read_text()
    assert len(before.splitlines()) == ref.samples // spec.batch
    again = generate(arm, spec, runner=ck)  # every shard read back: nothing computed again
    assert log.read_text() == before and np.array_equal(again.poses, ref.poses)


# ------------------------------------------------------------------ on a local Ray cluster


@pytest.fixture(scope="module")
def cluster():
    try:
        import ray
    except ImportError:
        missing("ray is not installed (pip install 'armbridge[ray]')")
    if ray.is_initialized():
        pytest.fail("a Ray is already initialised in this process")
    temp = tempfile.mkdtemp(prefix="abray", dir="/tmp")  # short: Ray's socket paths must fit 107 bytes
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, _temp_dir=temp)
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()
        shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture(scope="module")
def serial_smm():
    return build()


def test_cluster_has_two_workers(cluster):
    import ray

    assert ray.cluster_resources()["CPU"] == 2


def test_smm_data_job_on_ray_equals_serial(cluster, serial_smm, tmp_path):
    got = build(Runner(ray=cluster, checkpoint=tmp_path))
    same_dataset(got, serial_smm)
    log = [json.loads(x) for x in (tmp_path / "smm-grid" / DONE_LOG).read_text().splitlines()]
    assert sorted(r["shard"] for r in log) == list(range(16))
    # on Ray's workers, not here (which worker takes which shard is Ray's scheduling: on a loaded machine
    # one worker may take them all before the other has started, so the test does not count them)
    assert os.getpid() not in {r["pid"] for r in log}


def test_planning_sweep_on_ray_equals_serial(cluster):
    serial = masr_plan.run(SWEEP, parts=("fig7",))
    on_ray = masr_plan.run(SWEEP, parts=("fig7",), runner=Runner(ray=cluster))
    assert on_ray["shards"] == "ray" and serial["shards"] == "serial"
    assert costs_only(on_ray) == costs_only(serial)
    e1 = on_ray["fig7"]["environments"]["E1"]
    assert e1["rows"][-1]["iterations"] == 150 and e1["cost_range_s"] is not None  # paths were found


def no_times(result):
    """A wjrrt result without its times and what is read off them (success at a budget t)."""
    if isinstance(result, dict):
        return {k: no_times(v) for k, v in result.items() if "time" not in k and k != "success_at"}
    if isinstance(result, list):
        return [no_times(v) for v in result]
    return result


def test_wjrrt_sweep_on_ray_equals_serial_and_resumes(cluster, tmp_path):
    """One shard per (scene, seed): our planners' runs are the serial ones but their times (no run
    ran out of T); RRTConnect's runs are there and re-checked; a rerun reads every shard back."""
    from typer.testing import CliRunner

    from armbridge.bench import wjrrt
    from armbridge.bench.command import bench_app
    from armbridge.planning import ompl_bridge

    if ompl_bridge.available():
        missing(f"the ompl Python wheel is needed: {ompl_bridge.available()}")
    # T only guards against a hang: every run here ends by success or its iteration budget in well under a
    # second, so the records do not depend on the machine's speed (test_bench_wjrrt.py, T)
    size, scenes, planners = wjrrt.WjrrtBenchSize(seeds=3, time_limit=60.0), ("two-arm", "three-arm"), \
        ("wjrrt", "jt-rrt", "birrt", "wjrrt-connect", "RRTConnect")
    serial = wjrrt.run(size, scenes, planners)
    on_ray = wjrrt.run(size, scenes, planners, runner=Runner(ray=cluster, checkpoint=tmp_path))
    assert (serial["shards"], on_ray["shards"]) == ("serial", "ray")
    for name, sc in serial["scenes"].items():
        got = on_ray["scenes"][name]["planners"]
        for pl in wjrrt.OURS:
            runs = sc["planners"][pl]["runs"] + got[pl]["runs"]
            budget = sc["iterations_budget"]
            assert all(r["success"] or r["iterations"] == budget for r in runs)  # none stopped by the clock
            assert no_times(got[pl]) == no_times(sc["planners"][pl])
            assert [r["seed"] for r in got[pl]["runs"]] == [0, 1, 2]
        ompl = got["RRTConnect"]["runs"]
        assert [r["seed"] for r in ompl] == [0, 1, 2] and any(r["success"] for r in ompl)
        for r in ompl:
            assert r["planner_success"] == r["success"] and r["recheck"] is None  # our checker took every path
    log = tmp_path / "wjrrt" / DONE_LOG
    before = log.read_text()
    pids = {json.loads(x)["pid"] for x in before.splitlines()}
    assert len(before.splitlines()) == 6 and os.getpid() not in pids
    out = tmp_path / "again.json"
    res = CliRunner().invoke(bench_app, ["wjrrt", "--seeds", "3", "--time-limit", "60", "--scenes", ",".join(scenes),
                                         "--planners", ",".join(planners), "--ray", cluster, "--checkpoint",
                                         str(tmp_path), "--no-progress", "--json", str(out)])
    assert res.exit_code == 0, res.output
    again = json.loads(out.read_text())
    assert log.read_text() == before  # nothing computed again
    assert again["scenes"] == json.loads(json.dumps(on_ray["scenes"]))  # times too: read back


DRIVER = f"""
import sys
from pathlib import Path
from armbridge.shards import Runner
from armbridge.smm import dataset
from armbridge.smm.arms import get_smm_arm
from armbridge.smm.grid import GridSpec
job = {SMM_JOB}
dataset.build_dataset(get_smm_arm("planar3r"), job.pop("grid"), runner=Runner(ray=sys.argv[1],
                      checkpoint=Path(sys.argv[2])), **job)
"""


def _wait_for(log: Path, count: int, proc: subprocess.Popen, timeout: float = 60) -> list[dict]:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        lines = log.read_text().splitlines() if log.exists() else []
        if len(lines) >= count:
            return [json.loads(x) for x in lines]
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        time.sleep(0.02)
    raise AssertionError(f"{count} shards not done in {timeout} s")


def test_killed_worker_and_killed_job_resume_from_checkpoints(cluster, serial_smm, tmp_path):
    """A worker killed mid-job: Ray runs its shard again. The job's driver killed after some
    shards: the rerun reads those and computes only the rest; the data set is the serial one."""
    log = tmp_path / "smm-grid" / DONE_LOG
    env = {**os.environ, "PYTHONPATH": str(ROOT / "host")}
    proc = subprocess.Popen([sys.executable, "-c", DRIVER, cluster, str(tmp_path)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = _wait_for(log, 2, proc)
        os.kill(first[0]["pid"], signal.SIGKILL)  # a worker, busy with its next shard
        done = _wait_for(log, 4, proc)
        assert proc.poll() is None, "the job ended before it was killed"
        proc.kill()
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    done = [json.loads(x) for x in log.read_text().splitlines()]
    assert len(done) < 16
    finished = {r["shard"] for r in done}
    files = {i: (tmp_path / "smm-grid" / f"{i:06d}.npz").stat().st_mtime_ns for i in finished}
    got = build(Runner(ray=cluster, checkpoint=tmp_path))
    same_dataset(got, serial_smm)
    after = [json.loads(x) for x in log.read_text().splitlines()]
    redone = [r["shard"] for r in after[len(done):]]
    assert sorted(redone) == sorted(set(range(16)) - finished)  # only the unfinished ones, once each
    assert {i: (tmp_path / "smm-grid" / f"{i:06d}.npz").stat().st_mtime_ns for i in finished} == files


def test_bench_shards_cli_times_one_and_two_workers_with_identical_smms(cluster, tmp_path):
    from typer.testing import CliRunner

    from armbridge.cli import build_app

    out = tmp_path / "shards.json"
    res = CliRunner().invoke(build_app(), ["bench", "shards", "--robot", "planar3r", "--locations", "8", "--shard",
                                           "4", "--workers", "1,2", "--json", str(out)])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    one, two = data["rows"]
    assert (one["backend"], two["backend"]) == ("serial", "ray") and two["identical_to_first"]
    assert data["shards"] == 2 and len(two["shard_seconds"]) == 2 and one["efficiency"] == 1.0
    assert two["efficiency"] == pytest.approx(one["wall_s"] / (2 * two["wall_s"]))
    assert data["projection_paper_7r_grid"] is None  # the projection is the 7R's
