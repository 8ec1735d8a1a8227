"""OMPL STRIDE through the pybind11 shim over Debian's libompl-dev (planning.ext), with our real checker.

Real OMPL 1.5 and the real ChainChecker: STRIDE's paths must pass our checker
again, and the checker's own counter must grow by what the run reports (the
callbacks are ours, not OMPL's). The wheel's OMPL runs in the same process.
"""
import numpy as np
import pytest

from armbridge.errors import ArmbridgeError
from armbridge.planning.ext import build, stride
from tests.require import missing

if stride.missing():
    missing(f"OMPL STRIDE: {stride.missing()}")

from armbridge.planning.soft import ompl_planners  # noqa: E402
from armbridge.planning.soft.scene import fixed_scene  # noqa: E402


@pytest.fixture(scope="module")
def two_arm():
    scene = fixed_scene("two-arm")
    scene.find_goal_states()
    return scene


@pytest.mark.parametrize("seed", [0, 1])
def test_stride_solves_two_arm_with_our_checker(two_arm, seed):
    problem = two_arm.problem()
    before = problem.checker.checks
    r = ompl_planners.solve(problem, "STRIDE", seed=seed, time_limit=60.0)  # solves in ms: 60 s is a hang guard
    assert r.success and r.planner == "OMPL STRIDE"
    assert r.collision_checks == r.stats["obstacle_checks"] == problem.checker.checks - before > 0
    assert np.allclose(r.path[0], two_arm.start)
    assert problem.goal.is_satisfied(r.path[-1])
    assert two_arm.checker().path_problem(r.path) is None  # a fresh checker accepts every edge
    assert np.linalg.norm(two_arm.checker().tip(r.path[-1]) - two_arm.goal_point) <= two_arm.goal_tol
    assert r.stats["track_nodes"] == r.path.shape[0] - 1 and r.tree_size >= r.stats["track_nodes"]
    assert r.settings["ompl"].startswith("Debian libompl 1.5")
    assert r.settings["range"] > 0 and r.settings["goal_bias"] == pytest.approx(0.05)


def test_callbacks_are_ours_and_a_blocked_goal_fails(two_arm):
    """A checker that refuses every motion: STRIDE can add no edge, so it fails, having asked our callbacks."""
    problem = two_arm.problem()
    real = problem.checker
    calls = []

    class Refusing:
        checks = 0

        def is_valid(self, q):
            return real.is_valid(q)

        def motion_valid(self, a, b):
            calls.append(1)
            return False

    problem.checker = Refusing()
    r = stride.solve(problem, time_limit=0.3, seed=0)
    assert not r.success and r.path is None and calls


def test_iterations_cap_and_wheel_planners_beside_it(two_arm):
    capped = stride.solve(two_arm.problem(), time_limit=10.0, iterations=3)
    assert capped.iterations <= 3
    k = ompl_planners.solve(two_arm.problem(), "KPIECE1", seed=0, time_limit=60.0)  # the wheel's OMPL, same process
    assert k.success and two_arm.checker().path_problem(k.path) is None
    s = ompl_planners.solve(two_arm.problem(), "STRIDE", seed=0, time_limit=60.0)
    assert s.success


def test_bad_input_is_one_clear_error(two_arm):
    with pytest.raises(ArmbridgeError, match="time_limit"):
        stride.solve(two_arm.problem(), time_limit=0.0)
    with pytest.raises(ArmbridgeError, match="iterations"):
        stride.solve(two_arm.problem(), iterations=0)


def test_missing_libompl_dev_names_the_fix(monkeypatch, tmp_path):
    from armbridge.bench import wjrrt

    monkeypatch.setattr(build, "OMPL_INCLUDE", tmp_path)
    why = ompl_planners.missing("STRIDE")
    assert "libompl-dev" in why and "apt-get install" in why and "setup.sh" in why
    doc = wjrrt.run(wjrrt.WjrrtBenchSize(seeds=1, time_limit=0.1), ["two-arm"], ("STRIDE",))
    assert "libompl-dev" in doc["not_run"]["STRIDE"] and doc["scenes"]["two-arm"]["planners"] == {}
    build.stride_module.cache_clear()
    try:
        with pytest.raises(ArmbridgeError, match="libompl-dev"):
            build.stride_module()
    finally:
        build.stride_module.cache_clear()
