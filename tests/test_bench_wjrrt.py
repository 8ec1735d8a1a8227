"""armbridge bench wjrrt at its smallest (2 seeds, 2 scenes) and the OMPL glue under it (real OMPL, real checker)."""
import json

import numpy as np
import pytest

from armbridge.errors import ArmbridgeError
from armbridge.planning import ompl_bridge
from tests.require import missing

if ompl_bridge.available():
    missing(f"the ompl Python wheel is needed: {ompl_bridge.available()}")

from armbridge.bench import wjrrt, wjrrt_run  # noqa: E402
from armbridge.planning.soft import ompl_planners  # noqa: E402
from armbridge.planning.soft.scene import FORMAT, VERSION, horn_scene, scene_from_dict  # noqa: E402

STAT_KEYS = ("nodes", "track_nodes", "goal_nodes", "random_nodes", "obstacle_checks", "final_H", "tip_error_m")


def small_scene():
    """soft2 reaching over a block that the straight joint-space edge from start to goal.q runs through."""
    doc = {"format": FORMAT, "version": VERSION, "name": "test-two", "robot": "soft2", "link_width": 0.01,
           "obstacles": [[[0.17, 0.09], [0.19, 0.09], [0.19, 0.11], [0.17, 0.11]]],
           "start": [0.0, 0.0], "goal": {"point": [0.0, 0.0], "tol": 0.004, "q": [0.5, 0.9]},
           "params": {"iterations": 300}}
    from armbridge.robots.catalog import get_robot

    doc["goal"]["point"] = get_robot("soft2").ee_point(np.array([0.5, 0.9])).tolist()
    return scene_from_dict(doc, "test")


# The runs' wall-clock budget T, here only a guard against a hang: every run of these small scenes ends
# by success or at its iteration budget in tens of milliseconds, so what the tests compare never depends
# on how fast the machine is (with T = 3 s, a loaded machine once stopped a run by its budget: 4.2 s).
T = 60.0


def ended_by_itself(run: dict, budget: int) -> bool:
    """The run stopped on its own (a path, or its iteration budget), not on the clock."""
    return run["success"] or run["iterations"] == budget


@pytest.fixture(scope="module")
def result():
    return wjrrt.run(wjrrt.WjrrtBenchSize(seeds=2, time_limit=T), [small_scene(), horn_scene(5)])


def test_every_planner_every_column(result):
    doc = json.loads(json.dumps(result))  # what --json writes
    assert set(doc["scenes"]) == {"test-two", "horn-5"}
    ran = set(wjrrt.PLANNERS) - set(doc["not_run"])
    assert {"wjrrt", "jt-rrt", "birrt", "RRTConnect", "KPIECE1"} <= ran
    assert set(doc["not_run"]) == ({"STRIDE"} if ompl_planners.missing("STRIDE") else set())
    for why in doc["not_run"].values():
        assert "STRIDE" in why
    for sc in doc["scenes"].values():
        assert set(sc["planners"]) == ran
        for pl, d in sc["planners"].items():
            s = d["summary"]
            for col in wjrrt.COLUMNS:
                assert col in s
            assert s["runs"] == 2 and 0 <= s["success"] <= 2
            assert list(s["success_at"]) == [f"{t:g}" for t in doc["budgets_s"]]
            assert all(a <= b for a, b in zip(list(s["success_at"].values()), list(s["success_at"].values())[1:]))
            assert s["success_at"][f"{doc['budgets_s'][-1]:g}"] == s["success_rate"]
            for r in d["runs"]:
                for key in STAT_KEYS:
                    assert key in r
                assert r["obstacle_checks"] > 0
                if pl in wjrrt.OMPL:
                    assert r["goal_nodes"] is None and r["final_H"] is None
                    assert s["iterations_budget"] is None
    assert doc["scenes"]["horn-5"]["planners"]["wjrrt"]["summary"]["iterations_budget"] == 1000
    assert isinstance(doc["targets"], dict)


def test_ompl_paths_pass_our_checker(result):
    """Every OMPL path the planner called a solution is accepted again by our checker and ends in the goal."""
    solved = 0
    for sc in result["scenes"].values():
        for pl in set(wjrrt.OMPL) & set(sc["planners"]):  # STRIDE where its shim builds (test_stride.py)
            for r in sc["planners"][pl]["runs"]:
                if r["planner_success"]:
                    solved += 1
                    assert r["recheck"] is None and r["success"]
                    assert r["track_nodes"] >= 1 and r["nodes"] >= r["track_nodes"]
    assert solved >= 1  # horn-5 is easy for RRTConnect (a few tenths of a second)


def test_shard_records_round_trip_and_equal_the_plain_loop(result):
    """A shard's arrays give one_run's records back exactly (keys in order, Python types, None, OMPL's
    status); and the swept records of our planners are one_run's on the same scene and seed, but time_s."""
    from armbridge.bench.wjrrt_shards import decode_runs, encode_runs
    from armbridge.planning.soft.space import EDGE_RES

    scene = small_scene()
    for seed in (0, 1):
        recs = [wjrrt_run.one_run(scene, pl, seed, T, None, EDGE_RES) for pl in ("wjrrt", "birrt", "RRTConnect")]
        back = decode_runs(**encode_runs(recs))
        assert back == recs and [list(r) for r in back] == [list(r) for r in recs]
        assert [[type(v) for v in r.values()] for r in back] == [[type(v) for v in r.values()] for r in recs]
        assert "status" in back[2] and back[0]["recheck"] is None
        for pl, rec in zip(("wjrrt", "birrt"), recs):
            swept = result["scenes"]["test-two"]["planners"][pl]["runs"][seed]
            assert ended_by_itself(swept, 300) and ended_by_itself(rec, 300)  # scene params: 300 iterations
            assert {**swept, "time_s": 0} == {**rec, "time_s": 0}
    with pytest.raises(ValueError, match="FIELDS"):
        encode_runs([{**recs[0], "path_length": 1.0}])
    with pytest.raises(ValueError, match="expected int"):
        encode_runs([{**recs[0], "nodes": np.int64(3)}])


def test_bridge_counts_the_same_checker_and_returns_a_valid_path():
    scene = horn_scene(5)
    problem = scene.problem()
    before = problem.checker.checks
    r = ompl_planners.solve(problem, "RRTConnect", time_limit=T)
    assert r.success and r.stats["obstacle_checks"] == problem.checker.checks - before > 0
    assert np.allclose(r.path[0], scene.start)
    assert problem.goal.is_satisfied(r.path[-1])
    assert np.all(r.path >= problem.space.lower) and np.all(r.path <= problem.space.upper)
    assert scene.checker().path_problem(r.path) is None
    assert r.stats["track_nodes"] == r.path.shape[0] - 1
    capped = ompl_planners.solve(scene.problem(), "KPIECE1", time_limit=10.0, iterations=3)
    assert capped.iterations <= 3


def test_projection_is_the_tip():
    problem = horn_scene(5).problem()
    fn, dim, cells = ompl_planners.tip_projection(problem)
    assert dim == 2 and cells is None
    assert np.allclose(fn(problem.start), problem.checker.tip(problem.start))
    r = ompl_planners.solve(problem, "KPIECE1", time_limit=0.05, projection="random")
    assert r.settings["projection"] == "random"


def test_bad_input_is_one_clear_error():
    with pytest.raises(ArmbridgeError, match="--planners"):
        wjrrt.run(wjrrt.QUICK, [horn_scene(3)], ("wjrrt", "RRT-Connect"))
    with pytest.raises(ArmbridgeError, match="OMPL planner"):
        ompl_bridge.solve(horn_scene(3).problem(), "NoSuchPlanner", time_limit=0.1)
    with pytest.raises(ArmbridgeError, match="projection"):
        ompl_planners.solve(horn_scene(3).problem(), "KPIECE1", projection="elbow")


def test_figures(result, tmp_path):
    from armbridge.bench.wjrrt_plots import plots, success_figure

    fig = success_figure(result)
    for ax in fig.axes:
        gids = {line.get_gid() for line in ax.get_lines()}
        assert {"wjrrt", "RRTConnect", "KPIECE1"} <= gids
        styles = {line.get_gid(): line.get_linestyle() for line in ax.get_lines()}
        assert styles["wjrrt"] == "-" and styles["RRTConnect"] != "-"
    paths = plots(result, tmp_path)
    assert [p.name for p in paths] == ["wjrrt-success.png", "wjrrt-time.png", "wjrrt-clearance.png"]
    assert all(p.stat().st_size > 10_000 for p in paths)


def test_the_clearance_histogram_counts_every_successful_path_above_its_margin(result):
    from armbridge.bench.wjrrt_plots import clearance_excess, clearance_figure

    excess = clearance_excess(result)
    for pl in result["planners"]:
        runs = [(r, sc["margin_m"]) for sc in result["scenes"].values() for r in sc["planners"][pl]["runs"]]
        assert len(excess[pl]) == sum(r["success"] for r, _ in runs) > 0, pl
        assert sorted(excess[pl]) == pytest.approx(sorted(1000 * (r["clearance_min_m"] - m) for r, m in runs
                                                          if r["success"]))
        assert min(excess[pl]) >= 0.0, pl  # every path kept its margin
    labels = [t.get_text() for t in clearance_figure(result).legends[0].get_texts()]
    assert labels == [f"{wjrrt.LABELS[pl]} ({len(excess[pl])} paths)" for pl in result["planners"]]
    old = {**result, "scenes": {n: {k: v for k, v in sc.items() if k != "margin_m"}
                                for n, sc in result["scenes"].items()}}
    assert clearance_excess(old) is None and clearance_figure(old) is None


def test_cli_on_a_shipped_scene(tmp_path):
    from typer.testing import CliRunner

    from armbridge.bench.command import bench_app

    out = tmp_path / "w.json"
    r = CliRunner().invoke(bench_app, ["wjrrt", "--quick", "--seeds", "1", "--scenes", "two-arm",
                                       "--planners", "wjrrt,RRTConnect", "--time-limit", "5", "--json", str(out)])
    assert r.exit_code == 0, r.output
    doc = json.loads(out.read_text())
    assert list(doc["scenes"]) == ["two-arm"] and doc["size"] == {"seeds": 1, "time_limit": 5.0}
    assert set(doc["scenes"]["two-arm"]["planners"]) == {"wjrrt", "RRTConnect"}
    assert doc["scenes"]["two-arm"]["iterations_budget"] == 500  # Table 1's for two arms
    assert "Table 1 columns" in r.output
    ck = tmp_path / "ck"
    args = ["wjrrt", "--seeds", "2", "--scenes", "two-arm", "--planners", "wjrrt,birrt", "--time-limit", "5",
            "--checkpoint", str(ck), "--no-progress", "--json", str(out)]
    assert CliRunner().invoke(bench_app, args).exit_code == 0
    first, log = json.loads(out.read_text()), (ck / "wjrrt" / "done.jsonl").read_text()
    assert len(log.splitlines()) == 2 and first["shards"] == "serial"
    assert CliRunner().invoke(bench_app, args).exit_code == 0  # serially too, a rerun reads the shards back
    assert (ck / "wjrrt" / "done.jsonl").read_text() == log and json.loads(out.read_text())["scenes"] == first["scenes"]
    bad = CliRunner().invoke(bench_app, ["wjrrt", "--scenes", "four-arm", "--json", str(out)])
    assert isinstance(bad.exception, ArmbridgeError) and "four-arm" in str(bad.exception)  # cli.py prints it
