"""Closed-form 3R IK: round trips through FK, branch choice, failures, paths."""
import math

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from armbridge.errors import ArmbridgeError
from armbridge.ik import ik, solve_path
from armbridge.robots import ARM3R, PlanarChain, wrap_angle

PI = math.pi
IN_LIMITS = st.tuples(*(st.floats(lo, hi) for lo, hi in zip(ARM3R.q_min, ARM3R.q_max)))
# ARM3R's links with the paper's section-5.2 angle set: the elbow bends both
# ways and the shoulder spans a full turn (so -pi and pi are both inside).
SYM3R = PlanarChain(
    "sym3r", ARM3R.link_lengths, [-PI, -PI / 2, -PI / 4], [PI, PI / 2, PI / 4], ARM3R.v_max, ARM3R.joint_names
)


def pose_error(q, pose, robot=ARM3R):
    d = robot.fk(q) - pose
    d[..., 2] = wrap_angle(d[..., 2])  # phi = pi and phi = -pi are one pose
    return np.abs(d).max()


@pytest.mark.parametrize("robot", [ARM3R, SYM3R], ids=lambda r: r.name)
def test_round_trip_random_batch(robot):
    q = np.random.default_rng(4).uniform(robot.q_min, robot.q_max, (20000, 3))
    pose = robot.fk(q)
    sol, ok = ik(robot, pose)
    assert ok.all()
    assert robot.within_limits(sol).all()
    assert pose_error(sol, pose, robot) < 1e-9


@given(IN_LIMITS)
@example((2.0, 0.0, 1.5))  # straight elbow on its limit: arccos is ill-conditioned there
@example((0.75, 0.0, PI / 2))
def test_round_trip_and_q_prev_keeps_branch(q):
    pose = ARM3R.fk(q)
    sol, ok = ik(ARM3R, pose)
    assert ok and ARM3R.within_limits(sol) and pose_error(sol, pose) < 1e-9
    # Given the configuration itself as q_prev, IK returns that configuration
    # (the joint angles are ill-conditioned only near a straight elbow).
    if abs(math.sin(q[1])) > 1e-3:
        sol, ok = ik(ARM3R, pose, q_prev=q)
        np.testing.assert_allclose(sol, q, atol=1e-9)


def test_corners_of_the_limits_are_reachable():
    for q in (ARM3R.q_min, ARM3R.q_max, [0, 0, 0], [PI, -PI, PI / 2]):
        sol, ok = ik(ARM3R, ARM3R.fk(q))
        assert ok and ARM3R.within_limits(sol) and pose_error(sol, ARM3R.fk(q)) < 1e-9, q


def test_branch_nearest_q_prev():
    # ARM3R's elbow turns one way only ([-pi, 0]); SYM3R's both ways, so both
    # branches are valid here and q_prev decides.
    elbow_pos = np.array([0.2, 0.6, -0.3])  # mirror: [0.66, -0.6, 0.44]
    pose = SYM3R.fk(elbow_pos)
    sol_pos, ok_pos = ik(SYM3R, pose, q_prev=[0.0, 1.0, 0.0])
    sol_neg, ok_neg = ik(SYM3R, pose, q_prev=[0.0, -1.0, 0.0])
    assert ok_pos and ok_neg
    np.testing.assert_allclose(sol_pos, elbow_pos, atol=1e-12)
    np.testing.assert_allclose(sol_neg[1], -elbow_pos[1], atol=1e-12)
    assert pose_error(sol_neg, pose, SYM3R) < 1e-9
    # Without q_prev: the branch nearer the middle of the limits (here 0).
    expected = min((sol_pos, sol_neg), key=np.linalg.norm)
    np.testing.assert_array_equal(ik(SYM3R, pose)[0], expected)


@given(st.tuples(*(st.floats(lo, hi) for lo, hi in zip(SYM3R.q_min, SYM3R.q_max))))
@example((-2.0, 0.0, math.pi / 4))     # the stretched elbow, where a clean clone's draw found 1.6e-8
def test_two_sided_elbow_round_trip(q):
    pose = SYM3R.fk(q)
    sol, ok = ik(SYM3R, pose)
    # acos(c) near c = 1 (the elbow stretched) keeps half the digits: q2 to about sqrt(2 eps)
    # = 2e-8 rad, the pose to a link's length times that
    tol = 1e-9 if abs(math.sin(q[1])) > 1e-3 else 1e-7
    assert ok and SYM3R.within_limits(sol) and pose_error(sol, pose, SYM3R) < tol
    if abs(math.sin(q[1])) > 1e-3 and abs(abs(q[0]) - PI) > 1e-6:
        np.testing.assert_allclose(ik(SYM3R, pose, q_prev=q)[0], q, atol=1e-9)


def test_unreachable_and_out_of_limits():
    poses = np.array(
        [
            [0.5, 0.0, 0.0],  # beyond full reach
            [0.07, 0.0, 0.0],  # wrist at the base: inside the 0.07 m hole of links 1-2
            list(ARM3R.fk([-1.0, 0.0, 0.0])),  # only solution has the shoulder at -1 rad
            list(ARM3R.fk([0.5, -1.0, 0.5])),  # fine
        ]
    ).reshape(2, 2, 3)
    q, ok = ik(ARM3R, poses)
    assert ok.shape == (2, 2) and q.shape == (2, 2, 3)
    np.testing.assert_array_equal(ok, [[False, False], [False, True]])
    assert np.isnan(q[~ok]).all() and not np.isnan(q[ok]).any()


def test_rejects_bad_input():
    with pytest.raises(ArmbridgeError, match=r"shape \(\.\.\., 3\)"):
        ik(ARM3R, [0.1, 0.2])
    two_link = PlanarChain("two", [1.0, 1.0], [-1.0, -1.0], [1.0, 1.0], [1.0, 1.0], ["a", "b"])
    with pytest.raises(ArmbridgeError, match="needs a 3-joint chain, robot 'two' has 2"):
        ik(two_link, [0.1, 0.2, 0.0])


def smooth_joint_path(k=400):
    """A joint trajectory that stays well inside the limits, elbow bent."""
    t = np.linspace(0, 1, k)[:, None]
    mid = (ARM3R.q_min + ARM3R.q_max) / 2
    return mid + np.array([0.9, 0.9, 1.0]) * np.sin(2 * PI * t * np.array([1.0, 2.0, 3.0]))


def test_solve_path_follows_the_branch():
    q = smooth_joint_path()
    path = solve_path(ARM3R, ARM3R.fk(q), q[0])
    assert path.shape == q.shape
    np.testing.assert_allclose(path, q, atol=1e-9)


def test_solve_path_keeps_the_elbow_it_starts_with():
    # Both elbows are valid for SYM3R along this path, and for some poses the
    # mid-range default would pick the other one: the path must not flip.
    t = np.linspace(0, 1, 300)
    q = np.stack([2.5 + 0.5 * np.sin(2 * PI * t), 0.8 + 0.4 * np.cos(2 * PI * t), 0.2 * np.sin(4 * PI * t)], axis=1)
    poses = SYM3R.fk(q)
    assert (ik(SYM3R, poses)[0][:, 1] < 0).any()
    np.testing.assert_allclose(solve_path(SYM3R, poses, q[0]), q, atol=1e-9)


def test_solve_path_names_first_bad_pose():
    q = smooth_joint_path(50)
    poses = ARM3R.fk(q)
    poses[17] = ARM3R.fk([-1.0, 0.0, 0.0])
    poses[30] = [1.0, 1.0, 0.0]
    with pytest.raises(ArmbridgeError, match=r"^pose 17 of 50 .* reachable only outside the joint limits"):
        solve_path(ARM3R, poses, q[0])
    poses[17] = ARM3R.fk(q[17])
    with pytest.raises(ArmbridgeError, match=r"^pose 30 of 50 \(x=1.0000 m, y=1.0000 m, phi=0.0000 rad\) .* out of reach"):
        solve_path(ARM3R, poses, q[0])


def test_solve_path_rejects_bad_shapes():
    with pytest.raises(ArmbridgeError, match=r"shape \(k, 3\)"):
        solve_path(ARM3R, [0.1, 0.2, 0.0], [0.5, -1.0, 0.0])
    with pytest.raises(ArmbridgeError, match=r"q0 must have shape \(3,\)"):
        solve_path(ARM3R, [[0.1, 0.2, 0.0]], [0.5, -1.0])
