"""Random soft-arm scenes (planning.soft.random_scene) and `bench wjrrt` on scene files and generated specs."""
import json

import numpy as np
import pytest

from armbridge.errors import ArmbridgeError
from armbridge.planning.soft import planners
from armbridge.planning.soft.random_scene import (KINDS, _random_scene, open_scene, parse_spec, random_scene,
                                                  spec_scenes)
from armbridge.planning.soft.scene import load_scene, save_scene, scene_from_dict


@pytest.mark.parametrize("links", [2, 3, 7])
@pytest.mark.parametrize("kind", KINDS)
def test_each_kind_is_a_valid_solvable_scene(links, kind):
    scene = random_scene(links, kind, 1)
    assert scene.name == f"random-{links}-{kind}-1" and scene.robot.n == links
    assert scene.robot.name == {2: "soft2", 3: "soft3", 7: "soft7"}[links]
    again = scene_from_dict(json.loads(json.dumps(scene.to_dict())), "test")  # what a file would give
    chk = again.checker()
    witness = np.array(scene.provenance["witness"])
    assert witness.shape[1] == links and 3 <= witness.shape[0] <= 5
    assert np.array_equal(witness[0], scene.start) and np.array_equal(witness[-1], scene.goal_q)
    assert chk.path_problem(witness) is None  # solvable: the witness passes our checker, every edge
    assert np.linalg.norm(chk.tip(witness[-1]) - scene.goal_point) <= scene.goal_tol
    assert not chk.motion_valid(scene.start, scene.goal_q)  # and not by the straight edge
    assert 0 < scene.provenance["witness_clearance_m"]
    assert 0 < scene.params["d_min"] <= scene.provenance["witness_clearance_m"] / 2 + 1e-4
    sizes = {len(o) for o in scene.obstacles}
    assert (sizes == {2}) if kind != "clutter" else (min(sizes) >= 3 and len(scene.obstacles) >= 2)


@pytest.mark.parametrize("kind", KINDS)
def test_a_planner_solves_three_links(kind):
    """Bi-RRT (no time limit: the result depends on the seed only) finds a path the checker accepts."""
    scene = random_scene(3, kind, 0)
    r = planners.plan(scene, "birrt", seed=0, iterations=5000)
    assert r.path is not None
    assert scene.checker().path_problem(r.path) is None and scene.checker().tip(r.path[-1]) is not None


def test_same_seed_same_scene_other_seed_other_scene():
    first = random_scene(3, "clutter", 4).to_dict()
    _random_scene.cache_clear()
    assert random_scene(3, "clutter", 4).to_dict() == first  # generated again, not the cached one
    assert random_scene(3, "clutter", 5).to_dict()["obstacles"] != first["obstacles"]
    assert random_scene(3, "passage", 4).to_dict()["obstacles"] != first["obstacles"]


def test_round_trip_through_a_scene_file(tmp_path):
    scene = random_scene(7, "passage", 2)
    path = save_scene(scene, tmp_path / "mine.json")
    back = load_scene(str(path))
    assert back.to_dict() == scene.to_dict()
    assert open_scene("random:7:passage:2") is scene  # one generated scene by its spec (plan soft --env)
    assert open_scene(str(path)).to_dict() == scene.to_dict() and open_scene("two-arm").name == "two-arm"
    with pytest.raises(ArmbridgeError, match="one seed"):
        open_scene("random:7:passage:2-3")


def test_specs():
    assert parse_spec("random:3:corridor:7") == [(3, "corridor", 7)]
    assert parse_spec(" random:2:clutter:0-2") == [(2, "clutter", 0), (2, "clutter", 1), (2, "clutter", 2)]
    assert [s.name for s in spec_scenes("random:2:passage:3-4")] == ["random-2-passage-3", "random-2-passage-4"]
    for bad, what in (("random:4:corridor:0", "LINKS"), ("random:3:maze:0", "KIND"), ("random:3:corridor:5-2", "SEEDS"),
                      ("random:3:corridor:x", "SEEDS"), ("random:3:corridor", "random:LINKS:KIND:SEEDS"),
                      ("random:3:corridor:0-99999", "at most")):
        with pytest.raises(ArmbridgeError, match=what) as e:
            parse_spec(bad)
        assert "\n" not in str(e.value) and bad in str(e.value)
    for args in ((4, "corridor", 0), (3, "maze", 0), (3, "corridor", -1), (3.0, "corridor", 0)):
        with pytest.raises(ArmbridgeError, match="random scene"):
            random_scene(*args)


def test_bench_takes_files_specs_and_fixed_names(tmp_path):
    from armbridge.bench import wjrrt, wjrrt_run

    f = save_scene(random_scene(2, "corridor", 0), tmp_path / "corr.json")
    res = wjrrt.run(wjrrt.WjrrtBenchSize(seeds=1, time_limit=60.0),
                    [str(f), "random:2:clutter:0-1", "two-arm", str(f)], ("wjrrt", "birrt"), iterations=300)
    assert list(res["scenes"]) == ["random-2-corridor-0", "random-2-clutter-0", "random-2-clutter-1", "two-arm",
                                   "random-2-corridor-0-2"]  # a repeated name is made unique
    g = res["groups"]["random:2:clutter:0-1"]
    assert g["scenes"] == ["random-2-clutter-0", "random-2-clutter-1"] and g["links"] == 2
    for pl in ("wjrrt", "birrt"):
        s = g["planners"][pl]["summary"]
        assert s["runs"] == 2 and s["success"] == sum(
            res["scenes"][n]["planners"][pl]["summary"]["success"] for n in g["scenes"])
    assert not any("clutter" in k for k in res["targets"])  # the paper's targets: not on generated scenes
    assert any(k.startswith("two-arm") for k in res["targets"])
    assert res["warm_up_s"] >= 0 and {"wjrrt", "birrt"} <= wjrrt_run._WARM
    assert wjrrt_run.warm_up(["wjrrt", "birrt"]) == 0.0  # once per process
    from armbridge.bench.wjrrt_plots import by_group

    assert set(by_group(res)["scenes"]) == {"random-2-corridor-0", "two-arm", "random-2-corridor-0-2",
                                            "random:2:clutter:0-1"}
    for bad in ("random:9:corridor:0", "no-such-scene", str(tmp_path / "missing.json")):
        with pytest.raises(ArmbridgeError, match="random:LINKS|no such scene file|LINKS"):
            wjrrt.run(wjrrt.QUICK, [bad], ("wjrrt",))


def test_cli_takes_a_scene_file_and_a_spec(tmp_path):
    """The bug of issue 24: --scenes FILE was refused as an unknown fixed scene."""
    from typer.testing import CliRunner

    from armbridge.bench.command import bench_app

    f = save_scene(random_scene(3, "passage", 0), tmp_path / "p.json")
    out, kept = tmp_path / "w.json", tmp_path / "kept"
    r = CliRunner().invoke(bench_app, ["wjrrt", "--seeds", "1", "--scenes", f"{f},random:3:corridor:0",
                                       "--planners", "birrt", "--iterations", "300", "--time-limit", "60",
                                       "--save-scenes", str(kept), "--no-progress", "--json", str(out)])
    assert r.exit_code == 0, r.output
    doc = json.loads(out.read_text())
    assert list(doc["scenes"]) == ["random-3-passage-0", "random-3-corridor-0"]
    assert list(doc["groups"]) == ["random:3:corridor:0"] and "generated scenes" in r.output
    assert [p.name for p in kept.iterdir()] == ["random-3-corridor-0.json"]
    assert load_scene(str(kept / "random-3-corridor-0.json")).to_dict() == random_scene(3, "corridor", 0).to_dict()
    bad = CliRunner().invoke(bench_app, ["wjrrt", "--scenes", "random:3:corridor:9-1", "--json", str(out)])
    assert isinstance(bad.exception, ArmbridgeError) and "SEEDS" in str(bad.exception)
