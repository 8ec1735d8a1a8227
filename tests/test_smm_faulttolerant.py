"""SMM bounding boxes (smm/bbox.py), motions into them and locked-joint recovery (smm/faulttolerant.py),
and the Fig. 15-16 simulation (smm/simulate.py)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from armbridge.errors import ArmbridgeError
from armbridge.smm import bbox
from armbridge.smm import faulttolerant as ft
from armbridge.smm import nullspace
from armbridge.smm import simulate as sim
from armbridge.smm.arms import get_smm_arm
from armbridge.smm.manifold import SmmSet

torch.set_num_threads(1)
PI = math.pi


def smm_of(curves: list[np.ndarray]) -> SmmSet:
    """An SmmSet of one location from hand-made closed curves of equal length."""
    pts = np.stack(curves)[None]
    return SmmSet(ft.wrap(pts), np.array([len(curves)]), np.array([False]))


def ellipse(center, radii, n=200) -> np.ndarray:
    t = np.linspace(0, 2 * PI, n, endpoint=False)
    return np.asarray(center) + np.c_[radii[0] * np.cos(t), radii[1] * np.sin(t), radii[2] * np.sin(2 * t)]


# ---------------------------------------------------------------- arcs and boxes


def test_arc_of_a_curve_across_pi():
    t = np.linspace(0, 2 * PI, 64)
    lo, w = bbox.curve_arc(ft.wrap(3.0 + 0.5 * np.sin(t)))
    assert lo == pytest.approx(2.5, abs=1e-3) and w == pytest.approx(1.0, abs=1e-3)


def test_a_winding_joint_gets_the_full_circle():
    t = np.linspace(-PI, PI, 50)  # one whole turn, the first sample repeated at the end
    assert bbox.curve_arc(t)[1] == 2 * PI
    # Not winding, but swinging over more than a turn and back: also every angle.
    s = np.linspace(0, 2 * PI, 100)
    assert bbox.curve_arc(ft.wrap(3.3 * np.sin(s)))[1] == 2 * PI
    assert bbox.curve_arc(ft.wrap(3.0 * np.sin(s)))[1] == pytest.approx(6.0, abs=1e-3)


def test_arc_hull_keeps_out_the_largest_gap():
    assert bbox.arc_hull([(0.0, 1.0), (2.0, 1.0)]) == pytest.approx((0.0, 3.0))
    lo, w = bbox.arc_hull([(3.0, 1.0), (-3.0, 1.0)])  # across pi: from 3 to -2
    assert lo == pytest.approx(3.0) and w == pytest.approx(2 * PI - 5.0)
    assert bbox.Box(np.array([lo]), np.array([w])).contains(np.array([[PI], [-2.1], [-3.05]])).all()
    assert bbox.arc_hull([(0.0, 1.0), (0.5, 1.0)]) == pytest.approx((0.0, 1.5))
    assert bbox.arc_hull([(0.0, 4.0), (3.5, 3.0)])[1] == 2 * PI  # together they cover the circle


def test_box_contains_across_the_wrap():
    box = bbox.Box(np.array([3.0, -1.0]), np.array([1.0, 2 * PI]))
    q = np.array([[3.1, 0.0], [-3.1, 3.0], [-2.3, 1.0], [-2.2, 0.0], [2.9, 0.0]])
    assert box.contains(q).tolist() == [True, True, True, False, False]


def test_branch_and_location_boxes():
    a = ellipse([0.0, 1.0, -1.0], [0.5, 0.4, 0.3])
    b = ellipse([3.0, -2.0, 2.0], [0.3, 0.3, 0.3])  # joint 1 crosses pi
    smm = smm_of([a, b])
    boxes = bbox.branch_boxes(smm, 0)
    assert len(boxes) == 2
    np.testing.assert_allclose(boxes[0].lo, [-0.5, 0.6, -1.3], atol=1e-3)
    np.testing.assert_allclose(boxes[0].width, [1.0, 0.8, 0.6], atol=1e-3)
    assert boxes[1].contains(ft.wrap(b)).all() and boxes[0].contains(a).all()
    assert boxes[1].width[0] == pytest.approx(0.6, abs=1e-3)  # not the long way round
    loc = bbox.location_box(smm, 0)
    assert loc is not None and loc.contains(ft.wrap(np.vstack([a, b]))).all()
    empty = SmmSet(np.full((1, 1, 4, 3), np.nan), np.array([0]), np.array([False]))
    assert bbox.location_box(empty, 0) is None and bbox.branch_boxes(empty, 0) == []


def test_intersections():
    assert bbox.intersect_arcs((0.0, 1.0), (2.0, 1.0)) == []
    two = bbox.intersect_arcs((0.0, 5.0), (3.0, 5.0))  # overlapping at both ends
    np.testing.assert_allclose(sorted(two), [(0.0, 5.0 - (2 * PI - 3.0)), (3.0, 2.0)])
    assert bbox.intersect_arcs((1.0, 2 * PI), (0.5, 1.0)) == [(0.5, 1.0)]
    # Fig. 2b: the box of a's SMM against the two boxes of b's branches.
    box_a = bbox.Box(np.array([-1.0, -1.0]), np.array([2.0, 2.0]))
    box_b1 = bbox.Box(np.array([0.5, -3.0]), np.array([1.0, 2.5]))
    box_b2 = bbox.Box(np.array([0.5, 3.0]), np.array([1.0, 1.0]))  # misses a on joint 2
    regions = bbox.intersect_all([[box_a], [box_b1, box_b2]])
    assert len(regions) == 1
    np.testing.assert_allclose(regions[0].lo, [0.5, -1.0])
    np.testing.assert_allclose(regions[0].width, [0.5, 0.5])
    assert bbox.intersect_all([[box_a], [box_b2]]) == []
    with pytest.raises(ArmbridgeError, match="at least one task point"):
        bbox.intersect_all([])


def test_clipping_to_limits_is_an_intersection():
    box = bbox.Box(np.array([2.5, -0.5]), np.array([1.5, 1.0]))
    clipped = bbox.intersect_boxes(box, bbox.limits_box((np.array([0.0, -PI]), np.array([PI, 0.0]))))
    assert len(clipped) == 1
    np.testing.assert_allclose(clipped[0].lo, [2.5, -0.5])
    np.testing.assert_allclose(clipped[0].width, [PI - 2.5, 0.5])
    with pytest.raises(ArmbridgeError, match="joint 2"):
        bbox.limits_box((np.array([0.0, 1.0]), np.array([1.0, 0.5])))


def test_runs_within_limits_get_their_own_boxes():
    a = ellipse([0.0, 1.0, 0.0], [1.0, 0.5, 0.5])
    lims = (np.array([-0.5, -PI, -PI]), np.array([2.0, PI, PI]))  # cuts joint 1 at -0.5
    smm = smm_of([a])
    curves = bbox.smm_curves(smm, 0, lims)
    assert len(curves) == 1 and (curves[0][:, 0] >= -0.5).all()
    lims2 = (np.array([-0.5, -PI, -0.2]), np.array([2.0, PI, 0.2]))  # joint 3 too: the branch falls apart
    pieces = bbox.smm_curves(smm, 0, lims2)
    assert len(pieces) > 1
    for piece, box in zip(pieces, bbox.branch_boxes(smm, 0, lims2)):
        assert box.contains(piece).all()
        assert (box.width[2] <= 0.4 + 1e-9) and (box.width[0] <= 2.5)
    whole = bbox.smm_curves(smm, 0, (np.full(3, -PI), np.full(3, PI)))
    assert len(whole) == 1 and len(whole[0]) == len(a) + 1  # closed


# ---------------------------------------------------------------- motions


def test_entry_is_time_optimal_under_speed_limits():
    box = bbox.Box(np.array([2.8, -0.2, 1.0]), np.array([0.6, 0.4, 2 * PI]))
    vmax = np.array([1.0, 0.5, 2.0])
    q = np.array([-2.5, 1.0, 0.3])  # joint 1: 0.38 rad down to the arc through pi; joint 2: 0.8 down
    move = ft.entry_move(q, box, vmax)
    np.testing.assert_allclose(move.goal - q, [3.4 - 2 * PI + 2.5, -0.8, 0.0], atol=1e-12)
    assert move.duration == pytest.approx(0.8 / 0.5)
    assert box.contains(move.goal)
    assert (np.abs(move.goal - move.start) / move.duration <= vmax + 1e-12).all()
    # No faster way in: the slowest joint's own shortest time to its arc (brute force).
    own = [np.abs(ft.wrap(box.lo[j] + np.linspace(0, box.width[j], 2001) - q[j])).min() / vmax[j] for j in range(3)]
    assert move.duration == pytest.approx(max(own), abs=1e-3)
    assert ft.entry_move(move.goal, box, vmax).duration == pytest.approx(0.0, abs=1e-9)


def test_entry_under_limits_never_crosses_a_stop():
    box = bbox.Box(np.array([-3.0]), np.array([0.5]))  # just past -pi
    q = np.array([3.0])
    free = ft.entry_move(q, box, 1.0)  # the short way, through pi
    assert free.duration == pytest.approx(2 * PI - 6.0) and free.goal[0] == pytest.approx(2 * PI - 3.0)
    limited = ft.entry_move(q, box, 1.0, (np.array([-PI]), np.array([PI])))
    assert limited.goal[0] == pytest.approx(-2.5) and limited.duration == pytest.approx(5.5)
    out = ft.entry_move(np.array([1.0]), box, 1.0, (np.array([0.0]), np.array([2.0])))
    assert out.duration == math.inf
    with pytest.raises(ArmbridgeError, match="speed limits"):
        ft.entry_move(q, box, 0.0)


def test_motion_inside_a_box_stays_inside():
    box = bbox.Box(np.array([2.0, -1.0]), np.array([4.0, 2 * PI]))  # joint 1 from 2 round past pi to 6 - 2 pi
    q_from, q_to = np.array([2.2, 3.0]), np.array([-0.5, -3.0])
    move = ft.move_within(box, q_from, q_to, 1.0)
    assert box.contains(move.at(np.linspace(0, move.duration, 50))).all()
    np.testing.assert_allclose(ft.wrap(move.goal), q_to)
    assert move.goal[0] - q_from[0] == pytest.approx(2 * PI - 2.7)  # the way through pi, not through 0
    assert abs(move.goal[1] - q_from[1]) < 0.3  # full circle: the short way


# ---------------------------------------------------------------- recovery on real SMMs


@pytest.fixture(scope="module")
def planar():
    arm = get_smm_arm("planar3r")
    x = np.array([[0.3, 0.0], [1.5, 1.2], [-2.0, 0.5]])  # 2 branches, then 1, then 1
    return arm, x, nullspace.compute(arm, x, seed=1)


def test_locked_configurations_keep_the_value_and_reach_the_target(planar):
    arm, x, smm = planar
    assert smm.count.tolist() == [2, 1, 1]
    for l in range(len(x)):
        for j, box in [(j, box) for j in range(3) for box in bbox.branch_boxes(smm, l)]:
            v = float(box.lo[j] + 0.37 * box.width[j])
            configs = ft.locked_configurations(smm, l, j, v)
            assert len(configs) >= 2  # a closed branch crosses each value it takes at least twice
            np.testing.assert_allclose(configs[:, j], ft.wrap(v), atol=1e-12)
            err = np.linalg.norm(arm.task_error(configs, np.tile(x[l], (len(configs), 1))), axis=-1)
            assert err.max() < 5e-3 * arm.reach  # interpolation between samples
            q = sim.refine(arm, configs[0], x[l], np.arange(3) != j, 5)
            assert q[j] == configs[0][j] and sim.tip_error(arm, q, x[l]) < 1e-9


def test_a_lock_inside_the_box_is_always_recoverable(planar):
    arm, x, smm = planar
    rng = np.random.default_rng(3)
    for l in range(len(x)):
        for box in bbox.branch_boxes(smm, l):
            for _ in range(20):
                q = box.lo + rng.uniform(0, 1, 3) * box.width
                j = int(rng.integers(3))
                move = ft.recover(smm, l, q, j, 1.0)
                assert move is not None and move.goal[j] == q[j]
                q_end = sim.refine(arm, move.goal, x[l], np.arange(3) != j, 5)
                assert sim.tip_error(arm, q_end, x[l]) < 1e-9


def test_a_lock_outside_every_range_is_not(planar):
    arm, x, smm = planar
    loc = bbox.location_box(smm, 0)  # r = 0.3: joint 2 never straightens
    j = 1
    assert loc.width[j] < 2 * PI
    v = float(loc.lo[j] + loc.width[j] + 0.5 * (2 * PI - loc.width[j]))
    q = loc.lo + 0.5 * loc.width
    q[j] = v
    assert ft.locked_configurations(smm, 0, j, v).shape == (0, 3)
    assert ft.recover(smm, 0, q, j, 1.0) is None
    with pytest.raises(ArmbridgeError, match="joint 4"):
        ft.recovery_move(q, 3, np.zeros((1, 3)), 1.0)


def test_approach_ends_on_the_smm_inside_its_box(planar):
    arm, x, smm = planar
    q = np.array([0.1, 0.2, 0.3])
    curves = bbox.smm_curves(smm, 1)
    ap = ft.approach(q, curves, 1.0)
    assert ap.box.contains(ap.entry.goal) and ap.box.contains(ap.inside.goal)
    assert ap.box.contains(ap.inside.at(np.linspace(0, ap.inside.duration, 30))).all()
    assert sim.tip_error(arm, ap.inside.goal, x[1]) < 1e-6
    with pytest.raises(ArmbridgeError, match="out of reach"):
        ft.approach(q, [], 1.0)


# ---------------------------------------------------------------- the simulation


@pytest.fixture(scope="module")
def trials():
    arm = get_smm_arm("planar3r")
    draws = sim.draw_trials(arm, 60, seed=7)
    return arm, draws, nullspace.compute(arm, draws.x, seed=7)


def test_simulation_with_no_latency_succeeds(trials):
    arm, draws, smm = trials
    out = sim.simulate(arm, smm, draws, 0.0)
    again = sim.simulate(arm, smm, draws, 0.0)
    assert out == again  # deterministic
    assert out.out_of_reach == 0 and out.rate >= 0.85
    assert out.recovered >= 5 and out.in_box_at_lock >= 3


def test_every_lock_inside_the_box_is_recovered(trials):
    arm, draws, smm = trials
    times, paths = np.zeros(1), draws.q0[None]
    for l in range(len(draws)):
        how, in_box = sim.run_trial(arm, smm, l, draws, 0.0, times, paths[:, l], sim.Scenario())
        assert not in_box or how == "recovered"


def test_a_long_latency_lowers_the_success_rate(trials):
    arm, draws, smm = trials
    fast = sim.simulate(arm, smm, draws, 0.0014)  # the paper's learned method
    slow = sim.simulate(arm, smm, draws, 4.3)  # its nullspace method on the 7R
    assert slow.rate < fast.rate
    assert slow.before_lock < fast.before_lock


def test_compare_uses_the_same_trials():
    arm = get_smm_arm("planar3r")
    res = sim.compare(arm, {"a": 0.0, "b": 0.0}, trials=5, seed=2)
    assert res["a"] == res["b"] and res["a"].trials == 5
    assert set(res["a"].to_dict()) >= {"success_rate", "latency_s", "recovered"}


def test_bad_inputs_are_refused(trials):
    arm, draws, smm = trials
    with pytest.raises(ArmbridgeError, match="latency"):
        sim.simulate(arm, smm, draws, -1.0)
    with pytest.raises(ArmbridgeError, match="vmax"):
        sim.Scenario(vmax=0.0)
    with pytest.raises(ArmbridgeError, match="trials"):
        sim.draw_trials(arm, 0, 1)
    with pytest.raises(ArmbridgeError, match="locations"):
        sim.simulate(arm, smm, sim.draw_trials(arm, 3, 1), 0.0)
