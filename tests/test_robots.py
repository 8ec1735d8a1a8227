"""Planar chain kinematics, limits, validation; the robot interface every model implements,
the one registry, and the one angle-wrapping function."""
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
        ((0, -PI / 2, -PI / 2), (0.12, -0.12, -PI)),  # phi in [-pi, pi): -pi stays
        ((PI, 0, 0), (-0.38, 0.0, -PI)),  # sum pi wraps to -pi
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
    assert ARM3R.joint_points(q).shape == (*shape, 4, 2)
    assert ARM3R.within_limits(q).shape == shape
    assert ARM3R.clip(q).shape == (*shape, 3)
    # A batch is the same as its rows one by one.
    flat = q.reshape(-1, 3)
    np.testing.assert_array_equal(ARM3R.fk(q).reshape(-1, 3), np.array([ARM3R.fk(r) for r in flat]))


@pytest.mark.parametrize("bad", [np.zeros(2), np.zeros((5, 4)), 0.0])
def test_wrong_joint_count(bad):
    with pytest.raises(ArmbridgeError, match=r"shape \(\.\.\., 3\)"):
        ARM3R.fk(bad)


def test_joint_points_consistent_with_fk():
    q = np.random.default_rng(2).uniform(-2 * PI, 2 * PI, (200, 3))
    p = ARM3R.joint_points(q)
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
    assert -PI <= w < PI
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
    with pytest.raises(ArmbridgeError, match=r"unknown robot 'scara'; known robots: arm3r, masr5"):
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


# ---------------------------------------------------------------- the one wrap_angle

# The six copies the review found, as they were: the callers' results must not change.
OLD_WRAPS = {
    "planar.wrap_angle, faulttolerant.wrap": lambda a: np.pi - np.mod(np.pi - a, 2 * np.pi),
    "masr_kernels.wrap, masr_nn.wrap_angle_torch": lambda a: a - 2 * np.pi * np.floor((a + np.pi) / (2 * np.pi)),
    "masr_plan inline": lambda a: (a + np.pi) % (2 * np.pi) - np.pi,
    "smm.command._wrap": lambda a: np.array([math.pi - (math.pi - x) % (2 * math.pi) for x in a]),
}


@pytest.mark.parametrize("old", OLD_WRAPS.values(), ids=OLD_WRAPS.keys())
def test_wrap_angle_keeps_the_old_results(old):
    rng = np.random.default_rng(7)
    a = np.r_[rng.uniform(-30, 30, 20_000), rng.normal(0, 1e-3, 100)]
    new, was = wrap_angle(a), old(a)
    inside = np.abs(np.abs(was) - PI) > 1e-9  # off the seam the result is the same
    np.testing.assert_allclose(new[inside], was[inside], rtol=0, atol=1e-12)
    # On the seam the convention says -pi: the same angle as the old +pi.
    np.testing.assert_allclose(np.cos(new[~inside]), np.cos(was[~inside]), atol=1e-9)
    assert wrap_angle(PI) == -PI and wrap_angle(-PI) == -PI and wrap_angle(3 * PI) == -PI


def test_wrap_angle_numpy_numba_torch_and_floats_agree_bit_for_bit():
    import torch

    from armbridge.robots.masr_kernels import wrap

    a = np.random.default_rng(3).uniform(-50, 50, 5000)
    ref = wrap_angle(a)
    assert np.array_equal(ref, [wrap(x) for x in a])  # the numba kernel
    assert np.array_equal(ref, [wrap_angle(float(x)) for x in a])
    t = torch.tensor(a, requires_grad=True)
    wt = wrap_angle(t)
    assert np.array_equal(ref, wt.detach().numpy())
    wt.sum().backward()
    assert torch.all(t.grad == 1.0)  # a loss can wrap an angle error
    inside = a[(a >= -PI) & (a < PI)]
    assert np.array_equal(wrap_angle(inside), inside)  # nothing in range moves, not even by an ulp
    assert isinstance(wrap_angle(1.0), float) and wrap_angle([4.0]).shape == (1,)


# ------------------------------------------------------- one interface, one registry


def _every_robot():
    from armbridge.robots import get_robot, names

    return [get_robot(n) for n in names()]


@pytest.mark.parametrize("name", ["arm3r", "masr5", "planar3r", "spatial4r", "spatial7r"])
def test_every_registered_robot_implements_the_interface(name):
    from armbridge.robots import Robot, get_robot, robot_from_dict, robot_to_dict

    robot = get_robot(name)
    assert isinstance(robot, Robot) and robot.name == name and robot.kind in ("planar", "masr", "dh")
    k = robot.dof
    assert len(robot.joint_names) == len(set(robot.joint_names)) == k
    assert len(robot.joint_units) == k and set(robot.joint_units) <= {"rad", "m"}
    for a in (robot.q_min, robot.q_max, robot.v_max):
        assert a.shape == (k,) and not a.flags.writeable
    assert np.all(robot.q_min < robot.q_max) and np.all(robot.v_max > 0)
    q = robot.q_min + (robot.q_max - robot.q_min) * np.random.default_rng(0).uniform(size=(4, 5, k))
    pts = robot.joint_points(q)
    assert pts.shape[:2] == (4, 5) and pts.shape[-1] == robot.draw_dim
    np.testing.assert_array_equal(pts[..., 0, :], 0.0)  # the base at the origin
    assert np.all(np.linalg.norm(pts, axis=-1) <= robot.reach + 1e-12)
    assert robot.ee_point(q).shape == (4, 5, robot.draw_dim)
    assert robot.within_limits(q).all() and robot.within_limits(q).shape == (4, 5)
    assert robot.within_limits(robot.q_min) and robot.within_limits(robot.q_max)
    for j in range(k):
        for edge, step in ((robot.q_min, -1e-9), (robot.q_max, 1e-9)):
            out = q[0, 0].copy()
            out[j] = edge[j] + step
            assert not robot.within_limits(out), (j, out)
    again = robot_from_dict(json.loads(json.dumps(robot_to_dict(robot))))
    assert type(again) is type(robot) and again == robot


def test_masr_configuration_is_the_joints_and_d():
    from armbridge.robots import MASR5

    assert MASR5.dof == MASR5.n + 1 == 6
    assert MASR5.joint_names == ("theta_1", "theta_2", "theta_3", "theta_4", "theta_5", "d")
    assert MASR5.joint_units == ("rad",) * 5 + ("m",)
    np.testing.assert_allclose(MASR5.q_max, [*np.deg2rad([50] * 5), 0.8])
    np.testing.assert_allclose(MASR5.q_min, [*np.deg2rad([-50] * 5), 0.0])
    np.testing.assert_allclose(MASR5.v_max, [0.28] * 5 + [0.1])
    q = np.array([0.1, -0.2, 0.3, 0.0, 0.2, 0.5])
    np.testing.assert_array_equal(MASR5.ee_point(q), MASR5.ma_point(q))  # the end effector is the MA


def test_dh_joint_points_are_the_torch_frames():
    import torch

    from armbridge.robots import get_robot

    for name in ("planar3r", "spatial4r", "spatial7r"):
        arm = get_robot(name)
        q = np.random.default_rng(1).uniform(-PI, PI, (6, arm.n))
        frames = arm.frames(torch.tensor(q))[..., :3, 3].numpy()
        np.testing.assert_allclose(arm.joint_points(q), frames[..., : arm.draw_dim], atol=1e-12)


def test_dh_limits_are_data():
    from armbridge.robots.dh import DEFAULT_V_MAX, DHChain

    d = {"name": "two", "a": [1.0, 1.0], "alpha": [0.0, 0.0], "d": [0.0, 0.0], "theta": [0.0, 0.0], "space": "xy"}
    free = DHChain.from_dict(d)
    np.testing.assert_array_equal(free.q_max, [PI, PI])
    np.testing.assert_array_equal(free.v_max, [DEFAULT_V_MAX] * 2)
    assert free.joint_names == ("j1", "j2")
    stops = DHChain.from_dict({**d, "q_min": [-1, -1], "q_max": [1, 2], "v_max": [2, 2], "joint_names": ["a", "b"]})
    assert not stops.within_limits([0.0, 2.5]) and stops.within_limits([0.0, 1.5]) and stops != free
    with pytest.raises(ArmbridgeError, match="joint 1 needs q_min < q_max"):
        DHChain.from_dict({**d, "q_min": [-1, 3], "q_max": [1, 2]})
    # The planar arm seen as a DH chain keeps its limits and names.
    arm = DHChain.from_planar(ARM3R)
    assert arm.joint_names == ARM3R.joint_names and np.array_equal(arm.q_min, ARM3R.q_min)
    np.testing.assert_allclose(arm.joint_points([0.3, -0.4, 0.2]), ARM3R.joint_points([0.3, -0.4, 0.2]), atol=1e-15)


def test_registry_register_and_kinds(monkeypatch):
    from armbridge.robots import catalog, names, register, robot_from_dict
    from armbridge.robots.catalog import get_masr

    monkeypatch.setattr(catalog, "_BUILT", dict(catalog._BUILT))  # the robot registered here stays here

    assert names() == sorted(names()) and {"arm3r", "masr5", "spatial7r"} <= set(names())
    two = register(chain(name="test-registered"))
    assert get_robot("TEST-registered") is two and "test-registered" in names()
    assert register(chain(name="test-registered")) is not None  # the same robot again: fine
    with pytest.raises(ArmbridgeError, match="'arm3r' is already registered"):
        register(chain(name="arm3r"))
    with pytest.raises(ArmbridgeError, match="unknown robot kind 'scara'; known kinds: planar, masr, dh"):
        robot_from_dict({"kind": "scara", "name": "x"})
    with pytest.raises(ArmbridgeError, match=r"unknown MASR 'arm3r' \(the robot is not a MASR\); known MASRs: masr5"):
        get_masr("arm3r")
