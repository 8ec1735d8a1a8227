"""The soft arm's plans for the pump board (planning/soft/waypoints.py, plan_file.py, `armbridge plan
soft`) and the demo end to end: WJRRT on the three-arm scene, executed by the pump board's real .elf in
simavr (`emu:arduino_pump?speed=0`), the recording read back with rerun's own reader.

The waypoint criterion is checked on hand-worked cases: a joint-3-only excursion whose shape
distance is the tip's chord 2 l sin(theta / 2), a detour around an obstacle, the dead-band snapping
and its collision re-check, the timing model against the pneumatic plant itself.
"""
from __future__ import annotations

import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from armbridge.emulator.pump_plant import PumpParams, PumpPlant
from armbridge.errors import ArmbridgeError
from armbridge.planning.soft import waypoints as W
from armbridge.planning.soft.space import ChainChecker
from armbridge.robots import SOFT3

L = SOFT3.link_lengths
FREE = ChainChecker.create(SOFT3, [])


class Cfg:
    """The pump firmware's constants (config.h) that the timing model reads."""

    DBAND_DEFAULT_MRAD = 70
    KP_DEFAULT = 4000
    KP_INFLATE_PERMILLE = 600
    DUTY_MAX_INFLATE = 700
    DUTY_MAX_DEFLATE = 1000
    DUTY_MIN = 120


def chord(theta: float, length: float = 0.1) -> float:
    """How far the tip of a last link of `length` moves when its joint turns by theta."""
    return 2 * length * math.sin(theta / 2)


# ---------------------------------------------------------------- (a) the tracking error

def test_the_shape_distance_of_a_last_joint_turn_is_the_tips_chord():
    assert W.shape_distance(L, [0, 0, 0], [0, 0, 0.3]) == pytest.approx(chord(0.3))
    # joint 1 turns the whole arm: the tip (0.3 m out) moves farthest
    assert W.shape_distance(L, [0, 0, 0], [0.2, 0, 0]) == pytest.approx(chord(0.2, 0.3))
    assert W.reach_of(L).tolist() == pytest.approx([0.3, 0.2, 0.1])


def test_the_tracking_error_is_two_sided():
    """A segment that overshoots the planned edge (to 0.4 where the plan stops at 0.2) is off by the
    chord of the overshoot (the segment-to-plan side); one that stops short, by the same."""
    planned = np.array([[0, 0, 0], [0, 0, 0.2]])
    h = 1e-4
    assert W.tracking_error(planned, L, planned[0], planned[1], h) == pytest.approx(0.0, abs=1e-12)
    assert W.tracking_error(planned, L, [0, 0, 0], [0, 0, 0.4], h) == pytest.approx(chord(0.2), abs=h / 2)
    assert W.tracking_error(planned, L, [0, 0, 0], [0, 0, 0.1], h) == pytest.approx(chord(0.1), abs=h / 2)


def excursion(theta: float, k: int = 41) -> np.ndarray:
    """Joint 3 out to theta and back, k nodes."""
    s = np.sin(np.linspace(0, np.pi, k))[:, None]
    return s * np.array([0, 0, theta])


@pytest.mark.parametrize("theta, kept", [(0.05, False), (0.2, True)])
def test_an_excursion_is_kept_only_beyond_the_tolerance(theta, kept):
    """Out and back along joint 3: the start-to-goal segment stands still, so its error is the chord
    of the excursion, 5.0 mm for 0.05 rad (dropped at 10 mm), 20.0 mm for 0.2 rad (kept)."""
    path = excursion(theta)
    nodes = W.select_nodes(path, L, 0.01, FREE.motion_valid)
    assert nodes[0] == 0 and nodes[-1] == len(path) - 1
    if kept:
        # One node between: it must come within the tolerance (less h / 2) of the farthest shape, as
        # the segment from it back to the start covers everything below it.
        assert len(nodes) == 3
        assert chord(theta - path[nodes[1], 2]) <= 0.01 - 0.01 / 8
        assert W.tracking_error(path, L, path[0], path[-1], 1e-4) == pytest.approx(chord(theta), abs=1e-4)
    else:
        assert nodes.tolist() == [0, len(path) - 1]


def test_a_straight_path_keeps_its_ends():
    path = np.linspace([0, 0, 0], [0.4, 0.8, 0.9], 50)
    assert W.select_nodes(path, L, 0.005, FREE.motion_valid).tolist() == [0, 49]


# An obstacle (found by search, checked below) that the corner of the L-shaped path avoids and its diagonal
# does not.
TRIANGLE = [[0.2469, 0.1566], [0.2529, 0.1566], [0.2499, 0.1626]]


def test_a_detour_around_an_obstacle_keeps_the_fewest_nodes():
    """Joint 2 bends, then joint 1 turns; the diagonal collides: with a tolerance too loose to matter
    the fewest nodes are three (start, one on the L, goal), and every chosen segment is free."""
    path = np.vstack([np.linspace([0, 0, 0], [0, 0.9, 0], 21), np.linspace([0, 0.9, 0], [0.5, 0.9, 0], 21)[1:]])
    chk = ChainChecker.create(SOFT3, [np.array(TRIANGLE)])
    assert chk.path_problem(path) is None and not chk.motion_valid(path[0], path[-1])
    assert W.select_nodes(path, L, 1.0, FREE.motion_valid).tolist() == [0, 40]
    nodes = W.select_nodes(path, L, 1.0, chk.motion_valid)
    assert len(nodes) == 3 and nodes[0] == 0 and nodes[-1] == 40
    assert all(chk.motion_valid(path[a], path[b]) for a, b in zip(nodes[:-1], nodes[1:]))


def test_a_bad_tolerance_is_refused():
    with pytest.raises(ArmbridgeError, match="tracking tolerance"):
        W.select_nodes(excursion(0.1), L, 0.0, FREE.motion_valid)


# ---------------------------------------------------------------- (c) the dead band

@pytest.mark.parametrize("values, snapped", [
    ([0, 0.03, 0.1, 0.12, 0.3], [0, 0, 0.1, 0.1, 0.3]),     # below the band: hold; at or above: move
    ([0, 0.2, 0.25], [0, 0.25, 0.25]),                      # the goal's last move merged back into the one before
    ([0, 0.02, 0.04], [0, 0.04, 0.04]),                     # the joint's only move, smaller than the band
    ([0.3, 0.3, 0.3], [0.3, 0.3, 0.3]),                     # no move at all
])
def test_changes_below_the_dead_band_are_held(values, snapped):
    q = np.zeros((len(values), 3))
    q[:, 1] = values
    out, changed = W.snap(q, 0.07, FREE.motion_valid)
    assert out[:, 1].tolist() == pytest.approx(snapped)
    assert (out[:, [0, 2]] == 0).all() and changed[:, 1].tolist() == [a != b for a, b in zip(values, snapped)]
    moves = np.abs(np.diff(out[:, 1]))
    moves = moves[moves > 0]
    assert len(moves) <= 1 or np.all(moves >= 0.07 - 1e-12)      # at least the band, or the only move


def test_a_snapped_segment_that_collides_gets_its_planned_values_back():
    """Joint 1 would be held at 0.3 (a change of 0.25 under a 0.3 band); held, the arm sweeps through a
    triangle that the planned values pass by: the waypoint keeps its planned joint 1."""
    q = np.array([[0.3, 0, 0], [0.05, 0.5, 0], [0.0, 0.5, 0.4]])
    held, _ = W.snap(q, 0.3, FREE.motion_valid)
    assert held[1].tolist() == [0.3, 0.5, 0.0]
    chk = ChainChecker.create(SOFT3, [np.array([[0.261, 0.1321], [0.271, 0.1321], [0.266, 0.1241]])])
    assert not chk.motion_valid(held[0], held[1]) and chk.motion_valid(q[0], q[1]) and chk.motion_valid(q[1], q[2])
    out, changed = W.snap(q, 0.3, chk.motion_valid)
    assert out.tolist() == q.tolist() and not changed.any()


# ---------------------------------------------------------------- (d) timing

def hand_timing() -> W.PumpTiming:
    n = np.ones(3)
    return W.PumpTiming(band=0.07 * n, rate_in=0.1 * n, rate_de=0.2 * n, open_s=1.0 * n, settle_in_s=0.5 * n,
                        settle_de_s=0.8 * n, snap_rad=0.15 * n, rest=np.zeros(3))


def test_durations_follow_the_asymmetry():
    q = np.array([[0.3, 0, 0],      # inflate 0.3 from straight: 3 s + 1 s to open; hold 0.5
                  [0.1, 0, 0],      # deflate 0.2 at 0.2 rad/s: 1 s; hold 0.8
                  [0.1, 0.1, 0],    # joint 2 opens to 0.1, below its snap-through bend: overshoot, hold 0.8
                  [0.1, 0.1, 0]])   # no move
    move, hold = W.durations(q, hand_timing())
    assert move.tolist() == pytest.approx([4.0, 1.0, 2.0, W.MOVE_MIN_S])
    assert hold.tolist() == pytest.approx([0.5, 0.8, 0.8, 0.0])


def board_timing() -> W.PumpTiming:
    return W.pump_timing(PumpParams(), Cfg, SOFT3.q_max, SOFT3.v_max)


def test_the_rates_are_what_the_plant_does_at_the_controllers_ceilings():
    """The plant itself (emulator/pump_plant.py), driven at the inflation ceiling (700 per-mille) from
    straight: it opens after about the opening volume, then bends no slower than the model's rate at
    that duty (rate_in / RATE_FRACTION) over its range; deflating at full duty, no slower than
    rate_de / RATE_FRACTION. The asymmetry: inflation is the slower of the two."""
    tm = board_timing()
    assert np.all(tm.rate_in < tm.rate_de) and np.all(tm.rate_de <= SOFT3.v_max)
    plant = PumpPlant(SOFT3.q_max, [(205, 0, 716, 1047)] * 3)
    dt, t, log = 0.01, 0.0, []
    plant.drive([0.7] * 3)
    while t < 12.0:
        t += dt
        plant.advance_to(t)
        log.append((t, plant.q.copy()))
    ts = np.array([r[0] for r in log])
    qs = np.array([r[1] for r in log])
    for j in range(3):
        opened = np.nonzero(qs[:, j] > 0)[0][0]
        assert ts[opened] < 1.0                                  # 12.2 mL at 13.7 mm/s: 0.89 s
        assert qs[opened + 10, j] >= 0.9 * tm.snap_rad[j]        # and snaps through at once (0.1 s)
        band = (qs[:, j] > tm.snap_rad[j] + 0.05) & (qs[:, j] < 0.9 * SOFT3.q_max[j])
        rate = np.diff(qs[band, j]) / dt
        assert rate.min() >= 0.97 * tm.rate_in[j] / W.RATE_FRACTION, j
    plant.drive([-1.0] * 3)
    t0, log = t, []
    while t < t0 + 6.0:
        t += dt
        plant.advance_to(t)
        log.append(plant.q.copy())
    qs = np.array(log)
    for j in range(3):
        falling = (qs[:, j] < 0.8 * SOFT3.q_max[j]) & (qs[:, j] > 0.2)
        rate = -np.diff(qs[:, j])[falling[1:]] / dt
        assert rate.size and np.median(rate) >= 0.9 * tm.rate_de[j] / W.RATE_FRACTION, j


def test_the_opening_time_grows_with_a_slower_ramp_and_the_settle_is_finite():
    tm = board_timing()
    slow = W.pump_timing(PumpParams(), Cfg, SOFT3.q_max, SOFT3.v_max, rate_fraction=0.25)
    assert np.all(slow.open_s > tm.open_s)
    for x in (tm.open_s, tm.settle_in_s, tm.settle_de_s):
        assert np.all(np.isfinite(x) & (x > 0) & (x < 5))
    assert tm.band.tolist() == [0.07] * 3
    assert np.all((tm.snap_rad > 0.1 * SOFT3.q_max) & (tm.snap_rad < 0.28 * SOFT3.q_max))  # below p_open's branch
