"""DH chains and the SMM arms: FK, Jacobians, symmetries, descriptions."""
import math

import numpy as np
import pytest

from require import missing

try:
    import torch
except ImportError:
    missing("torch is not installed (`make setup` installs the [train] extra)")

from armbridge.errors import ArmbridgeError
from armbridge.robots.catalog import ARM3R
from armbridge.robots.dh import DHChain
from armbridge.robots.rotations import rot_from_vec, vec_from_rot
from armbridge.smm.arms import ARMS, get_smm_arm

torch.set_num_threads(1)
NAMES = ["planar3r", "spatial4r", "spatial7r", "arm3r"]


def _q(arm: DHChain, count: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(count, arm.n, generator=g, dtype=torch.float64) * 2 - 1) * math.pi


def test_dh_tables_are_tables_i_and_ii() -> None:
    r4 = get_smm_arm("spatial4r")
    np.testing.assert_allclose(r4.alpha, [math.pi / 2, -math.pi / 2, math.pi / 2, 0])
    np.testing.assert_allclose(r4.a, [1.4142, 1.4142, 1.4142, 1.2247])
    np.testing.assert_allclose(r4.d, [0, 1, -1, 0.5])
    np.testing.assert_allclose(r4.theta, 0)
    assert (r4.n, r4.m, r4.space) == (4, 3, "xyz")
    r7 = get_smm_arm("spatial7r")
    np.testing.assert_allclose(r7.alpha, [-1.7104, -1.9897, -1.1519, 0.8726, -1.6057, -1.6150, 0])
    np.testing.assert_allclose(r7.a, [0.17, 1.42, 1.42, 0.56, 1.32, 1.27, 0])
    np.testing.assert_allclose(r7.d, [0, 1.67, -0.69, -1.77, 2.42, -0.38, 0.95])
    np.testing.assert_allclose(r7.theta, 0)
    assert (r7.n, r7.m, r7.space) == (7, 6, "pose")
    r3 = get_smm_arm("planar3r")
    assert (r3.n, r3.m, r3.reach) == (3, 2, 3.0)
    np.testing.assert_allclose(r3.a, [1, 1, 1])
    arm = get_smm_arm("ARM3R")
    np.testing.assert_allclose(arm.a, ARM3R.link_lengths)
    assert arm.reach == pytest.approx(0.38)


def test_fk_hand_worked() -> None:
    r3 = get_smm_arm("planar3r")
    np.testing.assert_allclose(r3.task(np.array([0.0, 0.0, 0.0])), [3, 0], atol=1e-15)
    np.testing.assert_allclose(r3.task(np.array([math.pi / 2, -math.pi / 2, math.pi / 2])), [1, 2], atol=1e-15)
    np.testing.assert_allclose(r3.task(np.array([math.pi / 2, math.pi, 0.0])), [0, -1], atol=1e-15)
    # 4R at q = 0: link i adds R_{i-1} (a_i x + d_i z) with R_0 = I, R_1 = Rx(pi/2), R_2 = I,
    # R_3 = R_4 = Rx(pi/2), and Rx(pi/2) z = -y: p = (sum a, -d2 - d4, d3) = (5.4673, -1.5, -1).
    r4 = get_smm_arm("spatial4r")
    t = r4.fk(np.zeros(4))
    p = np.array([5.4673, -1.5, -1.0])
    np.testing.assert_allclose(t[:3, 3], p, atol=1e-12)
    np.testing.assert_allclose(t[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)
    # The planar chain agrees with PlanarChain.
    arm = get_smm_arm("arm3r")
    q = _q(arm, 20).numpy()
    np.testing.assert_allclose(arm.task(q), ARM3R.fk(q)[:, :2], atol=1e-14)


@pytest.mark.parametrize("name", NAMES)
def test_jacobian_matches_finite_differences(name: str) -> None:
    arm = get_smm_arm(name)
    q = _q(arm, 8, seed=1)
    x = arm.task(q)
    jac = arm.jacobian(q)
    assert jac.shape == (8, arm.m, arm.n)
    eps = 1e-6
    for i in range(arm.n):
        dq = torch.zeros(arm.n, dtype=torch.float64)
        dq[i] = eps
        # task_error(q + dq, x(q)) = -(J dq) to first order (angular rows: world-frame rotation).
        fd = (arm.task_error(q - dq, x) - arm.task_error(q + dq, x)) / (2 * eps)
        torch.testing.assert_close(jac[..., i], fd, atol=1e-8, rtol=0)


@pytest.mark.parametrize("name", NAMES)
def test_batched_shapes_numpy_and_errors(name: str) -> None:
    arm = get_smm_arm(name)
    q = _q(arm, 6).reshape(2, 3, arm.n)
    assert arm.fk(q).shape == (2, 3, 4, 4)
    x = arm.task(q)
    assert x.shape == (2, 3, arm.m)
    assert float(arm.fk_error(q, x).abs().max()) < 1e-14
    assert isinstance(arm.task(q.numpy()), np.ndarray)
    # eq. (19): moving the target by 1 % of L along x is a 1 % position error.
    shifted = x.clone()
    shifted[..., 0] += 0.01 * arm.reach
    expect = 0.005 if arm.space == "pose" else 0.01
    torch.testing.assert_close(arm.fk_error(q, shifted), torch.full((2, 3), expect, dtype=torch.float64))
    with pytest.raises(ArmbridgeError, match="q must have shape"):
        arm.fk(torch.zeros(arm.n + 1))
    with pytest.raises(ArmbridgeError, match="location has"):
        arm.task_error(q, torch.zeros(arm.m + 1))


@pytest.mark.parametrize("name", NAMES)
def test_large_and_small_batches_agree(name: str) -> None:
    """Large batches use the batch-last chain, small ones 4x4 products: same numbers."""
    arm = get_smm_arm(name)
    q = _q(arm, 300, seed=4)
    big = arm.kinematics(q)
    small = arm.kinematics(q[:7])
    for a, b in zip(big, small):
        torch.testing.assert_close(a[:7], b, atol=1e-13, rtol=0)
    torch.testing.assert_close(big[1][:7], arm.fk(q[:7])[:, :3, 3], atol=1e-13, rtol=0)


def test_pose_orientation_error_is_angle_over_pi() -> None:
    arm = get_smm_arm("spatial7r")
    q = _q(arm, 4)
    x = arm.task(q)
    r = rot_from_vec(x[:, 3:])
    turn = torch.tensor([0.0, 0.0, 0.3], dtype=torch.float64)
    x2 = torch.cat([x[:, :3], vec_from_rot(rot_from_vec(turn) @ r)], -1)
    torch.testing.assert_close(arm.fk_error(q, x2), torch.full((4,), 0.5 * 0.3 / math.pi, dtype=torch.float64))


def test_rotation_vector_round_trip_including_near_pi() -> None:
    g = torch.Generator().manual_seed(3)
    v = torch.randn(500, 3, generator=g, dtype=torch.float64)
    v = v / v.norm(dim=-1, keepdim=True) * torch.rand(500, 1, generator=g, dtype=torch.float64) * math.pi
    v[0] = 0
    v[1] = torch.tensor([math.pi - 1e-9, 0, 0])
    r = rot_from_vec(v)
    torch.testing.assert_close(rot_from_vec(vec_from_rot(r)), r, atol=1e-12, rtol=0)


def assert_turning_moves_only_the_shift(arm, q: torch.Tensor, joint: int, angle: float, atol: float) -> None:
    """Turning `joint` by `angle` leaves the canonical location and moves shift[joint] by `angle`."""
    c, shift = arm.canonical(arm.task(q))
    turned = q.clone()
    turned[:, joint] += angle
    c2, shift2 = arm.canonical(arm.task(turned))
    torch.testing.assert_close(c2, c, atol=atol, rtol=0)
    moved = torch.remainder(shift2[:, joint] - shift[:, joint] - angle + math.pi, 2 * math.pi) - math.pi
    torch.testing.assert_close(moved, torch.zeros_like(moved), atol=atol, rtol=0)


@pytest.mark.parametrize("name", NAMES)
def test_joint1_rotation_is_canonical_symmetry(name: str) -> None:
    """Turning theta_1 by phi turns the location by phi about base z (section V-B)."""
    arm = get_smm_arm(name)
    q = _q(arm, 10, seed=2)
    x = arm.task(q)
    c, shift = arm.canonical(x)
    assert c.shape == (10, arm.c_dim) and shift.shape == (10, arm.n)
    torch.testing.assert_close(arm.task_error(q, arm.uncanonical(c, shift)), torch.zeros_like(x), atol=1e-12, rtol=0)
    assert_turning_moves_only_the_shift(arm, q, 0, 0.9, atol=1e-12)
    # The canonical location is reached by moving the joints back by the shift.
    back = q - shift
    torch.testing.assert_close(arm.task_error(back, arm.uncanonical(c)), torch.zeros_like(x), atol=1e-12, rtol=0)


def test_spatial7r_canonical_drops_the_tool_roll() -> None:
    """The 7R's joint 7 only rolls the tool: turning it leaves c alone and moves shift[6];
    c = (rho, z, polar, azimuth) of the tool axis."""
    arm = get_smm_arm("spatial7r")
    assert arm.tool_roll and arm.c_dim == 4
    assert not get_smm_arm("spatial4r").tool_roll
    q = _q(arm, 10, seed=4)
    c, shift = arm.canonical(arm.task(q))
    assert_turning_moves_only_the_shift(arm, q, 6, 1.3, atol=1e-10)
    axis = arm.fk(q - shift)[:, :3, 2]  # the tool axis at the canonical location
    polar, azimuth = c[:, 2], c[:, 3]
    torch.testing.assert_close(axis, torch.stack([polar.sin() * azimuth.cos(), polar.sin() * azimuth.sin(),
                                                  polar.cos()], -1), atol=1e-10, rtol=0)
    with pytest.raises(ArmbridgeError, match="one offset per joint"):
        arm.uncanonical(c, shift[:, :3])


def test_spatial7r_last_joint_turns_the_tool_about_its_z() -> None:
    arm = get_smm_arm("spatial7r")
    q = _q(arm, 5)
    t = arm.fk(q)
    q2 = q.clone()
    q2[:, 6] += 0.7
    t2 = arm.fk(q2)
    torch.testing.assert_close(t2[:, :3, 3], t[:, :3, 3])
    rz = rot_from_vec(torch.tensor([0.0, 0.0, 0.7], dtype=torch.float64))
    torch.testing.assert_close(t2[:, :3, :3], t[:, :3, :3] @ rz)


def test_from_planar_and_round_trip() -> None:
    arm = DHChain.from_planar(ARM3R)
    assert arm.space == "xy" and arm.name == "arm3r"
    assert DHChain.from_dict(arm.to_dict()) == arm
    assert set(ARMS) == set(NAMES) | {"soft3"}  # the soft arm is a planar 3R too: it has SMMs


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"a": [1.0, 1.0]}, "alpha has 3 values, a has 2"),
        ({"d": [0.0, "x", 0.0]}, "d must be a list of numbers"),
        ({"alpha": [0.0, float("nan"), 0.0]}, "alpha must be a flat list of finite numbers"),
        ({"theta": [[0.0], [0.0], [0.0]]}, "theta must be a flat list"),
        ({"space": "xz"}, "space must be one of"),
        ({"alpha": [0.0, 0.5, 0.0]}, "space 'xy' needs a planar chain"),
        ({"a": [0.0, 0.0, 0.0]}, "no length"),
        ({"a": []}, "a is empty"),
        ({"name": ""}, "name must be a non-empty string"),
    ],
)
def test_bad_descriptions_raise_clear_errors(change: dict, message: str) -> None:
    d = {"name": "bad", "a": [1.0, 1.0, 1.0], "alpha": [0.0] * 3, "d": [0.0] * 3, "theta": [0.0] * 3, "space": "xy"}
    d.update(change)
    if change.get("a") == []:
        d.update({"alpha": [], "d": [], "theta": []})
    with pytest.raises(ArmbridgeError, match=message):
        DHChain.from_dict(d)


def test_bad_description_keys_and_unknown_robot() -> None:
    with pytest.raises(ArmbridgeError, match="missing keys"):
        DHChain.from_dict({"name": "x", "a": [1.0]})
    with pytest.raises(ArmbridgeError, match="unknown SMM robot 'puma'"):
        get_smm_arm("puma")
