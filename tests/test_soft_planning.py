"""The soft arm's planners (WJRRT, JT-RRT, Bi-RRT) and scenes: hand-worked kernels, paths re-checked, bad files."""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Polygon

from armbridge.errors import ArmbridgeError
from armbridge.planning.smoothing import shortcut
from armbridge.planning.soft import planners
from armbridge.planning.soft.jacobian_rrt import objective, weigh
from armbridge.planning.soft.scene import (FIXED, FORMAT, SCENE_DIR, VERSION, fixed_scene, horn_scene, load_scene,
                                           scene_from_dict)
from armbridge.planning.soft.space import EDGE_RES, ChainChecker, jt_step
from armbridge.robots import PlanarChain

PAPER = ("two-arm", "three-arm", "seven-tube")
STATS = ("nodes", "track_nodes", "goal_nodes", "random_nodes", "obstacle_checks", "final_H", "tip_error_m")


def _free_2link(length=0.1):
    return PlanarChain(name="t2", link_lengths=np.full(2, length), q_min=np.full(2, -math.pi),
                       q_max=np.full(2, math.pi), v_max=np.ones(2), joint_names=("a", "b"))


# ------------------------------------------------------------------ the kernels by hand
def test_jacobian_transpose_step_by_hand():
    """q = (0, pi/2), links 0.1: joint 2 at (0.1, 0), tip at (0.1, 0.1).

    J's columns are perp(tip - joint): (-0.1, 0.1) and (-0.1, 0). With dX = (0.003, 0.004) (|dX| = 5 mm < dx):
    J^T dX = (1e-4, -3e-4); J J^T dX = (2e-5, 1e-5); rho = <dX, JJ^T dX> / |JJ^T dX|^2 = 1e-7 / 5e-10 = 200;
    dq = (0.02, -0.06); the linearised tip step rho JJ^T dX = (4, 2) mm, shorter than dX.
    """
    chk = ChainChecker.create(_free_2link(), [])
    q = np.array([0.0, math.pi / 2])
    pts, J, out = np.empty((3, 2)), np.empty((2, 2)), np.empty(2)
    d = jt_step(q, np.array([0.103, 0.104]), 0.01, chk.lengths, chk.base, chk.lower, chk.upper, pts, J, out)
    assert d == pytest.approx(0.005)
    assert J == pytest.approx(np.array([[-0.1, -0.1], [0.1, 0.0]]))
    assert out == pytest.approx([0.02, math.pi / 2 - 0.06])
    # The same goal 10x farther: dX is cut to dx = 0.01 along the same direction, so dq is 0.01 / 0.005 = 2x.
    d = jt_step(q, np.array([0.13, 0.14]), 0.01, chk.lengths, chk.base, chk.lower, chk.upper, pts, J, out)
    assert d == pytest.approx(0.05)
    assert out == pytest.approx([0.04, math.pi / 2 - 0.12])
    # Joint limits clip the step.
    tight = ChainChecker(chk.lengths, chk.base, np.array([-0.01, 0.0]), np.array([0.01, math.pi / 2]), (), 0.0,
                         EDGE_RES)
    jt_step(q, np.array([0.13, 0.14]), 0.01, tight.lengths, tight.base, tight.lower, tight.upper, pts, J, out)
    assert out == pytest.approx([0.01, math.pi / 2 - 0.12])


def test_weights_and_objective_against_shapely():
    """W_s (eq. 20), W_d (eq. 21) and H (eq. 9-10) of a hand-made configuration, distances by shapely."""
    box = np.array([[0.12, 0.02], [0.16, 0.02], [0.16, 0.06], [0.12, 0.06]])
    wall = np.array([[0.0, 0.15], [0.2, 0.15]])
    width = 0.01
    chk = ChainChecker.create(_free_2link(), [box, wall], link_width=width)
    qc, qn = np.array([0.2, 0.95]), np.array([0.25, 0.9])
    goal = np.array([0.15, 0.1])
    pts, cl = np.empty((3, 2)), np.empty(2)
    d, least, ws, wd, length = weigh(qc, qn, goal, chk.lengths, chk.base, chk.verts, chk.starts, chk.half_width, pts, cl)
    P = chk.points(qn)
    links = [LineString(P[i:i + 2]) for i in range(2)]
    dist = [min(link.distance(Polygon(box)), link.distance(LineString(wall))) - width / 2 for link in links]
    assert min(dist) > 0  # a free configuration: both links clear of both obstacles
    assert cl == pytest.approx(dist, abs=1e-12)
    assert ws == pytest.approx(sum(dist), abs=1e-12) and least == pytest.approx(min(dist), abs=1e-12)
    assert wd == pytest.approx(0.05 + 0.05) and length == pytest.approx(math.hypot(0.05, 0.05))
    assert d == pytest.approx(float(np.linalg.norm(goal - P[-1])))
    lam = 1e-5
    assert objective(d, least, lam) == pytest.approx(d ** 2 + lam / min(dist))
    assert objective(d, 0.0, lam) == math.inf and objective(d, 0.0, 0.0) == pytest.approx(d ** 2)


# ------------------------------------------------------------------ plans
@pytest.fixture(scope="module")
def plans():
    """Every planner on the two paper scenes with few links, seeds 0 and 1 (module scope: planned once)."""
    out = {}
    for name in ("two-arm", "three-arm"):
        for planner in planners.PLANNERS:
            for seed in (0, 1):
                out[name, planner, seed] = planners.plan(fixed_scene(name), planner, seed=seed)
    return out


def _dense_collision(scene, path, step):
    """The first (edge, problem) where shapely sees a link within half the width of an obstacle, or two
    non-adjacent links within the width, on shapes interpolated so that no joint turns more than `step`."""
    obstacles = [Polygon(p) if len(p) > 2 else LineString(p) for p in scene.obstacles]
    chk = scene.checker()
    w = scene.link_width
    for k in range(len(path) - 1):
        m = max(1, int(math.ceil(np.max(np.abs(path[k + 1] - path[k])) / step)))
        for t in np.linspace(0.0, 1.0, m + 1):
            P = chk.points(path[k] + t * (path[k + 1] - path[k]))
            links = shapely.linestrings(np.stack([P[:-1], P[1:]], axis=1))
            for o in obstacles:
                if np.any(shapely.distance(links, o) <= w / 2):
                    return k, "obstacle"
            for a in range(len(links) - 2):
                if np.any(shapely.distance(links[a], links[a + 2:]) <= w):
                    return k, "self"
    return None


def test_every_path_is_collision_free_at_a_finer_resolution(plans):
    for (name, planner, seed), r in plans.items():
        scene = fixed_scene(name)
        assert r.success, (name, planner, seed)
        assert np.array_equal(r.path[0], scene.start)
        assert np.linalg.norm(scene.checker().tip(r.path[-1]) - scene.goal_point) <= scene.goal_tol
        assert scene.checker(res=EDGE_RES / 10).path_problem(r.path) is None, (name, planner, seed)
        assert _dense_collision(scene, r.path, step=5e-4) is None, (name, planner, seed)


def test_stats_are_table_1s_columns(plans):
    for (name, planner, seed), r in plans.items():
        assert set(STATS) <= set(r.stats), planner
        assert r.stats["track_nodes"] == r.path.shape[0] - 1
        assert r.collision_checks == r.stats["obstacle_checks"] > 0
        assert r.stats["tip_error_m"] <= fixed_scene(name).goal_tol
        if planner == "birrt":
            assert r.stats["goal_nodes"] is None and r.stats["final_H"] is None
            assert r.tree_size == r.stats["nodes"] > r.stats["track_nodes"]
        else:
            assert r.stats["goal_nodes"] + r.stats["random_nodes"] == r.stats["track_nodes"]
            assert r.tree_size == r.stats["nodes"]
            assert r.stats["goal_nodes"] > 0 or planner == "wjrrt-connect"  # its random steps may get there alone
            assert (r.stats["final_H"] is None) == (planner == "jt-rrt")


def test_wjrrt_nodes_keep_the_thresholds(plans):
    """Every WJRRT path node but the start passes eq. (7)'s per-link test, W_s > C1 and W_d < C2; H is eq. 9."""
    for name in ("two-arm", "three-arm"):
        scene, r = fixed_scene(name), plans[name, "wjrrt", 0]
        p, chk = scene.params, scene.checker()
        for a, b in zip(r.path[:-1], r.path[1:]):
            cl = chk.link_clearance(b)
            assert cl.min() > p["d_min"] and cl.sum() > p["C1"] and np.abs(b - a).sum() < p["C2"]
        tip_err = float(np.linalg.norm(chk.tip(r.path[-1]) - scene.goal_point))
        assert r.stats["final_H"] == pytest.approx(tip_err ** 2 + p["lambda"] / chk.clearance(r.path[-1]))


def test_same_seed_same_plan():
    scene = fixed_scene("three-arm")
    for planner in planners.PLANNERS:
        a, b = planners.plan(scene, planner, seed=7), planners.plan(scene, planner, seed=7)
        assert np.array_equal(a.path, b.path) and a.stats == b.stats and a.iterations == b.iterations
        assert not np.array_equal(a.path, planners.plan(scene, planner, seed=8).path)


def test_jt_rrt_is_wjrrt_with_the_weighting_off():
    """Neutral thresholds (C1 = 0, C2 = inf, d_min = 0, lambda = 0) make WJRRT the JT-RRT plan, step for step."""
    scene = fixed_scene("three-arm")
    jt = planners.plan(scene, "jt-rrt", seed=3)
    wj = planners.plan(scene, "wjrrt", seed=3, C1=0.0, C2=math.inf, d_min=0.0, **{"lambda": 0.0})
    assert np.array_equal(jt.path, wj.path) and jt.stats["nodes"] == wj.stats["nodes"]
    with pytest.raises(ArmbridgeError, match="jt-rrt: unknown parameter 'C1'"):
        planners.plan(scene, "jt-rrt", C1=0.1)


def test_tree_kinds_label_goal_and_random_steps(plans):
    r = plans["two-arm", "wjrrt", 0]
    assert r.stats["goal_nodes"] >= 1 and r.stats["random_nodes"] >= 1  # the post forces a random detour


@pytest.mark.parametrize("name", PAPER)
def test_the_paper_scenes_need_obstacle_avoidance(name):
    """A pure Jacobian-transpose descent (JT-RRT, P_G = 1, k = 0) fails; without the obstacles it arrives."""
    scene = fixed_scene(name)
    assert not planners.plan(scene, "jt-rrt", seed=0, iterations=200, p_goal=1.0, k=0.0).success
    free = dataclasses.replace(scene, obstacles=[], goal_states=None)
    assert planners.plan(free, "jt-rrt", seed=0, iterations=5, p_goal=1.0, k=0.0).success


@pytest.mark.parametrize("name", FIXED)
def test_each_fixed_scene_is_solved_by_wjrrt_at_seed_0(name):
    scene = fixed_scene(name)
    r = planners.plan(scene, "wjrrt", seed=0)
    assert r.success and scene.checker().path_problem(r.path) is None
    assert r.iterations <= scene.params["iterations"]


def test_birrt_joins_the_trees_at_a_goal_configuration():
    scene = fixed_scene("seven-tube")
    # the trees' mechanics, without the clearance margin (soft7's 13.4 mm leaves Bi-RRT little room in the
    # tube; the margin is tested in test_soft_clearance.py)
    r = planners.plan(scene, "birrt", seed=0, margin=0.0)
    assert r.success and scene.checker(res=EDGE_RES / 10).path_problem(r.path) is None
    roots = scene.find_goal_states(scene.checker())  # those of the touch check (margin 0)
    assert np.min(np.linalg.norm(roots - r.path[-1], axis=1)) == 0.0  # it ends on a goal tree's root


def test_shortcut_smoothing_keeps_the_path_valid_and_shorter(plans):
    scene = fixed_scene("three-arm")
    raw = plans["three-arm", "wjrrt", 0].path
    smooth = planners.plan(scene, "wjrrt", seed=0, smooth=True)
    assert np.array_equal(smooth.path[0], raw[0]) and np.array_equal(smooth.path[-1], raw[-1])
    assert smooth.path.shape[0] < raw.shape[0]
    assert smooth.cost <= float(np.sum(np.linalg.norm(np.diff(raw, axis=0), axis=1)))
    wide = scene.checker(link_width=scene.link_width + 2 * scene.params["d_min"])
    index = {tuple(q): i for i, q in enumerate(raw)}
    shortcuts = [(a, b) for a, b in zip(smooth.path[:-1], smooth.path[1:]) if index[tuple(b)] - index[tuple(a)] > 1]
    assert shortcuts and all(wide.motion_valid(a, b) for a, b in shortcuts)  # they keep WJRRT's clearance
    again = shortcut(raw, scene.checker(), np.random.default_rng([0, 1]))
    assert scene.checker().path_problem(again) is None


# ------------------------------------------------------------------ OMPL's horn
def test_horn_walls_are_ompls_formula_for_3_links():
    """createHornEnvironment(3, log(3)/3): w = 1/3, eps = ln 3 / 3, walls turn by 60 degrees per segment;
    the lower one from (w, -eps) with segments w (1 + pi eps), the upper from (w, eps) with w (1 - pi eps)."""
    w, eps = 1 / 3, math.log(3) / 3
    lo, up = w * (1 + math.pi * eps), w * (1 - math.pi * eps)
    c60, s60 = 0.5, math.sqrt(3) / 2
    a0, b0 = (w, -eps), (w, eps)
    a1 = (a0[0] + c60 * lo, a0[1] + s60 * lo)
    a2 = (a1[0] - c60 * lo, a1[1] + s60 * lo)
    b1 = (b0[0] + c60 * up, b0[1] + s60 * up)
    b2 = (b1[0] - c60 * up, b1[1] + s60 * up)
    want = [[a0, a1], [a1, a2], [b0, b1], [b1, b2]]
    scene = horn_scene(3)
    assert len(scene.obstacles) == 4
    for got, exp in zip(scene.obstacles, want):
        assert got == pytest.approx(np.array(exp), abs=1e-12)
    assert a1 == pytest.approx((0.691744, 0.254581), abs=1e-6)  # worked out once on paper
    assert scene.start == pytest.approx([0.0, math.pi / 3, math.pi / 3])
    assert scene.goal_q == pytest.approx([math.pi - 0.001, 0.0, 0.0])
    assert scene.link_width == 0.0 and scene.robot.link_lengths == pytest.approx([w] * 3)


def test_the_shipped_horn_is_horn_scene_7():
    shipped, made = fixed_scene("horn"), horn_scene(7, fixed_scene("horn").params)
    assert shipped.to_dict() == made.to_dict()


# ------------------------------------------------------------------ bad files
def _doc(**change):
    doc = json.loads((SCENE_DIR / "three-arm.json").read_text())
    for key, v in change.items():
        doc[key] = v
    return doc


def _err(tmp_path, doc):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ArmbridgeError) as e:
        load_scene(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg
    return msg[len(str(path)) + 2:]


def test_bad_scene_files_name_the_field(tmp_path):
    d = _doc()
    assert _err(tmp_path, {**d, "colour": "red"}).startswith('unknown field "colour" (allowed: format, version')
    assert _err(tmp_path, _doc(start=[0.0, 0.1])) == "start must have 3 values, got 2"
    assert _err(tmp_path, _doc(base=[0, 0])) == "base ([x, y, heading] in m, m, rad) must have 3 values, got 2"
    bow = [[0.0, 0.2], [0.05, 0.25], [0.05, 0.2], [0.0, 0.25]]
    assert _err(tmp_path, _doc(obstacles=[bow])).startswith("obstacles[0] is self-intersecting")
    assert _err(tmp_path, _doc(obstacles=[[[0, 0], [0, 0]]])).startswith("obstacles[0] is a wall of zero length")
    assert _err(tmp_path, _doc(start=[0.0, 1.2, 0.0])) == (
        "start[1] = 1.2 rad is outside joint2's range [0, 0.9599] rad (0 to 55 deg)")
    assert _err(tmp_path, _doc(start=[0.1, 0.0, 0.0], obstacles=[[[0.28, 0.27], [0.32, 0.27], [0.3, 0.31]]])) == (
        "start is in collision: link 1 hits obstacle 0 (obstacles[] counts from 0; link width 0.015 m)")
    assert _err(tmp_path, _doc(goal={"point": [0.2, 0.065], "tol": -0.001})) == (
        "goal.tol = -0.001 m is outside (0, 0.3] (the robot's reach)")
    assert _err(tmp_path, _doc(goal={"point": [-0.2, 0.3], "tol": 0.002})) == (
        "goal.point (-0.2, 0.3) is out of reach: 0.55 m from the base, the arm reaches 0.3 m")
    # q = 0 puts the tip at (0.05, 0.30): |(0.15, -0.235)| = 0.2788 m from the goal.
    assert _err(tmp_path, _doc(goal={"point": [0.2, 0.065], "tol": 0.002, "q": [0.0, 0.0, 0.0]})) == (
        "goal.q puts the tip 0.2788 m from goal.point, outside goal.tol = 0.002 m")
    assert _err(tmp_path, _doc(goal={"point": [0.2, 0.065], "tol": 0.002, "where": 1})) == (
        'goal: unknown field "where" (allowed: point, tol, q)')
    assert _err(tmp_path, _doc(params={"p_goal": 1.5})) == "params.p_goal = 1.5 is outside [0.0, 1.0]"
    assert _err(tmp_path, _doc(params={"C1": -0.01})) == "params.C1 = -0.01 is outside [0.0, inf]"
    assert _err(tmp_path, _doc(params={"iterations": 10.5})) == "params.iterations must be a whole number, got 10.5"
    assert _err(tmp_path, _doc(params={"rho": 1})).startswith('params: unknown field "rho" (allowed: iterations,')
    assert _err(tmp_path, _doc(link_width=-0.01)) == "link_width = -0.01 m is outside [0, inf)"
    assert _err(tmp_path, _doc(robot="masr5")) == "robot: 'masr5' is a masr robot; a chain scene needs a planar chain"
    assert _err(tmp_path, _doc(format="armbridge-masr-env")) == (
        'format is "armbridge-masr-env", expected "armbridge-chain-env"')


def test_a_goal_the_arm_cannot_reach_inside_its_limits(tmp_path):
    """Within the 0.3 m reach but not within soft3's one-way joints (behind the mount): the descent says so."""
    msg = _err(tmp_path, _doc(goal={"point": [0.35, 0.1], "tol": 0.002}, obstacles=[]))
    assert msg.startswith("goal.point (0.35, 0.1): the tip descent from 64 random starts found no collision-free "
                          "configuration within goal.tol = 0.002 m")
    assert msg.endswith("if the goal is reachable, give one as goal.q")


def test_scenes_round_trip_and_missing_files(tmp_path):
    from armbridge.planning.soft.scene import save_scene

    for name in FIXED:
        scene = fixed_scene(name)
        again = load_scene(save_scene(scene, tmp_path / f"{name}.json"))
        assert again.to_dict() == scene.to_dict()
    with pytest.raises(ArmbridgeError, match="no such scene file"):
        load_scene(tmp_path / "none.json")
    with pytest.raises(ArmbridgeError, match="unknown fixed scene 'four-arm'"):
        fixed_scene("four-arm")
    assert scene_from_dict(_doc()).name == "three-arm" and (FORMAT, VERSION) == ("armbridge-chain-env", 1)


@pytest.mark.parametrize("name,seed", [("three-arm", 0), ("three-arm", 2), ("two-arm", 1)])
def test_the_plan_ends_on_the_goal_point_not_on_the_goal_discs_rim(name, seed):
    """WJRRT stops at the first state inside the goal disc, about its rim (1.95 of
    2 mm on three-arm seed 0); ik.onto_goal adds one short, checked state on the
    point, so the last pump waypoint the board is sent is within tol / 4."""
    from armbridge.planning.soft.command import plan_for_pump

    sp = plan_for_pump(name, seed=seed)
    scene, ch = sp.scene, sp.scene.checker()
    path = sp.result.path
    assert np.linalg.norm(ch.tip(path[-1]) - scene.goal_point) <= scene.goal_tol / 4
    assert ch.motion_valid(path[-2], path[-1]) and ch.is_valid(path[-1])
    assert sp.summary()["tip_error_m"] <= scene.goal_tol / 4
    assert sp.summary()["planner_tip_error_m"] <= scene.goal_tol


def test_onto_goal_leaves_a_path_whose_goal_state_is_blocked():
    """When the state on the goal point (or the edge to it) is not free, the path stays as it is."""
    from armbridge.planning.soft.ik import onto_goal

    scene = fixed_scene("three-arm")
    ch = scene.checker()
    path = planners.plan(scene, "wjrrt", seed=0).path
    assert len(onto_goal(path, ch, scene.goal_point, scene.goal_tol)) == len(path) + 1
    blocked = dataclasses.replace(scene, obstacles=scene.obstacles + [
        np.array([scene.goal_point + [-0.004, -0.004], scene.goal_point + [0.004, -0.004],
                  scene.goal_point + [0.004, 0.004], scene.goal_point + [-0.004, 0.004]])])
    assert onto_goal(path, blocked.checker(), scene.goal_point, scene.goal_tol) is path
