"""The MASR in the planning vocabulary (planning.masr.space): MasrSpace, MasrChecker, MasrGoal, Problem."""
import numpy as np
import pytest
from shapely.geometry import LineString, Polygon

from armbridge.errors import ArmbridgeError
from armbridge.planning.base import Problem
from armbridge.planning.masr import rrt_star
from armbridge.planning.masr.environment import fixed_environment
from armbridge.planning.masr.space import MasrChecker, MasrGoal, MasrSpace
from armbridge.robots import MASR5

ARM = MASR5


def rand_q(rng, count, spill=0.0):
    """Uniform in C_f, or in C_f grown by `spill` (a share of each range) to have some outside it."""
    lo = np.append(-ARM.theta_b, 0.0)
    hi = np.append(ARM.theta_b, ARM.total_length)
    pad = spill * (hi - lo)
    return rng.uniform(lo - pad, hi + pad, (count, ARM.n + 1))


def t_norm(a, b):
    """|b - a|_t of Steer: sum |dtheta| / theta-dot + |dd| / d-dot (s)."""
    return np.abs(b[:-1] - a[:-1]).sum() / ARM.joint_speed + abs(b[-1] - a[-1]) / ARM.ma_speed


def test_space_is_c_f_with_eq8_and_steer():
    space = MasrSpace(ARM)
    assert space.dim == ARM.n + 1
    np.testing.assert_array_equal(space.lower, np.append(-ARM.theta_b, 0.0))
    np.testing.assert_array_equal(space.upper, np.append(ARM.theta_b, ARM.total_length))
    rng = np.random.default_rng(0)
    Q = space.sample(rng, 2000)
    assert Q.shape == (2000, ARM.n + 1) and ARM.within_limits(Q).all()
    # uniform: every coordinate spreads over its whole range
    span = (Q.max(0) - Q.min(0)) / (space.upper - space.lower)
    assert np.all(span > 0.98)
    np.testing.assert_array_equal(space.from_unit(np.zeros((1, ARM.n + 1)))[0], space.lower)
    A, B = rand_q(rng, 200), rand_q(rng, 200)
    np.testing.assert_allclose(space.distance(A, B), ARM.action_cost(A, B), rtol=1e-12)
    assert space.cost(A[0], B[0]) == pytest.approx(float(ARM.action_cost(A[0], B[0])), rel=1e-12)
    assert space.path_cost(A[:3]) == pytest.approx(float(ARM.path_time(A[:3])), rel=1e-12)
    assert space.path_cost(A[:1]) == 0.0
    for a, b in zip(A[:50], B[:50]):
        for step in (0.5, 4.0, 1e3):
            q = space.interpolate(a, b, step)
            if t_norm(a, b) <= step:
                np.testing.assert_array_equal(q, b)
            else:  # on the segment a -> b, exactly `step` seconds of |.|_t from a
                s = (q - a) / (b - a)
                np.testing.assert_allclose(s, s[0], rtol=1e-9)
                assert t_norm(a, q) == pytest.approx(step, rel=1e-9)
    with pytest.raises(ArmbridgeError, match="unknown steer"):
        MasrSpace(ARM, "spline")


def test_convention_steer_stops_the_convention_after_delta():
    space = MasrSpace(ARM, "convention")
    rng = np.random.default_rng(1)
    for a, b in zip(rand_q(rng, 100), rand_q(rng, 100)):
        full = float(ARM.action_cost(a, b))
        step = 0.4 * full
        q = space.interpolate(a, b, step)
        # the convention's motion a -> q is the first `step` seconds of a -> b: it costs step,
        # and the rest q -> b costs the remainder (one motion, cut once)
        assert float(ARM.action_cost(a, q)) == pytest.approx(step, rel=1e-6, abs=1e-9)
        assert float(ARM.action_cost(a, q)) + float(ARM.action_cost(q, b)) <= full + 1e-6
        np.testing.assert_array_equal(space.interpolate(a, b, 2 * full), b)


def test_checker_is_the_collision_checker_and_counts():
    env = fixed_environment("E1")
    chk = MasrChecker(env.checker())
    rng = np.random.default_rng(2)
    Q = rand_q(rng, 600, spill=0.05)
    ours = np.array([chk.is_valid(q) for q in Q])
    np.testing.assert_array_equal(ours, env.checker().free(Q))
    assert 0.2 < ours.mean() < 0.95
    assert chk.checks == 600
    inside = Q[ARM.within_limits(Q)]
    np.testing.assert_array_equal(chk.valid_rows(inside), env.checker().free(inside))
    A, B = Q[ours][:150], rand_q(rng, 150)
    for a, b in zip(A, B):
        assert chk.motion_valid(a, b) == env.checker().edge_free(a, b, check_start=False)
    # clearance: the least distance of a link segment to a polygon, less half the link width (shapely)
    polys = [Polygon(p) for p in env.obstacles]
    for q in Q[:60]:
        pts = ARM.joint_points(q)
        ref = min(LineString(pts[k:k + 2]).distance(P) for k in range(ARM.n) for P in polys) - chk.margin
        assert chk.clearance(q) == pytest.approx(ref, abs=1e-12)
        if ref > 1e-9 and ARM.within_limits(q):
            assert chk.is_valid(q)


def test_goal_is_the_goal_check_over_the_margin():
    env = fixed_environment("E3")
    goal = MasrGoal(ARM, env.goal_pose, env.e_p, env.e_phi)
    assert goal.rect_width == env.e_p
    assert goal.is_satisfied(env.goal_q) and goal.distance(env.goal_q) == 0.0
    assert goal.score(env.goal_q) <= 1.0
    rng = np.random.default_rng(3)
    near = env.goal_q + rng.normal(0, 0.01, (400, ARM.n + 1)) * np.append(np.ones(ARM.n), 0.3)
    near = np.clip(near, np.append(-ARM.theta_b, 0), np.append(ARM.theta_b, ARM.total_length))
    sat = np.array([goal.is_satisfied(q) for q in near])
    np.testing.assert_array_equal(sat, env.in_goal(near))
    assert 0.05 < sat.mean() < 0.95
    score = goal.score(near)
    clear = np.abs(score - 1.0) > 1e-9
    np.testing.assert_array_equal(sat[clear], score[clear] <= 1.0)
    for q, s in zip(near[~sat][:20], score[~sat][:20]):
        assert goal.distance(q) == pytest.approx(s, rel=1e-12) and s > 1.0  # the kernel and MasrArm agree
    with pytest.raises(ArmbridgeError, match="rectangle width"):
        MasrGoal(ARM, env.goal_pose, env.e_p, env.e_phi, rect_width=0.0)


def test_environment_problem_and_planning_on_it():
    env = fixed_environment("E1")
    problem = env.problem()
    assert isinstance(problem, Problem) and problem.name == "E1"
    np.testing.assert_array_equal(problem.start, env.start)
    np.testing.assert_array_equal(problem.goal_states, env.goal_q[None])
    assert problem.checker.collision is env.checker()
    # the planner on the problem is the planner on the environment, and it counts in the problem's checker
    a = rrt_star.plan(env, planner="rrt*", iterations=200, seed=4)
    before = problem.checker.checks
    b = rrt_star.plan(problem, planner="rrt*", iterations=200, seed=4)
    np.testing.assert_array_equal(a.best_costs, b.best_costs)
    assert (a.tree_size, a.collision_checks) == (b.tree_size, b.collision_checks)
    assert problem.checker.checks - before >= b.collision_checks + 200  # edges, and SampleFree's draws
    # a wider OnGoal rectangle and the convention's Steer come in through the problem
    wide = env.problem(goal_rect_width=2 * env.e_p, steer="convention")
    c = rrt_star.plan(wide, planner="rrt*", iterations=50, seed=4)
    assert c.settings["goal_rect_width_m"] == 2 * env.e_p and c.settings["steer"] == "convention"
    assert isinstance(c, rrt_star.PlanResult) and c.summary()["cost_s"] == (c.cost if c.success else None)
