"""Planar chain kinematics, limits, validation and the robot catalog."""
import dataclasses
import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from armbridge.errors import ArmbridgeError
from armbridge.robots import ARM3R, PlanarChain, get_robot, wrap_angle

PI = math.pi
ANGLE = st.floats(-4 * PI, 4 * PI, allow_nan=False)


def chain(**overrides):
    d = {
        "name": "test2r",
        "link_lengths": [1.0, 0.5],
        "q_min": [-1.0, -2.0],
        "q_max": [1.0, 2.0],
        "v_max": [1.0, 1.0],
        "joint_names": ["a", "b"],
    }
    d.update(overrides)
    return PlanarChain(**d)


def numeric_jacobian(robot, q, h=1e-6):
    cols = []
    for j in range(robot.n):
        dq = np.zeros(robot.n)
        dq[j] = h
        d = robot.fk(q + dq) - robot.fk(q - dq)
        d[..., 2] = wrap_angle(d[..., 2])  # phi may wrap between the two samples
        cols.append(d / (2 * h))
    return np.stack(cols, axis=-1)


# Worked by hand with l = (0.19, 0.12, 0.07): each link adds l_i (cos, sin)
# of the summed angle so far.
@pytest.mark.parametrize(
    "q, pose",
    [
        ((0, 0, 0), (0.38, 0.0, 0.0)),
        ((PI / 2, 0, 0), (0.0, 0.38, PI / 2)),
        ((PI / 2, -PI / 2, 0), (0.19, 0.19, 0.0)),
        ((PI / 2, -PI / 2, PI / 2), (0.12, 0.26, PI / 2)),
        ((PI, -PI, PI / 2), (-0.07, 0.07, PI / 2)),
        ((0, -PI / 2, -PI / 2), (0.12, -0.12, PI)),  # sum -pi wraps to +pi
        ((PI, 0, 0), (-0.38, 0.0, PI)),
        ((PI, 0, PI / 2), (-0.31, -0.07, -PI / 2)),  # sum 3pi/2 wraps to -pi/2
    ],
)
def test_fk_hand_worked(q, pose):
    np.testing.assert_allclose(ARM3R.fk(q), pose, atol=1e-12)


@pytest.mark.parametrize("shape", [(), (7,), (4, 5)])
def test_batch_shapes(shape):
    q = np.random.default_rng(1).uniform(-3, 3, (*shape, 3))
    assert ARM3R.fk(q).shape == (*shape, 3)
    assert ARM3R.jacobian(q).shape == (*shape, 3, 3)
    assert ARM3R.joint_positions(q).shape == (*shape, 4, 2)
    assert ARM3R.within_limits(q).shape == shape
    assert ARM3R.clip(q).shape == (*shape, 3)
    # A batch is the same as its rows one by one.
    flat = q.reshape(-1, 3)
    np.testing.assert_array_equal(ARM3R.fk(q).reshape(-1, 3), np.array([ARM3R.fk(r) for r in flat]))


@pytest.mark.parametrize("bad", [np.zeros(2), np.zeros((5, 4)), 0.0])
def test_wrong_joint_count(bad):
    with pytest.raises(ArmbridgeError, match=r"shape \(\.\.\., 3\)"):
        ARM3R.fk(bad)


def test_joint_positions_consistent_with_fk():
    q = np.random.default_rng(2).uniform(-2 * PI, 2 * PI, (200, 3))
    p = ARM3R.joint_positions(q)
    np.testing.assert_array_equal(p[:, 0], 0.0)
    np.testing.assert_allclose(p[:, -1], ARM3R.fk(q)[:, :2], atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(np.diff(p, axis=1), axis=-1), np.broadcast_to(ARM3R.link_lengths, (200, 3)))


@pytest.mark.parametrize("low, high", [(ARM3R.q_min, ARM3R.q_max), (-3 * PI, 3 * PI)], ids=["in-limits", "anywhere"])
def test_jacobian_matches_finite_differences(low, high):
    q = np.random.default_rng(3).uniform(low, high, (500, 3))
    np.testing.assert_allclose(ARM3R.jacobian(q), numeric_jacobian(ARM3R, q), atol=1e-8)


@given(st.lists(ANGLE, min_size=2, max_size=2))
def test_jacobian_matches_finite_differences_2r(q):
    robot = chain()
    np.testing.assert_allclose(robot.jacobian(q), numeric_jacobian(robot, np.array(q)), atol=1e-8)


@given(ANGLE)
def test_wrap_angle_range(a):
    w = wrap_angle(a)
    assert -PI < w <= PI
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9) and math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)


def test_limits_inclusive_and_per_joint():
    assert ARM3R.within_limits(ARM3R.q_min) and ARM3R.within_limits(ARM3R.q_max)
    mid = (ARM3R.q_min + ARM3R.q_max) / 2
    for j in range(3):
        for edge, step in ((ARM3R.q_min, -1e-9), (ARM3R.q_max, 1e-9)):
            q = mid.copy()
            q[j] = edge[j] + step
            assert not ARM3R.within_limits(q), (j, q)


@given(st.lists(ANGLE, min_size=3, max_size=3))
def test_clip(q):
    c = ARM3R.clip(q)
    assert ARM3R.within_limits(c)
    if ARM3R.within_limits(q):
        np.testing.assert_array_equal(c, q)
    np.testing.assert_array_equal(ARM3R.clip(c), c)


def test_arm3r_is_the_paper_arm():
    np.testing.assert_array_equal(ARM3R.link_lengths, [0.19, 0.12, 0.07])
    np.testing.assert_array_equal(ARM3R.q_min, [0.0, -PI, -PI / 2])
    np.testing.assert_array_equal(ARM3R.q_max, [PI, 0.0, PI / 2])
    np.testing.assert_array_equal(ARM3R.v_max, [3.0, 3.0, 3.0])
    assert ARM3R.joint_names == ("shoulder", "elbow", "wrist")
    assert ARM3R.n == 3


def test_get_robot():
    assert get_robot("arm3r") is ARM3R
    assert get_robot("ARM3R") is ARM3R
    with pytest.raises(ArmbridgeError, match=r"unknown robot 'scara'; known robots: arm3r"):
        get_robot("scara")


def test_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        ARM3R.name = "other"
    with pytest.raises(ValueError):
        ARM3R.q_max[0] = 10.0


def test_dict_round_trip_through_json():
    d = json.loads(json.dumps(ARM3R.to_dict()))
    robot = PlanarChain.from_dict(d)
    assert robot == ARM3R and hash(robot) == hash(ARM3R)
    assert robot != chain()
    np.testing.assert_array_equal(robot.fk([0.3, -0.2, 0.1]), ARM3R.fk([0.3, -0.2, 0.1]))


def test_from_dict_errors():
    d = ARM3R.to_dict()
    del d["v_max"]
    with pytest.raises(ArmbridgeError, match=r"'arm3r': missing keys \['v_max'\]"):
        PlanarChain.from_dict(d)
    with pytest.raises(ArmbridgeError, match=r"unknown keys \['mass'\]"):
        PlanarChain.from_dict({**ARM3R.to_dict(), "mass": 1.0})
    with pytest.raises(ArmbridgeError, match="must be a JSON object"):
        PlanarChain.from_dict([1, 2])
    with pytest.raises(ArmbridgeError, match="link_lengths must be a list of numbers"):
        PlanarChain.from_dict({**ARM3R.to_dict(), "link_lengths": ["a", "b", "c"]})


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"name": ""}, "name must be a non-empty string"),
        ({"link_lengths": [1.0, 0.0]}, r"link_lengths must all be > 0 m"),
        ({"link_lengths": [1.0, -0.5]}, r"link_lengths must all be > 0 m"),
        ({"link_lengths": []}, "link_lengths is empty"),
        ({"link_lengths": [[1.0, 0.5]]}, "flat list of finite numbers"),
        ({"link_lengths": [1.0, float("nan")]}, "flat list of finite numbers"),
        ({"q_min": [-1.0, 2.0]}, r"joint 1 needs q_min < q_max, got \[2.0, 2.0\]"),
        ({"q_max": [-1.5, 2.0]}, r"joint 0 needs q_min < q_max"),
        ({"q_max": [1.0, 2.0, 3.0]}, "q_max has 3 values, link_lengths has 2"),
        ({"v_max": [1.0, 0.0]}, r"v_max must all be > 0 rad/s"),
        ({"joint_names": ["a"]}, "joint_names must be 2 non-empty strings"),
        ({"joint_names": "ab"}, "joint_names must be 2 non-empty strings"),
        ({"joint_names": ["a", ""]}, "joint_names must be 2 non-empty strings"),
        ({"joint_names": ["a", "a"]}, "joint_names must be unique"),
    ],
)
def test_bad_constructor(overrides, message):
    with pytest.raises(ArmbridgeError, match=message):
        chain(**overrides)
