"""MASR model: kinematics, the motion convention, costs and regularisers (masr paper, sections II-III)."""
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbridge.errors import ArmbridgeError
from armbridge.robots import MASR5, MasrArm, get_masr, get_robot
from armbridge.robots.masr import ANGLE_TOL

PI = math.pi
COS5, SIN5 = math.cos(0.5), math.sin(0.5)


def arm(**overrides):
    d = {
        "name": "test4",
        "link_lengths": [0.3, 0.25, 0.2, 0.15],  # r = 0, 0.3, 0.55, 0.75; l = 0.9
        "theta_b": [1.0, 1.0, 1.0, 1.0],
        "ma_speed": 0.1,
        "joint_speed": 0.5,
        "link_width": 0.02,
    }
    d.update(overrides)
    return MasrArm(**d)


def q(*values):
    return np.array(values, dtype=float)


# ------------------------------------------------------------------ description
def test_masr5_is_the_papers_arm():
    assert MASR5.n == 5
    np.testing.assert_allclose(MASR5.link_lengths, [0.2, 0.2, 0.2, 0.1, 0.1])
    np.testing.assert_allclose(MASR5.theta_b, np.full(5, np.deg2rad(50)))
    assert MASR5.ma_speed == 0.1 and MASR5.joint_speed == 0.28
    assert MASR5.total_length == pytest.approx(0.8) and MASR5.l == MASR5.total_length
    np.testing.assert_allclose(MASR5.r, [0, 0.2, 0.4, 0.6, 0.7])
    assert get_masr("MASR5") is MASR5
    assert get_robot("arm3r").name == "arm3r"  # the planar catalog is unchanged
    with pytest.raises(ArmbridgeError, match="unknown MASR 'nope'.*masr5"):
        get_masr("nope")


def test_frozen_arrays():
    with pytest.raises(ValueError):
        MASR5.link_lengths[0] = 1.0
    with pytest.raises(ValueError):
        MASR5.r[0] = 1.0


def test_round_trip_through_json():
    for a in (MASR5, arm()):
        d = json.loads(json.dumps(a.to_dict()))
        assert MasrArm.from_dict(d) == a
        assert hash(MasrArm.from_dict(d)) == hash(a)
    assert set(MASR5.to_dict()) == {"name", "link_lengths", "theta_b", "ma_speed", "joint_speed", "link_width",
                                    "d_margin"}
    assert MASR5.d_margin == 0.005  # the MA firmware's localisation bound (docs/masr.md)
    # older descriptions (model cards, plan files) have no d_margin: the default applies
    old = {k: v for k, v in MASR5.to_dict().items() if k != "d_margin"}
    assert MasrArm.from_dict(old) == MASR5
    assert MasrArm.from_dict({**MASR5.to_dict(), "d_margin": 0.002}) != MASR5


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"name": ""}, "name must be a non-empty string"),
        ({"link_lengths": []}, "link_lengths is empty"),
        ({"link_lengths": [0.3, 0.0, 0.2, 0.1]}, r"link_lengths must all be > 0 m"),
        ({"link_lengths": [0.3, "a", 0.2, 0.1]}, "link_lengths must be a list of numbers"),
        ({"link_lengths": "0.3"}, "link_lengths must be a list of numbers"),
        ({"link_lengths": [[0.3, 0.2]]}, "link_lengths must be a flat list of finite numbers"),
        ({"link_lengths": [0.3, float("nan"), 0.2, 0.1]}, "flat list of finite numbers"),
        ({"theta_b": [1.0, 1.0]}, "theta_b has 2 values, link_lengths has 4"),
        ({"theta_b": [1.0, 0.0, 1.0, 1.0]}, r"theta_b must all be in \(0, pi\]"),
        ({"theta_b": [1.0, 4.0, 1.0, 1.0]}, r"theta_b must all be in \(0, pi\]"),
        ({"ma_speed": 0}, "ma_speed must be > 0 m/s"),
        ({"ma_speed": "fast"}, "ma_speed must be a number"),
        ({"ma_speed": True}, "ma_speed must be a number"),
        ({"joint_speed": -0.2}, "joint_speed must be > 0 rad/s"),
        ({"joint_speed": float("inf")}, "joint_speed must be finite"),
        ({"link_width": -0.01}, "link_width must be >= 0 m"),
        ({"d_margin": -0.001}, r"d_margin must be in \[0, 0.075\) m"),
        ({"d_margin": 0.075}, r"d_margin must be in \[0, 0.075\) m .*shortest link"),
        ({"d_margin": "5mm"}, "d_margin must be a number"),
    ],
)
def test_bad_descriptions(overrides, message):
    with pytest.raises(ArmbridgeError, match=message):
        arm(**overrides)


def test_from_dict_names_missing_and_unknown_keys():
    d = MASR5.to_dict()
    del d["ma_speed"]
    d["speed"] = 1
    with pytest.raises(ArmbridgeError, match=r"missing keys \['ma_speed'\]; unknown keys \['speed'\]"):
        MasrArm.from_dict(d)
    with pytest.raises(ArmbridgeError, match="must be a JSON object, got list"):
        MasrArm.from_dict([1, 2])


# ------------------------------------------------------------------ kinematics
def test_locate_at_the_boundaries():
    # r = 0, 0.3, 0.55, 0.75; l = 0.9
    a = arm()
    j, d_link = a.locate(np.array([0.0, 0.1, 0.3, 0.55, 0.6, 0.75, 0.9]))
    np.testing.assert_array_equal(j, [0, 0, 1, 2, 2, 3, 3])
    np.testing.assert_allclose(d_link, [0.0, 0.1, 0.0, 0.0, 0.05, 0.0, 0.15], atol=1e-15)
    # within POS_TOL off the arm is clamped onto it
    j, d_link = a.locate(np.array([-1e-12, 0.9 + 1e-12]))
    np.testing.assert_array_equal(j, [0, 3])
    np.testing.assert_allclose(d_link, [0.0, 0.15])
    with pytest.raises(ArmbridgeError, match=r"d = 0.95 m is off the arm \[0, 0.9\] m"):
        a.locate([0.2, 0.95])
    with pytest.raises(ArmbridgeError, match="off the arm"):
        a.locate(-0.01)
    with pytest.raises(ArmbridgeError, match="must be finite"):
        a.locate(float("nan"))


@pytest.mark.parametrize(
    "config, pose",
    [
        # straight arm along +x: the MA at d is at (d, 0)
        (q(0, 0, 0, 0, 0, 0.5), (0.5, 0.0, 0.0)),
        # at the base the MA sits on link 1: heading theta_1
        (q(0.3, 0, 0, 0, 0, 0.0), (0.0, 0.0, 0.3)),
        # at joint 2 (d = r_2 = 0.2) the MA is on link 2, d_link = 0: heading theta_1 + theta_2
        (q(0.5, 0.3, 0, 0, 0, 0.2), (0.2 * COS5, 0.2 * SIN5, 0.8)),
        # mid link 1
        (q(0.5, 0.3, 0, 0, 0, 0.1), (0.1 * COS5, 0.1 * SIN5, 0.5)),
        # bent: cumulative angles 0.5, 0, 0.5, 0, 0.5; d = 0.65 is 0.05 m along link 4 (heading 0)
        (q(0.5, -0.5, 0.5, -0.5, 0.5, 0.65), (0.4 * COS5 + 0.25, 0.4 * SIN5, 0.0)),
        # same bend, MA at the tip: on link 5 with d_link = l_5
        (q(0.5, -0.5, 0.5, -0.5, 0.5, 0.8), (0.5 * COS5 + 0.3, 0.5 * SIN5, 0.5)),
    ],
)
def test_fk_hand_worked_masr5(config, pose):
    np.testing.assert_allclose(MASR5.fk(config), pose, atol=1e-12)


def test_fk_square_bend_and_wrap():
    a = arm(link_lengths=[1.0, 1.0, 0.5], theta_b=[PI] * 3)
    # joints at (0,0), (0,1), (1,1); link 3 points up; d = 2.25 is 0.25 m along it
    np.testing.assert_allclose(a.fk(q(PI / 2, -PI / 2, PI / 2, 2.25)), (1.0, 1.25, PI / 2), atol=1e-12)
    np.testing.assert_allclose(
        a.joint_points(q(PI / 2, -PI / 2, PI / 2, 2.25)), [[0, 0], [0, 1], [1, 1], [1, 1.5]], atol=1e-12
    )
    # phi wraps to (-pi, pi]: 3 * 0.8 pi = 2.4 pi -> 0.4 pi
    assert a.fk(q(0.8 * PI, 0.8 * PI, 0.8 * PI, 2.5))[2] == pytest.approx(0.4 * PI)


def test_fk_batches_and_agrees_with_the_polyline():
    rng = np.random.default_rng(1)
    qs = np.concatenate([rng.uniform(-0.8, 0.8, (4, 3, 5)), rng.uniform(0, 0.8, (4, 3, 1))], axis=-1)
    qs[0, 0, -1] = 0.4  # exactly on joint 3
    poses = MASR5.fk(qs)
    assert poses.shape == (4, 3, 3)
    for idx in np.ndindex(4, 3):
        np.testing.assert_allclose(poses[idx], MASR5.fk(qs[idx]), atol=1e-15)
    np.testing.assert_allclose(MASR5.ma_point(qs), poses[..., :2])
    # the MA lies on the polyline: at a joint it is that joint's point
    np.testing.assert_allclose(MASR5.ma_point(qs[0, 0]), MASR5.joint_points(qs[0, 0])[2], atol=1e-15)
    # and the tip of the polyline is the MA at d = l
    tip = qs.copy()
    tip[..., -1] = MASR5.total_length
    np.testing.assert_allclose(MASR5.ma_point(tip), MASR5.joint_points(qs)[..., -1, :], atol=1e-12)


def test_bad_configuration_shape():
    with pytest.raises(ArmbridgeError, match=r"shape \(\.\.\., 6\) = \(theta_1..theta_5, d\), got \(5,\)"):
        MASR5.fk(np.zeros(5))
    with pytest.raises(ArmbridgeError, match="do not broadcast"):
        MASR5.ma_travel(np.zeros((2, 6)), np.zeros((3, 6)))


def test_feasible_eq5():
    b = np.deg2rad(50)
    qs = np.array(
        [
            [0, 0, 0, 0, 0, 0.4],
            [b, -b, b, -b, b, 0.0],  # bounds included
            [0, 0, 0, 0, 0, 0.8],
            [b + 1e-9, 0, 0, 0, 0, 0.4],
            [0, 0, 0, 0, -b - 1e-9, 0.4],
            [0, 0, 0, 0, 0, -1e-9],
            [0, 0, 0, 0, 0, 0.8 + 1e-9],
        ]
    )
    np.testing.assert_array_equal(MASR5.within_limits(qs), [True, True, True, False, False, False, False])
    assert MASR5.within_limits(qs.reshape(7, 1, 6)).shape == (7, 1)


# ------------------------------------------------------------ motion convention
def test_fig3b():
    """Fig. 3b: D_a = d_link + 2 l_1 + l_2.

    The text puts the MA on link 3 at d_c = r_3 + d_link = l_1 + l_2 + d_link,
    with joints 1 and 2 to be turned. If delta d > 0 the MA would sweep down to
    joint 1 and then up past d_c: D_a = d_c + d_f > 2 d_c, too long. So
    delta d <= 0: no actuated joint lies above d_c, the MA drives down to
    joint 2 (l_2 + d_link, step 1), turns it (2), drives on to joint 1 (l_1, 3),
    turns it (4) and drives back up to its final place d_f (5). The sum
    l_2 + d_link + l_1 + d_f equals d_link + 2 l_1 + l_2 only for d_f = l_1 = r_2:
    the figure's MA ends on joint 2. (Turning joint 1 alone gives the same D_a,
    since the MA passes joint 2 anyway.)
    """
    a = arm()
    l1, l2, d_link = 0.3, 0.25, 0.07
    q_c = q(0, 0, 0, 0, l1 + l2 + d_link)
    q_d = q(0.2, -0.3, 0, 0, l1)
    expected = d_link + 2 * l1 + l2
    assert a.ma_travel(q_c, q_d) == pytest.approx(expected)
    assert a.action_sequence(q_c, q_d) == [
        ("move", l1 + l2 + d_link, l1),
        ("rotate", 2, 0.0, -0.3),
        ("move", l1, 0.0),
        ("rotate", 1, 0.0, 0.2),
        ("move", 0.0, l1),
    ]
    assert a.ma_travel(q_c, q(0.2, 0, 0, 0, l1)) == pytest.approx(expected)  # joint 1 alone
    # the same joints with the MA ending further out (delta d > 0): down to joint 1, then out
    assert a.ma_travel(q_c, q(0.2, -0.3, 0, 0, 0.7)) == pytest.approx(l1 + l2 + d_link + 0.7)


@pytest.mark.parametrize(
    "q_c, q_d, travel",
    [
        (q(0, 0, 0, 0, 0.4), q(0, 0, 0, 0, 0.4), 0.0),  # nothing to do
        (q(0, 0, 0, 0, 0.4), q(0, 0, 0, 0, 0.85), 0.45),  # pure MA move out
        (q(0, 0, 0, 0, 0.4), q(0, 0, 0, 0, 0.1), 0.3),  # pure MA move in
        (q(0, 0, 0, 0, 0.3), q(0, 0.5, 0, 0, 0.3), 0.0),  # the joint under the MA: no travel
        (q(0, 0, 0, 0, 0.3), q(0, 0.5, 0, 0, 0.5), 0.2),  # ... then a move
        (q(0, 0, 0, 0, 0.4), q(0, 0, 0, 1e-10, 0.4), 0.0),  # below ANGLE_TOL: not actuated
        # delta d > 0: down to joint 1 (0.4), up to joint 4 (0.75), back to 0.6 (0.15)
        (q(0, 0, 0, 0, 0.4), q(0.1, 0, 0, 0.1, 0.6), 1.3),
        # delta d < 0: up to joint 4 (0.35), down to joint 1 (0.75), up to 0.35 (0.35)
        (q(0, 0, 0, 0, 0.4), q(0.1, 0, 0, 0.1, 0.35), 1.45),
        # delta d = 0 counts as <= 0: up first
        (q(0, 0, 0, 0, 0.4), q(0.1, 0, 0, 0.1, 0.4), 1.5),
        # delta d > 0 with only joints above: straight out, via joint 4
        (q(0, 0, 0, 0, 0.1), q(0, 0, 0.1, 0.1, 0.9), 0.8),
        # delta d > 0 past the farthest joint below: down then straight out
        (q(0, 0, 0, 0, 0.4), q(0, 0.1, 0, 0, 0.9), 0.1 + 0.6),
    ],
)
def test_ma_travel_examples(q_c, q_d, travel):
    a = arm()
    assert a.ma_travel(q_c, q_d) == pytest.approx(travel, abs=1e-12)
    moves = [abs(s[2] - s[1]) for s in a.action_sequence(q_c, q_d) if s[0] == "move"]
    assert sum(moves) == pytest.approx(travel, abs=1e-12)


def test_sequence_both_directions_by_hand():
    a = arm()
    assert a.action_sequence(q(0, 0, 0, 0, 0.4), q(0.1, 0, 0, 0.2, 0.6)) == [
        ("move", 0.4, 0.0),
        ("rotate", 1, 0.0, 0.1),
        ("move", 0.0, 0.75),
        ("rotate", 4, 0.0, 0.2),
        ("move", 0.75, 0.6),
    ]
    assert a.action_sequence(q(0, 0, 0, 0, 0.4), q(0.1, 0, 0, 0.2, 0.35)) == [
        ("move", 0.4, 0.75),
        ("rotate", 4, 0.0, 0.2),
        ("move", 0.75, 0.0),
        ("rotate", 1, 0.0, 0.1),
        ("move", 0.0, 0.35),
    ]
    # joints at d_c are turned first; the others nearest first within a group
    assert a.action_sequence(q(0, 0, 0, 0, 0.55), q(0.1, 0.2, 0.3, 0, 0.6)) == [
        ("rotate", 3, 0.0, 0.3),
        ("move", 0.55, 0.3),
        ("rotate", 2, 0.0, 0.2),
        ("move", 0.3, 0.0),
        ("rotate", 1, 0.0, 0.1),
        ("move", 0.0, 0.6),
    ]
    assert a.action_sequence(q(0, 0, 0, 0, 0.4), q(0, 0, 0, 0, 0.4)) == []
    with pytest.raises(ArmbridgeError, match="single configurations"):
        a.action_sequence(np.zeros((2, 5)), np.zeros((2, 5)))


def test_joint_within_pos_tol_of_the_ma_needs_no_move():
    # r_4 = 0.2 + 0.2 + 0.2 = 0.6000000000000001 in floating point; d = 0.6 is on joint 4
    q_c, q_d = q(0, 0, 0, 0, 0, 0.6), q(0, 0, 0, 0.3, 0, 0.6)
    assert MASR5.action_sequence(q_c, q_d) == [("rotate", 4, 0.0, 0.3)]
    assert MASR5.ma_travel(q_c, q_d) == 0.0


def test_intermediate_configs():
    a = arm()
    q_c, q_d = q(0, 0, 0, 0, 0.4), q(0.1, 0, 0, 0.2, 0.6)
    np.testing.assert_allclose(
        a.intermediate_configs(q_c, q_d),
        [
            [0, 0, 0, 0, 0.0],
            [0.1, 0, 0, 0, 0.0],
            [0.1, 0, 0, 0, 0.75],
            [0.1, 0, 0, 0.2, 0.75],
            [0.1, 0, 0, 0.2, 0.6],
        ],
    )
    assert a.intermediate_configs(q_c, q_c).shape == (0, 5)
    # a sub-tolerance joint change is not a step, but the last row is still q_d exactly
    q_d2 = q(0.1, 0, 1e-12, 0.2, 0.6)
    assert len(a.action_sequence(q_c, q_d2)) == 5
    np.testing.assert_array_equal(a.intermediate_configs(q_c, q_d2)[-1], q_d2)


def _pair(draw_floats, actuate):
    """q_c, q_d on MASR5 from hypothesis draws; joints not actuated are equal bit for bit."""
    b = MASR5.theta_b
    th_c = np.array(draw_floats[:5]) * b
    th_d = np.where(actuate, np.array(draw_floats[5:10]) * b, th_c)
    th_d = np.where(np.abs(th_d - th_c) > ANGLE_TOL, th_d, th_c)
    d_c, d_d = draw_floats[10] * MASR5.total_length, draw_floats[11] * MASR5.total_length
    return np.append(th_c, d_c), np.append(th_d, d_d)


UNIT = st.floats(-1, 1, allow_nan=False)
POS = st.one_of(st.floats(0, 1, allow_nan=False), st.sampled_from([0.0, 0.25, 0.5, 0.75, 0.875, 1.0]))


@settings(max_examples=300, deadline=None)
@given(
    angles=st.lists(UNIT, min_size=10, max_size=10),
    positions=st.lists(POS, min_size=2, max_size=2),
    actuate=st.lists(st.booleans(), min_size=5, max_size=5),
)
def test_sequence_reproduces_q_d_and_its_moves_sum_to_d_a(angles, positions, actuate):
    q_c, q_d = _pair(angles + positions, np.array(actuate))
    steps = MASR5.action_sequence(q_c, q_d)
    cur = q_c.copy()
    travelled = 0.0
    rotated = []
    for step in steps:
        if step[0] == "move":
            assert step[1] == cur[-1]  # moves chain up
            assert step[1] != step[2]
            travelled += abs(step[2] - step[1])
            cur[-1] = step[2]
        else:
            _, j, th_from, th_to = step
            assert 1 <= j <= 5 and th_from == cur[j - 1]
            assert abs(cur[-1] - MASR5.r[j - 1]) <= 1e-9  # turned only from its own joint
            assert abs(th_to - th_from) > ANGLE_TOL
            cur[j - 1] = th_to
            rotated.append(j)
    np.testing.assert_array_equal(cur, q_d)  # exactly
    assert travelled == pytest.approx(float(MASR5.ma_travel(q_c, q_d)), abs=1e-12)
    assert sorted(rotated) == [k + 1 for k in np.flatnonzero(np.abs(q_d[:5] - q_c[:5]) > ANGLE_TOL)]
    # the convention: the group away from the final position comes first
    d_c, delta = q_c[-1], q_d[-1] - q_c[-1]
    away = [j for j in rotated if (MASR5.r[j - 1] < d_c - 1e-9 if delta > 0 else MASR5.r[j - 1] > d_c + 1e-9)]
    toward = [j for j in rotated if (MASR5.r[j - 1] > d_c + 1e-9 if delta > 0 else MASR5.r[j - 1] < d_c - 1e-9)]
    if away and toward:
        assert max(rotated.index(j) for j in away) < min(rotated.index(j) for j in toward)
    configs = MASR5.intermediate_configs(q_c, q_d)
    assert configs.shape == (len(steps), 6)
    if steps:
        np.testing.assert_array_equal(configs[-1], q_d)


def test_ma_travel_and_costs_vectorise():
    rng = np.random.default_rng(7)
    b = MASR5.theta_b
    n_pairs = 2000
    th = rng.uniform(-b, b, (n_pairs, 2, 5))
    th[:, 1] = np.where(rng.random((n_pairs, 5)) < 0.5, th[:, 0], th[:, 1])  # about half the joints still
    d = rng.uniform(0, 0.8, (n_pairs, 2, 1))
    qs = np.concatenate([th, d], axis=-1)
    q_c, q_d = qs[:, 0], qs[:, 1]
    travel = MASR5.ma_travel(q_c, q_d)
    cost = MASR5.action_cost(q_c, q_d)
    assert travel.shape == cost.shape == (n_pairs,)
    for i in range(0, n_pairs, 97):
        moves = [abs(s[2] - s[1]) for s in MASR5.action_sequence(q_c[i], q_d[i]) if s[0] == "move"]
        assert travel[i] == pytest.approx(sum(moves), abs=1e-12)
        assert cost[i] == pytest.approx(MASR5.action_cost(q_c[i], q_d[i]))
    # one node against many candidates broadcasts
    np.testing.assert_allclose(MASR5.action_cost(q_c[0], q_d), MASR5.action_cost(np.broadcast_to(q_c[0], q_d.shape), q_d))
    np.testing.assert_allclose(MASR5.reg_action(q_c[0], q_d)[:3], [MASR5.reg_action(q_c[0], q_d[i]) for i in range(3)])


# ------------------------------------------------------------------------ costs
def test_action_cost_and_path_time_by_hand():
    # MASR5, d-dot 0.1 m/s, theta-dot 0.28 rad/s. MA at 0.3 turns joint 1 by 0.28 rad and comes back:
    # D_a = 0.3 + 0.3 = 0.6 m -> 6 s; 0.28 rad -> 1 s.
    q0 = q(0, 0, 0, 0, 0, 0.3)
    q1 = q(0.28, 0, 0, 0, 0, 0.3)
    assert MASR5.action_cost(q0, q1) == pytest.approx(7.0)
    # then drive to joint 3 (0.1 m, 1 s), turn it by -0.14 rad (0.5 s), drive to the tip (0.4 m, 4 s)
    q2 = q(0.28, 0, -0.14, 0, 0, 0.8)
    assert MASR5.action_cost(q1, q2) == pytest.approx(5.5)
    assert MASR5.path_time(np.stack([q0, q1, q2])) == pytest.approx(12.5)
    assert MASR5.path_time(q0[None]) == 0.0
    assert MASR5.path_time(np.stack([np.stack([q0, q1, q2])] * 4)).shape == (4,)
    with pytest.raises(ArmbridgeError, match=r"path must have shape \(\.\.\., K, 6\) with K >= 1"):
        MASR5.path_time(q0)
    with pytest.raises(ArmbridgeError, match="K >= 1"):
        MASR5.path_time(np.zeros((0, 6)))


def test_regularisers_by_hand():
    q_c = q(0, 0, 0, 0, 0, 0.3)
    q_d = q(0.1, -0.2, 0, 0, 0.05, 0.7)
    assert MASR5.reg_joint(q_c, q_d) == pytest.approx(0.35)
    # r = 0, 0.2, 0.4, 0.6, 0.7; |d_c - r| = 0.3, 0.1, 0.1, 0.3, 0.4 m
    expected = (0.1 * 0.3 + 0.2 * 0.1 + 0.05 * 0.4) / (0.28 * 0.1)
    assert MASR5.reg_action(q_c, q_d) == pytest.approx(expected)
    assert MASR5.reg_action(q_c, q_c) == 0.0


def test_fig4c_regulariser():
    """Fig. 4c: 5R with l_1..3 = l, l_4,5 = 0.5 l; q_c = (0, 1.5 l), q~ = (a, 2a, -3a, -3a, 2a, 2.5 l).

    MASR5 is exactly this arm with l = 0.2 m. Eq. (12) with r_i = l_1 + ... + l_{i-1}
    (r = 0, l, 2l, 3l, 3.5l) and the current d_c = 1.5 l: distances 1.5, 0.5, 0.5,
    1.5, 2.0 l, turns 1, 2, 3, 3, 2 a, so 1.5 + 1 + 1.5 + 4.5 + 4 = 12.5 tau_l tau_theta.
    The paper prints 13.5; that is eq. (12) for five links of length l (r_5 = 4l,
    joint 5 at 2.5 l from the MA) - see docs/masr.md.
    """
    l, alpha = 0.2, 0.1
    tau_l, tau_theta = l / MASR5.ma_speed, alpha / MASR5.joint_speed
    q_c = q(0, 0, 0, 0, 0, 1.5 * l)
    q_t = q(alpha, 2 * alpha, -3 * alpha, -3 * alpha, 2 * alpha, 2.5 * l)
    assert MASR5.within_limits(q_t)
    assert MASR5.reg_action(q_c, q_t) == pytest.approx(12.5 * tau_l * tau_theta)
    assert MASR5.reg_joint(q_c, q_t) == pytest.approx(11 * alpha)
    uniform = MasrArm.from_dict({**MASR5.to_dict(), "name": "uniform5", "link_lengths": [l] * 5})
    assert uniform.reg_action(q_c, q_t) == pytest.approx(13.5 * tau_l * tau_theta)


# ------------------------------------------------------------------ joint margin
def test_joint_clearance_and_margin_range():
    a = arm()  # r = 0, 0.3, 0.55, 0.75; l = 0.9; d_margin 5 mm
    np.testing.assert_allclose(a.joint_clearance([0.0, 0.29, 0.3, 0.5, 0.9]), [0.3, 0.01, 0.0, 0.05, 0.15])
    assert a.holds_margin([0.0, 0.295, 0.9, 0.555]).tolist() == [True, True, True, True]  # the ends are no joints
    assert a.holds_margin([0.2951, 0.3, 0.5549, 0.3 + 1e-12]).tolist() == [False] * 4
    lo, hi = a.margin_range(np.arange(4))
    np.testing.assert_allclose(lo, [0.0, 0.305, 0.555, 0.755], atol=2e-9)
    np.testing.assert_allclose(hi, [0.295, 0.545, 0.745, 0.9], atol=2e-9)
    assert np.all(a.holds_margin(lo)) and np.all(a.holds_margin(hi))
    one = MasrArm(name="one", link_lengths=np.array([0.5]), theta_b=np.array([1.0]), ma_speed=0.1,
                  joint_speed=0.5, link_width=0.0)
    assert one.joint_clearance(0.25) == np.inf and one.holds_margin(0.0)


@settings(max_examples=200, deadline=None)
@given(angles=st.lists(UNIT, min_size=5, max_size=5), u=st.floats(0, 1), goal=st.lists(UNIT, min_size=3, max_size=3))
def test_span_pose_errors_are_the_worst_over_the_margin(angles, u, goal):
    """span_pose_errors = the max of fk's errors over a dense sweep of [d - m, d + m] (d holding the margin)."""
    th = np.array(angles) * MASR5.theta_b
    link = int(u * 4.999)
    lo, hi = MASR5.margin_range(link)
    d = float(lo + (hi - lo) * ((u * 4.999) % 1))
    x_goal = MASR5.fk(np.r_[th, d]) + np.array(goal) * [0.01, 0.01, 0.05]
    dp, dphi = MASR5.span_pose_errors(np.r_[th, d], x_goal)
    m = MASR5.d_margin
    sweep = np.clip(np.linspace(d - m, d + m, 401), 0, MASR5.total_length)
    qs = np.tile(np.r_[th, d], (sweep.size, 1))
    qs[:, -1] = sweep
    x = MASR5.fk(qs)
    ref_dp = np.linalg.norm(x[:, :2] - x_goal[:2], axis=1)
    ref_dphi = np.abs((x[:, 2] - x_goal[2] + np.pi) % (2 * np.pi) - np.pi)
    assert np.all(MASR5.locate(sweep)[0] == link)  # the margin keeps the whole interval on the link
    assert dp == pytest.approx(ref_dp.max(), abs=1e-12)
    assert dphi == pytest.approx(ref_dphi.max(), abs=1e-12) and np.ptp(ref_dphi) < 1e-12  # constant heading
    ok = MASR5.reaches(np.r_[th, d], x_goal, 0.008, math.radians(4))
    assert ok == bool((ref_dp.max() <= 0.008) & (ref_dphi.max() <= math.radians(4)))


def test_reaches_refuses_an_answer_on_a_joint():
    q_on = np.array([0.2, 0.1, -0.3, 0.2, 0.1, 0.6])  # exactly on joint 4
    goal = MASR5.fk(q_on)
    assert not MASR5.reaches(q_on, goal, 0.008, math.radians(4))
    assert MASR5.reaches(q_on, goal, 0.008, math.radians(4), margin=0.0)  # eq. (9) alone accepts it
    q_in = q_on.copy()
    q_in[-1] = 0.65  # mid-link: exact, and 5 mm either way stays within 8 mm
    assert MASR5.reaches(q_in, MASR5.fk(q_in), 0.008, math.radians(4))
