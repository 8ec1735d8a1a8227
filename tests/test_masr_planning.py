"""MASR planning (masr paper, section IV): environments, collision checking, MASR-RRT* vs RRT*, plan files, CLI."""
import json

import numpy as np
import pytest
from require import missing
import shapely
from shapely.geometry import LineString, Polygon

from armbridge.errors import ArmbridgeError
from armbridge.ik import masr_dls as dls_ik
from armbridge.planning.masr import rrt_star
from armbridge.planning.masr.collision import CollisionChecker, rotation_order
from armbridge.planning.command import plan_app, resolve_goal_ik, shipped_ik_card
from armbridge.planning.masr.environment import (
    FIXED,
    environment_from_dict,
    fixed_environment,
    load_environment,
    save_environment,
)
from armbridge.planning.masr.plan_file import load_masr_plan, masr_plan_document, plan_from_document, save_masr_plan
from armbridge.planning.masr.random_env import random_environment
from armbridge.robots import MASR5

ARM = MASR5
R = 0.5 * ARM.link_width


def rand_q(rng, count):
    tb = ARM.theta_b
    return np.concatenate([rng.uniform(-tb, tb, (count, ARM.n)), rng.uniform(0, ARM.total_length, (count, 1))], 1)


def star(rng, center, radius, k):
    ang = np.sort(rng.uniform(0, 2 * np.pi, k))
    rad = radius * rng.uniform(0.5, 1.0, k)
    return np.asarray(center) + np.stack([rad * np.cos(ang), rad * np.sin(ang)], 1)


def shapely_hits(q, polygons, r=R):
    """Reference: any link segment within r of any polygon (shapely distance)."""
    pts = ARM.joint_points(q)
    polys = [Polygon(p) for p in polygons]
    return any(LineString(pts[k:k + 2]).distance(P) <= r for k in range(ARM.n) for P in polys)


def convention_free_shapely(qa, qb, polygons):
    """Reference CollisionFree: every configuration after a step of MasrArm.action_sequence, by shapely."""
    return not any(shapely_hits(q, polygons) for q in ARM.intermediate_configs(qa, qb))


def env_doc(**over):
    doc = {"format": "armbridge-masr-env", "version": 1, "name": "t", "robot": "masr5",
           "obstacles": [[[0.3, 0.3], [0.45, 0.3], [0.45, 0.45], [0.3, 0.45]]],
           "start": [0, 0, 0, 0, 0, 0.1], "goal": {"pose": [0.6, -0.2, -0.4]}}
    doc.update(over)
    return doc


@pytest.fixture(scope="module")
def dls():
    return dls_ik.goal_ik(ARM)


@pytest.fixture(scope="module")
def goal_ik():
    """The shipped IK-NN (models/onnx)."""
    return resolve_goal_ik(fixed_environment("E1"), "auto")[0]


# ------------------------------------------------------------------ collision
def test_collision_checker_matches_shapely():
    rng = np.random.default_rng(0)
    polygons = [star(rng, c, 0.09, k) for c, k in (((0.4, 0.2), 5), ((0.25, -0.35), 3), ((0.55, -0.1), 7),
                                                     ((0.1, 0.45), 4))]
    chk = CollisionChecker.create(ARM, polygons)
    Q = rand_q(rng, 1500)
    ours = chk.hits(Q) >= 0
    segs = ARM.joint_points(Q)
    lines = shapely.linestrings(segs[:, np.repeat(np.arange(ARM.n), 2) + np.tile([0, 1], ARM.n)]
                                .reshape(len(Q), ARM.n, 2, 2).reshape(-1, 2, 2))
    dist = np.min(np.stack([shapely.distance(lines, Polygon(p)) for p in polygons]), axis=0).reshape(len(Q), ARM.n)
    dmin = dist.min(axis=1)
    clear = np.abs(dmin - R) > 1e-9  # leave out exact ties
    assert np.array_equal(ours[clear], dmin[clear] <= R)
    assert 0.2 < ours.mean() < 0.8  # both outcomes well represented
    # the code names the polygon and the link: check it against shapely for one hit
    i = int(np.flatnonzero(ours)[0])
    p, link = chk.first_hit(Q[i])
    assert LineString(segs[i, link:link + 2]).distance(Polygon(polygons[p])) <= R + 1e-12


def test_collision_inside_polygon_and_margin():
    square = [[0.25, -0.05], [0.35, -0.05], [0.35, 0.05], [0.25, 0.05]]
    chk = CollisionChecker.create(ARM, [square])
    straight = np.zeros(6)
    assert chk.first_hit(straight) == (0, 1)  # link 2 passes through the square
    chk_far = CollisionChecker.create(ARM, [[[0.2, R + 1e-4], [0.3, 0.1], [0.2, 0.1]]])
    assert chk_far.first_hit(straight) is None
    chk_near = CollisionChecker.create(ARM, [[[0.2, R - 1e-4], [0.3, 0.1], [0.2, 0.1]]])
    assert chk_near.first_hit(straight) is not None  # within the inflated margin, not in the polygon
    # a polygon containing a whole link
    chk_in = CollisionChecker.create(ARM, [[[-0.1, -0.1], [0.9, -0.1], [0.9, 0.1], [-0.1, 0.1]]])
    assert chk_in.first_hit(straight) == (0, 0)


def test_rotation_order_and_edge_check_follow_the_convention():
    rng = np.random.default_rng(1)
    polygons = [star(rng, (0.45, 0.25), 0.1, 6), star(rng, (0.3, -0.3), 0.1, 5)]
    chk = CollisionChecker.create(ARM, polygons, sweep_res=0.0)  # the paper's check: after each rotation
    A = rand_q(rng, 300)
    B = A + rng.normal(0, 0.3, A.shape) * (rng.random(A.shape) < 0.6)
    B[:, :-1] = np.clip(B[:, :-1], -ARM.theta_b, ARM.theta_b)
    B[:, -1] = np.clip(B[:, -1], 0, ARM.total_length)
    B[::7, -1] = ARM.r[rng.integers(0, ARM.n, len(B[::7]))]  # MA ending on joints
    A[::5, -1] = ARM.r[rng.integers(0, ARM.n, len(A[::5]))]  # MA starting on joints
    free_a = chk.free(A)
    agree = 0
    for qa, qb in zip(A[free_a], B[free_a]):
        order = np.empty(ARM.n, dtype=np.int64)
        m = rotation_order(qa, qb, chk.rj, order)
        seq = [s[1] - 1 for s in ARM.action_sequence(qa, qb) if s[0] == "rotate"]
        assert list(order[:m]) == seq
        ours = chk.edge_free(qa, qb)
        assert ours == convention_free_shapely(qa, qb, polygons)
        agree += 1
    assert agree > 50
    # sub-stepped sweeps only ever add collisions
    swept = CollisionChecker.create(ARM, polygons, sweep_res=0.005)
    for qa, qb in zip(A[free_a][:80], B[free_a][:80]):
        if swept.edge_free(qa, qb):
            assert chk.edge_free(qa, qb)


def test_cost_kernel_is_eq8():
    rng = np.random.default_rng(2)
    A, B = rand_q(rng, 500), rand_q(rng, 500)
    B[::3, :2] = A[::3, :2]  # unactuated joints
    A[::4, -1] = ARM.r[rng.integers(0, ARM.n, len(A[::4]))]
    rj = np.ascontiguousarray(ARM.r)
    ours = np.array([rrt_star.action_cost(a, b, rj, 1 / ARM.ma_speed, 1 / ARM.joint_speed) for a, b in zip(A, B)])
    np.testing.assert_allclose(ours, ARM.action_cost(A, B), rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------------ planner
def _assert_goal_holds_margin(env, q_goal, k=41):
    """A planned goal: d at least d_margin from every joint, and the MA within (e_p, e_phi) of the goal
    for every d in [d - m, d + m] (a dense sweep of fk, independent of span_pose_errors)."""
    m = ARM.d_margin
    assert ARM.joint_clearance(q_goal[-1]) >= m - 1e-12
    qs = np.tile(q_goal, (k, 1))
    qs[:, -1] = np.clip(q_goal[-1] + np.linspace(-m, m, k), 0, ARM.total_length)
    dp, dphi = env.pose_errors(qs)
    assert np.all(dp <= env.e_p) and np.all(dphi <= env.e_phi)
    assert len(set(ARM.locate(qs[:, -1])[0].tolist())) == 1  # the interval stays on one link


@pytest.fixture(scope="module")
def e1_result(goal_ik):
    env = fixed_environment("E1")
    return env, rrt_star.plan(env, planner="masr-rrt*", iterations=1000, goal_ik=goal_ik, seed=0)


def test_planner_finds_a_valid_path(e1_result):
    env, res = e1_result
    assert res.success, res.summary()
    P = res.path
    np.testing.assert_array_equal(P[0], env.start)
    assert env.in_goal(P[-1])  # eq. (9) for every d within the joint margin
    _assert_goal_holds_margin(env, P[-1])
    assert np.all(ARM.within_limits(P))
    chk = env.checker()
    assert chk.path_problem(P) is None
    for qa, qb in zip(P[:-1], P[1:]):
        assert chk.edge_free(qa, qb)
        assert convention_free_shapely(qa, qb, env.obstacles)  # independent check along the convention
    # the cost of the returned path is eq. (7), and the tree agreed
    assert res.cost == pytest.approx(float(ARM.path_time(P)), rel=1e-12)
    assert res.best_costs[-1] == pytest.approx(res.cost, rel=1e-9)
    # best cost never increases once found
    bc = res.best_costs[np.isfinite(res.best_costs)]
    assert np.all(np.diff(bc) <= 1e-9)


def test_planner_is_deterministic_and_prefix_consistent(goal_ik):
    env = fixed_environment("E3")
    a = rrt_star.plan(env, iterations=400, goal_ik=goal_ik, seed=3)
    b = rrt_star.plan(env, iterations=400, goal_ik=goal_ik, seed=3)
    c = rrt_star.plan(env, iterations=200, goal_ik=goal_ik, seed=3)
    np.testing.assert_array_equal(a.best_costs, b.best_costs)
    np.testing.assert_array_equal(a.best_costs[:200], c.best_costs)  # same random streams for any N_c


def test_baseline_needs_no_ik_and_masr_needs_one():
    env = fixed_environment("E1")
    res = rrt_star.plan(env, planner="rrt*", iterations=300, seed=0)
    assert res.ik_calls == 0 and res.settings["goal_bias"] == 0.1
    with pytest.raises(ArmbridgeError, match="needs a goal IK"):
        rrt_star.plan(env, planner="masr-rrt*", iterations=10)
    with pytest.raises(ArmbridgeError, match="unknown planner"):
        rrt_star.plan(env, planner="prm", iterations=10)


def test_masr_rrt_star_at_least_as_good_as_baseline(goal_ik):
    """A small statistical check on fixed seeds: E1-E3 and two random V-C environments."""
    envs = [fixed_environment(n) for n in FIXED] + [random_environment(ARM, seed=s) for s in (1, 2)]
    its = 1000
    cps = (250, 500, 1000)
    score = {"masr-rrt*": [], "rrt*": []}
    for env in envs:
        for seed in range(3):
            for pl in score:
                r = rrt_star.plan(env, planner=pl, iterations=its, goal_ik=goal_ik if pl == "masr-rrt*" else None,
                                  seed=seed)
                score[pl].append(r.best_costs[[c - 1 for c in cps]])
    m, b = np.array(score["masr-rrt*"]), np.array(score["rrt*"])
    for k, c in enumerate(cps):
        assert np.isfinite(m[:, k]).sum() >= np.isfinite(b[:, k]).sum(), c
        both = np.isfinite(m[:, k]) & np.isfinite(b[:, k])
        assert both.sum() >= 4
        assert np.mean(m[both, k]) <= np.mean(b[both, k]), c


# ------------------------------------------------------------------ environments
def test_fixed_environments_load_and_have_goal_configurations():
    for name in FIXED:
        env = fixed_environment(name)
        assert env.name == name and len(env.obstacles) >= 2
        assert env.in_goal(env.goal_q) and env.checker().free(env.goal_q)
        assert env.checker().free(env.start)
    e3 = fixed_environment("E3")
    assert "opening" in e3.description
    # E3's goal is inside the pocket: the straight-line move from the start is blocked
    assert not e3.checker().edge_free(e3.start, e3.goal_q)


def test_environment_json_round_trip(tmp_path):
    for env in (fixed_environment("E3"), random_environment(ARM, seed=5)):
        p = save_environment(env, tmp_path / f"{env.name}.json")
        back = load_environment(p)
        assert back == env
        assert back.to_dict() == json.loads(p.read_text())
        if env.known_path is not None:
            np.testing.assert_array_equal(back.known_path, env.known_path)


def test_random_environment_follows_section_VC():
    env = random_environment(ARM, seed=7)
    assert 1 <= len(env.obstacles) <= 4
    assert env.provenance["coverage"] <= 0.30
    P = env.known_path  # the known solution
    np.testing.assert_array_equal(P[0], env.start)
    assert env.in_goal(P[-1]) and env.checker().path_problem(P) is None
    again = random_environment(ARM, seed=7)
    assert again == env


@pytest.mark.parametrize("doc, message", [
    (env_doc(obstacles=[[[0.3, 0.3], [0.5, 0.5], [0.5, 0.3], [0.3, 0.5]]]),
     r"obstacles\[0\] is self-intersecting at \(0.4, 0.4\)"),
    (env_doc(obstacles=[[[0.3, 0.3], [0.5, 0.3]]]), r"obstacles\[0\] must be a list of at least 3"),
    (env_doc(goal={"pose": [0.9, 0.2, 0.0]}), r"goal pose \(0.9, 0.2, 0\) is out of reach: 0.922 m from the base"),
    (env_doc(goal={"pose": [-0.3, 0.0, 0.0]}), r"is out of reach: no configuration within the joint limits"),
    (env_doc(start=[0, 0, 0, 0, 0, 0.1], obstacles=[[[0.5, -0.05], [0.6, -0.05], [0.6, 0.05], [0.5, 0.05]]]),
     r"start configuration is in collision: link 3 is within 0.015 m .* of obstacles\[0\]"),
    (env_doc(start=[0, 1.2, 0, 0, 0, 0.1]), r"start configuration is infeasible: theta_2 = 1.2 rad is outside"),
    (env_doc(start=[0, 0, 0, 0, 0, 0.9]), r"d = 0.9 m is off the arm"),
    (env_doc(goal={"pose": [0.6, -0.2, -0.4], "q": [0, 0, 0, 0, 0, 0.5]}), r"goal.q puts the MA .* outside e_p"),
    (env_doc(colour="red"), r'unknown field "colour"'),
    (env_doc(version=2), r"unsupported version 2"),
])
def test_bad_environments_are_refused(doc, message):
    with pytest.raises(ArmbridgeError, match=message):
        environment_from_dict(doc, "bad.json")


def test_goal_blocked_by_an_obstacle():
    doc = env_doc(goal={"pose": [0.375, 0.375, 0.5]})  # inside the square obstacle
    with pytest.raises(ArmbridgeError, match="is blocked|out of reach"):
        environment_from_dict(doc)


# ------------------------------------------------------------------ plan files, CLI
def test_plan_file_round_trip_and_checks(tmp_path, e1_result):
    env, res = e1_result
    out = save_masr_plan(env, res.path, tmp_path / "p.json", provenance={"seed": 0})
    plan = load_masr_plan(out)
    np.testing.assert_array_equal(plan.q, res.path)
    assert plan.total_time == pytest.approx(res.cost, rel=1e-12)
    assert sum(s["duration"] for s in plan.steps()) == pytest.approx(res.cost, rel=1e-9)
    for a, (qa, qb) in zip(plan.actions, zip(res.path[:-1], res.path[1:])):
        assert len(a["steps"]) == len(ARM.action_sequence(qa, qb))
    doc = masr_plan_document(env, res.path)
    bad = json.loads(json.dumps(doc))
    bad["masr"]["tau"] += 1.0
    with pytest.raises(ArmbridgeError, match=r"tau = .* but the path takes"):
        plan_from_document(bad, "p.json")
    bad = json.loads(json.dumps(doc))
    bad["masr"]["actions"][0]["steps"] = bad["masr"]["actions"][0]["steps"][::-1]
    with pytest.raises(ArmbridgeError, match="action 0"):
        plan_from_document(bad, "p.json")
    # a last waypoint within d_margin of a joint is refused, in one line naming the margin
    bad = json.loads(json.dumps(doc))
    bad["masr"].pop("environment")
    last = bad["waypoints"][-1]["q"]
    j = int(np.argmin(np.abs(ARM.r[1:] - last[-1]))) + 1
    bad["waypoints"][-1]["q"][-1] = float(ARM.r[j] - 0.002)
    bad["masr"].pop("goal")
    fixed = masr_plan_document(env, np.array([w["q"] for w in bad["waypoints"]]))
    fixed["masr"].pop("environment")
    fixed["masr"].pop("goal")
    with pytest.raises(ArmbridgeError, match=r"^p.json: the last waypoint puts the MA at d = .*, 2.000 mm from a "
                                             r"joint, inside the robot's d_margin = 5 mm") as exc:
        plan_from_document(fixed, "p.json")
    assert "\n" not in str(exc.value)
    # a goal check that holds at d but not for every d within the margin is refused too
    q_last = res.path[-1].copy()
    x = ARM.fk(q_last)
    u = np.array([np.cos(x[2]), np.sin(x[2])])
    shifted = json.loads(json.dumps(doc))
    shifted["masr"]["goal"]["pose"] = [float(v) for v in (*(x[:2] + 0.0045 * u), x[2])]  # 4.5 mm along the link
    shifted["masr"].pop("environment")
    with pytest.raises(ArmbridgeError, match=r"the last waypoint puts the MA up to (9\.[5-9]\d|1\d\.\d\d) mm .* within d_margin"):
        plan_from_document(shifted, "p.json")
    bad = json.loads(json.dumps(doc))
    bad["masr"]["environment"]["obstacles"].append([[0.0, 0.05], [0.8, 0.05], [0.8, 0.6], [0.0, 0.6]])
    bad["masr"]["environment"]["start"] = [0, 0, 0, 0, 0, 0.1]
    with pytest.raises(ArmbridgeError):
        plan_from_document(bad, "p.json")


def test_cli_writes_plan_and_png(tmp_path):
    from typer.testing import CliRunner

    out, png, js = tmp_path / "plan.json", tmp_path / "fig.png", tmp_path / "s.json"
    r = CliRunner().invoke(plan_app, ["masr", "--env", "E1", "--out", str(out), "--iterations", "1000",
                                      "--seed", "0", "--png", str(png), "--json", str(js)])
    assert r.exit_code == 0, r.output
    plan = load_masr_plan(out)
    assert plan.provenance["planner"] == "masr-rrt*" and plan.env.name == "E1"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads(js.read_text())
    assert summary["success"] and summary["cost_s"] == pytest.approx(plan.total_time)
    # the baseline through the CLI, and an unknown environment
    r = CliRunner().invoke(plan_app, ["masr", "--env", "E1", "--out", str(tmp_path / "b.json"),
                                      "--planner", "rrt*", "--iterations", "1500"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(plan_app, ["masr", "--env", str(tmp_path / "nope.json"), "--out", str(out)])
    assert isinstance(r.exception, ArmbridgeError) and "no such environment file" in str(r.exception)


def test_shipped_iknn_drives_masr_rrt_star():
    assert shipped_ik_card("masr5") is not None, "models/onnx/masr5-iknn-card.json is shipped"
    env = fixed_environment("E1")
    ik, desc = resolve_goal_ik(env, "auto")
    assert "IK-NN" in desc
    res = rrt_star.plan(env, planner="masr-rrt*", iterations=1000, goal_ik=ik, seed=0)
    assert res.success and res.ik_calls > 0
    assert env.checker().path_problem(res.path) is None and env.in_goal(res.path[-1])
    assert res.settings["d_margin_m"] == ARM.d_margin


@pytest.mark.parametrize("planner", ["masr-rrt*", "rrt*"])
def test_every_goal_node_holds_the_margin(goal_ik, dls, planner):
    """Every goal node either planner makes (GoalFix), with the IK-NN and the numeric IK, on E1-E3 and a
    random environment, holds the joint margin and passes the goal check across [d - m, d + m]."""
    envs = [fixed_environment(n) for n in FIXED] + [random_environment(ARM, seed=3)]
    found = 0
    for env in envs:
        for ik in ((goal_ik, dls) if planner == "masr-rrt*" else (None,)):
            res = rrt_star.plan(env, planner=planner, iterations=600, goal_ik=ik, seed=1)
            if res.success:
                found += 1
                _assert_goal_holds_margin(env, res.path[-1])
    assert found >= (6 if planner == "masr-rrt*" else 1)


def test_numeric_ik_answers_hold_the_margin():
    rng = np.random.default_rng(4)
    q_true = rand_q(rng, 300)
    q_true[::3, -1] = ARM.r[rng.integers(1, ARM.n, 100)]  # a third of the goals sampled on a joint
    xg = ARM.fk(q_true)
    q, score = dls_ik.solve(ARM, xg, rand_q(rng, 300))
    assert ARM.holds_margin(q[:, -1]).all()
    ok = ARM.reaches(q, xg, 0.008, np.radians(4))
    np.testing.assert_array_equal(ok, score <= 1.0)
    assert ok[1::3].mean() > 0.9  # goals away from the joints are found
    one = dls_ik.goal_ik(ARM)(xg[1], rand_q(rng, 1)[0])
    assert ARM.holds_margin(one[-1])


def test_ompl_comparison_runs():
    from armbridge.planning.masr.ompl_compare import ompl_available, ompl_rrt_star

    if ompl_available():
        missing(f"ompl not importable: {ompl_available()}")
    r = ompl_rrt_star(fixed_environment("E1"), iterations=200, seed=0)
    assert r["iterations"] >= 200 and r["time_per_1000_s"] > 0
    if r["success"]:
        assert r["cost_s"] == pytest.approx(float(ARM.path_time(r["path"])))
        assert fixed_environment("E1").checker().path_problem(r["path"]) is None
