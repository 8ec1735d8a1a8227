"""WJRRT-Connect (planning/soft/connect.py): WJRRT grown from both ends in numba, and bench wjrrt's comparison
with RRTConnect (bench.wjrrt.versus). Paths are re-checked by the certified checker and against the goal."""
from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from armbridge.bench.wjrrt import versus
from armbridge.errors import ArmbridgeError
from armbridge.planning.soft import connect, planners
from armbridge.planning.soft.random_scene import random_scene
from armbridge.planning.soft.scene import fixed_scene, horn_scene

SCENES = ("two-arm", "three-arm", "seven-tube")


def _checked(scene, r):
    """The path starts at the start, every edge is certified free with the margin, the tip ends in the goal."""
    chk = scene.planning_checker()
    assert r.path is not None
    assert np.array_equal(r.path[0], scene.start)
    assert chk.path_problem(r.path) is None
    assert np.linalg.norm(chk.tip(r.path[-1]) - scene.goal_point) <= scene.goal_tol
    assert not np.any(np.all(np.diff(r.path, axis=0) == 0, axis=1)), "a repeated state"
    assert r.cost == pytest.approx(float(np.sum(np.linalg.norm(np.diff(r.path, axis=0), axis=1))))


@pytest.mark.parametrize("name", SCENES)
def test_solves_the_papers_scenes_and_every_path_is_certified(name):
    scene = fixed_scene(name)
    for seed in range(3):
        r = planners.plan(scene, "wjrrt-connect", seed=seed, iterations=200_000)  # seven-tube: up to ~50,000
        _checked(scene, r)
        assert r.stats["track_nodes"] == r.path.shape[0] - 1
        assert r.settings["goal_tree"] is True
        assert r.settings["margin_m"] == scene.planning_margin


def test_same_seed_same_path_and_growing_the_arrays_changes_nothing(monkeypatch):
    scene = random_scene(7, "corridor", 1)
    a = planners.plan(scene, "wjrrt-connect", seed=4, iterations=50000)
    b = planners.plan(scene, "wjrrt-connect", seed=4, iterations=50000)
    _checked(scene, a)
    assert np.array_equal(a.path, b.path) and a.iterations == b.iterations
    monkeypatch.setattr(connect, "CAPACITY", 4)  # FULL on the first iterations: the arrays double many times
    c = planners.plan(scene, "wjrrt-connect", seed=4, iterations=50000)
    assert np.array_equal(a.path, c.path) and a.stats["nodes"] == c.stats["nodes"]
    other = [planners.plan(scene, "wjrrt-connect", seed=s, iterations=50000).path for s in (5, 6)]
    assert any(p is None or p.shape != a.path.shape or not np.array_equal(p, a.path) for p in other)


def test_the_step_fits_the_scene_and_the_scenes_wjrrt_step_does_not_leak():
    scene = fixed_scene("three-arm")  # its params give WJRRT a 0.1 rad step
    r = planners.plan(scene, "wjrrt-connect", seed=0, iterations=20000)
    box = scene.planning_checker().upper - scene.planning_checker().lower
    assert r.settings["step"] == pytest.approx(connect.RANGE_FRACTION * float(np.linalg.norm(box)))
    assert r.settings["p_goal"] == connect.DEFAULTS["p_goal"]
    mine = planners.plan(scene, "wjrrt-connect", seed=0, iterations=20000, step=0.05, p_goal=0.0)
    assert mine.settings["step"] == 0.05 and mine.settings["p_goal"] == 0.0
    _checked(scene, mine)
    steps = np.linalg.norm(np.diff(mine.path, axis=0), axis=1)
    assert steps.max() <= 0.05 + 1e-12


def test_without_goal_configurations_only_the_start_tree_grows():
    scene = fixed_scene("two-arm")
    problem = dataclasses.replace(scene.problem(margin=scene.planning_margin), goal_states=np.zeros((0, 0)))
    r = connect.solve(problem, seed=1, iterations=20000)
    assert r.settings["goal_tree"] is False
    _checked(scene, r)
    assert r.stats["goal_nodes"] + r.stats["random_nodes"] == r.stats["track_nodes"]


def test_the_iteration_budget_is_exact_and_a_failed_run_reports_its_closest_tip():
    scene = horn_scene(5)
    r = planners.plan(scene, "wjrrt-connect", seed=0, iterations=3)
    assert r.path is None and r.iterations == 3 and math.isinf(r.cost)
    assert r.stats["tip_error_m"] > scene.goal_tol


def test_a_stalled_goal_extension_relaxes_the_weights():
    """The horn's goal lies behind its bend: Jacobian steps from the start tree stall, and the weights halve."""
    scene = fixed_scene("horn")
    r = planners.plan(scene, "wjrrt-connect", seed=0, iterations=20000, p_goal=1.0, d_min=0.01, C1=0.05)
    assert r.stats["weight_relax"] < 1.0


@pytest.mark.parametrize("kw, words", [({"bogus": 1}, "unknown parameter 'bogus'"), ({"step": 0.0}, "step = 0.0"),
                                       ({"step": math.inf}, "finite"), ({"p_goal": 1.5}, "outside [0, 1]")])
def test_bad_parameters_are_one_clear_error(kw, words):
    with pytest.raises(ArmbridgeError, match=re.escape(words)):
        planners.plan(fixed_scene("two-arm"), "wjrrt-connect", **kw)


def _result(ours_times, peer_times, clearance=0.01, margin=0.005, T=2.0):
    def runs(ts):
        return [{"seed": i, "success": math.isfinite(t), "time_s": t if math.isfinite(t) else T,
                 "clearance_min_m": clearance if math.isfinite(t) else None} for i, t in enumerate(ts)]

    return {"planners": ["wjrrt-connect", "RRTConnect"], "not_run": {}, "budgets_s": [0.01, 0.05, 0.1, 1.0, 2.0],
            "groups": {}, "scenes": {"s": {"margin_m": margin, "planners": {
                "wjrrt-connect": {"runs": runs(ours_times)}, "RRTConnect": {"runs": runs(peer_times)}}}}}


def test_versus_reads_success_at_every_budget_from_005_s_and_the_median():
    inf = math.inf
    ahead = versus(_result([0.001, 0.002, 0.3, inf], [0.02, 0.2, 0.5, inf]))
    assert ahead["budgets_s"] == [0.05, 0.1, 1.0, 2.0] and ahead["met"]
    assert ahead["parts"]["s"]["success_at"]["wjrrt-connect"] == [0.5, 0.5, 0.75, 0.75]
    assert ahead["parts"]["s"]["success_at"]["RRTConnect"] == [0.25, 0.25, 0.75, 0.75]
    # behind at 0.1 s only: missed, although the median and the end are level or better
    behind = versus(_result([0.001, 0.002, 0.3, 0.4], [0.02, 0.07, 0.08, 0.5]))
    assert not behind["parts"]["s"]["success_met"] and not behind["met"]
    # faster at every budget, but a path that kept less than its margin fails it
    thin = versus(_result([0.001] * 3, [0.5] * 3, clearance=0.004))
    assert thin["clearance_below_margin"] and not thin["met"]
    # a planner that did not run: no comparison
    r = _result([0.001], [0.002])
    r["not_run"] = {"RRTConnect": "no OMPL"}
    assert versus(r) == {}
