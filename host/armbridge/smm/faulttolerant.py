"""Fault-tolerant planning with SMM bounding boxes (Clark and Xie, section III-A).

A locked joint can still reach a task point when its value lies within the
range of the task point's SMMs: the bounding box of the SMMs (Fig. 2a) gives
artificial joint limits inside which every single-joint lock is recoverable.
This module holds the geometry of that strategy, pure numpy:

* boxes on the circle: the smallest arc per joint covering an SMM branch (a
  joint that winds all the way round gets the full circle), per branch and per
  location, and their intersections for several task points (Fig. 2b);
* the time-optimal motion into a box under per-joint speed limits;
* the motion between two configurations inside a box that never leaves it;
* locked-joint recovery: the configurations on the SMMs whose locked joint has
  the locked value, and the fastest motion to one of them with the healthy joints.

Angles are radians. A box's arcs are `lo` plus up to `width` counter-clockwise.
Joint limits (lo, hi), when given, must span at most 2 pi; motions under limits
never wrap around the circle (a joint cannot cross its stops), so their
configurations are lifted into [lo, hi].
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import product

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.geometry import wrap_angle as wrap  # angles in [-pi, pi), as in SmmSet
from armbridge.smm.manifold import SmmSet

TWO_PI = 2.0 * np.pi
_EPS = 1e-9  # rad: slack of the containment and limit tests

Limits = tuple[np.ndarray, np.ndarray]  # (lo, hi) per joint, rad


def _ccw(a) -> np.ndarray:
    """Angles mod 2 pi in [0, 2 pi): the counter-clockwise distance from 0."""
    return np.mod(np.asarray(a, dtype=float), TWO_PI)


# ---------------------------------------------------------------- boxes


@dataclass(frozen=True, eq=False)
class Box:
    """A product of arcs, one per joint: joint j in [lo[j], lo[j] + width[j]] mod 2 pi.

    width[j] == 2 pi is the full circle. Section III-A: the bounding box of the
    SMMs of a task point; a joint locked inside it can still reach the point.
    """

    lo: np.ndarray  # (n,) wrapped to [-pi, pi)
    width: np.ndarray  # (n,) in [0, 2 pi]

    @property
    def n(self) -> int:
        return int(self.lo.size)

    @property
    def full(self) -> np.ndarray:
        """Joints whose arc is the whole circle."""
        return self.width >= TWO_PI - _EPS

    def contains(self, q, tol: float = _EPS) -> np.ndarray:
        """Whether configurations q (..., n) lie in the box (within tol rad)."""
        s = _ccw(np.asarray(q, dtype=float) - self.lo + tol)
        return np.all(self.full | (s <= self.width + 2 * tol), axis=-1)


def curve_arc(theta) -> tuple[float, float]:
    """The smallest arc (lo, width) covering a curve sampled at angles theta (N,).

    The curve is followed by its wrapped increments (samples must be closer
    than pi); a curve whose unwrapped range reaches 2 pi (a closed curve that
    winds round the circle, given with its first sample repeated at the end)
    covers the full circle.
    """
    theta = np.asarray(theta, dtype=float)
    path = theta[0] + np.concatenate([[0.0], np.cumsum(wrap(np.diff(theta)))])
    lo, hi = float(path.min()), float(path.max())
    if hi - lo >= TWO_PI - _EPS:
        return float(wrap(theta[0])), TWO_PI
    return float(wrap(lo)), hi - lo


def arc_hull(arcs: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """The smallest arc covering a union of arcs: the complement of the largest
    gap the union leaves on the circle."""
    if not arcs:
        raise ArmbridgeError("arc_hull needs at least one arc")
    if any(w >= TWO_PI - _EPS for _, w in arcs):
        return float(wrap(arcs[0][0])), TWO_PI
    # Arcs as intervals of [0, 2 pi], the ones passing 2 pi split in two; merged.
    ivs: list[tuple[float, float]] = []
    for lo, w in arcs:
        a = float(_ccw(lo))
        ivs += [(a, a + w)] if a + w <= TWO_PI else [(a, TWO_PI), (0.0, a + w - TWO_PI)]
    ivs.sort()
    merged = [list(ivs[0])]
    for a, b in ivs[1:]:
        if a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    # Gap i lies before merged[i]; gap 0 runs from the last interval round to the first.
    gaps = [merged[0][0] + TWO_PI - merged[-1][1]] + [merged[i][0] - merged[i - 1][1] for i in range(1, len(merged))]
    i = int(np.argmax(gaps))
    if gaps[i] <= _EPS:
        return float(wrap(merged[0][0])), TWO_PI
    lo = merged[i][0]
    return float(wrap(lo)), float(TWO_PI - gaps[i])


def curve_box(points) -> Box:
    """The bounding box of one curve of configurations (N, n) (Fig. 2a)."""
    points = np.asarray(points, dtype=float)
    arcs = [curve_arc(points[:, j]) for j in range(points.shape[1])]
    return Box(np.array([a[0] for a in arcs]), np.array([a[1] for a in arcs]))


def hull_box(boxes: Sequence[Box]) -> Box:
    """The smallest box covering several boxes (per joint: the arc hull)."""
    if not boxes:
        raise ArmbridgeError("hull_box needs at least one box")
    n = boxes[0].n
    arcs = [arc_hull([(float(b.lo[j]), float(b.width[j])) for b in boxes]) for j in range(n)]
    return Box(np.array([a[0] for a in arcs]), np.array([a[1] for a in arcs]))


def limits_box(limits: Limits) -> Box:
    """Joint limits as a box (intersect with it to clip a box to the limits)."""
    lo, hi = _check_limits(limits)
    return Box(wrap(lo), hi - lo)


def _check_limits(limits: Limits) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = (np.asarray(x, dtype=float) for x in limits)
    if lo.shape != hi.shape or lo.ndim != 1:
        raise ArmbridgeError(f"joint limits must be two vectors of the same length, got {lo.shape} and {hi.shape}")
    bad = np.nonzero(~((hi > lo) & (hi - lo <= TWO_PI + _EPS)))[0]
    if bad.size:
        j = int(bad[0])
        raise ArmbridgeError(f"joint limits of joint {j + 1}: [{lo[j]:.4f}, {hi[j]:.4f}] rad must have lo < hi "
                             f"and span at most 2 pi")
    return lo, hi


def lift(q, limits: Limits) -> np.ndarray:
    """q (..., n) moved by whole turns into [lo, hi]; NaN where no turn fits."""
    lo, hi = (np.asarray(x, dtype=float) for x in limits)
    x = lo + _ccw(np.asarray(q, dtype=float) - lo + _EPS) - _EPS
    return np.where(x <= hi + _EPS, np.clip(x, lo, hi), np.nan)


def limited_pieces(points, limits: Limits) -> list[np.ndarray]:
    """The runs of consecutive samples of a closed branch (N, n) that lie within
    the joint limits, each lifted into the limits (a branch wholly inside is one
    run, closed by repeating its first sample)."""
    lifted = lift(np.asarray(points, dtype=float), limits)
    inside = ~np.isnan(lifted).any(axis=1)
    # A step between two samples inside that jumps by more than pi once lifted
    # goes round through a stop: the run breaks there too.
    jump = np.abs(lifted - np.roll(lifted, 1, axis=0)).max(axis=1) > np.pi
    if inside.all() and not jump.any():
        return [np.vstack([lifted, lifted[:1]])]
    # Start at a break, so that no run wraps past the end of the sequence.
    starts = ~inside | jump
    order = np.roll(np.arange(len(lifted)), -int(np.argmax(starts)))
    pieces: list[np.ndarray] = []
    run: list[np.ndarray] = []
    for i in order:
        if run and (not inside[i] or jump[i]):
            pieces.append(np.array(run))
            run = []
        if inside[i]:
            run.append(lifted[i])
    if run:
        pieces.append(np.array(run))
    return pieces


def smm_curves(smm: SmmSet, l: int, limits: Limits | None = None) -> list[np.ndarray]:
    """The curves whose boxes plan motions for location l: each SMM branch
    (closed by repeating its first sample) or, with joint limits, each run of a
    branch within them (see branch_boxes)."""
    if limits is None:
        return [np.vstack([b, b[:1]]) for b in smm.branches(l)]
    limits = _check_limits(limits)
    return [p for b in smm.branches(l) for p in limited_pieces(b, limits)]


def branch_boxes(smm: SmmSet, l: int, limits: Limits | None = None) -> list[Box]:
    """One bounding box per SMM branch of location l (Fig. 2b).

    With joint limits (SMMs ignore them), each branch is cut into its runs of
    configurations within the limits and each run gets its own box. Plain
    clipping of a branch's box to the limits would not do: a value of the
    clipped box may only be reached by the branch outside the limits. A run is
    connected, so its box keeps the guarantee of section III-A: for every joint
    value in the box there is a configuration of the run, within limits, that
    reaches the task point.
    """
    return [curve_box(c) for c in smm_curves(smm, l, limits)]


def location_box(smm: SmmSet, l: int, limits: Limits | None = None) -> Box | None:
    """The box covering every SMM branch of location l; None when out of reach
    (or, with limits, when no SMM configuration lies within them). Between
    the arcs of two branches it may take in values no branch reaches: the
    guarantee of section III-A belongs to the branch boxes."""
    boxes = branch_boxes(smm, l, limits)
    return hull_box(boxes) if boxes else None


def intersect_arcs(a: tuple[float, float], b: tuple[float, float]) -> list[tuple[float, float]]:
    """The intersection of two arcs: none, one or two arcs (two arcs longer
    than pi can overlap at both ends)."""
    if a[1] >= TWO_PI - _EPS:
        return [b]
    if b[1] >= TWO_PI - _EPS:
        return [a]
    out = []
    # b's start as seen from a's start, and a's start as seen from b's start.
    s = float(_ccw(b[0] - a[0]))
    if s <= a[1]:
        out.append((b[0], min(b[1], a[1] - s)))
    t = float(_ccw(a[0] - b[0]))
    if t <= b[1] and t > 0:
        out.append((a[0], min(a[1], b[1] - t)))
    return [(float(wrap(lo)), float(w)) for lo, w in out]


def intersect_boxes(a: Box, b: Box) -> list[Box]:
    """The intersection of two boxes: every product of the per-joint arc
    intersections (empty list when a joint's arcs do not meet)."""
    per_joint = [intersect_arcs((float(a.lo[j]), float(a.width[j])), (float(b.lo[j]), float(b.width[j])))
                 for j in range(a.n)]
    return [Box(np.array([c[0] for c in combo]), np.array([c[1] for c in combo])) for combo in product(*per_joint)]


def intersect_all(groups: Sequence[Sequence[Box]]) -> list[Box]:
    """Section III-A, several task points: the regions lying in one box of every
    group (a group: the boxes of one task point). Empty when they do not overlap,
    the case of [9] where the robot should get as close as it can instead."""
    if not groups:
        raise ArmbridgeError("intersect_all needs the boxes of at least one task point")
    regions = list(groups[0])
    for group in groups[1:]:
        regions = [r for region in regions for box in group for r in intersect_boxes(region, box)]
    return regions


# ---------------------------------------------------------------- motions


@dataclass(frozen=True, eq=False)
class Move:
    """A straight line in joint space from start to goal in `duration` s, every
    joint at constant speed (synchronised: the slowest joint at its limit).
    goal is the start plus the signed joint motion, not wrapped."""

    start: np.ndarray
    goal: np.ndarray
    duration: float

    def at(self, t) -> np.ndarray:
        """Configurations at times t (s from the start), clamped to [0, duration]."""
        t = np.asarray(t, dtype=float)
        f = np.ones_like(t) if self.duration <= 0 else np.clip(t / self.duration, 0.0, 1.0)
        return self.start + f[..., None] * (self.goal - self.start)


def _check_speeds(vmax, n: int) -> np.ndarray:
    v = np.broadcast_to(np.asarray(vmax, dtype=float), (n,))
    if not np.all(v > 0):
        raise ArmbridgeError(f"joint speed limits must be > 0 rad/s, got {v.tolist()}")
    return v


def synchronised(start, delta, vmax) -> Move:
    """The straight-line motion by delta that takes the least time under the
    speed limits: duration = max_j |delta_j| / vmax_j."""
    start = np.asarray(start, dtype=float)
    delta = np.asarray(delta, dtype=float)
    v = _check_speeds(vmax, start.size)
    return Move(start, start + delta, float(np.max(np.abs(delta) / v)))


def _nearest_on_arc(q: float, lo: float, width: float, lim: tuple[float, float] | None) -> float:
    """The signed joint motion from q to the nearest point of the arc; without
    limits either way round the circle, with limits within [lim] only (NaN when
    the arc has no point there)."""
    if lim is None:
        if width >= TWO_PI - _EPS:
            return 0.0
        s = float(_ccw(q - lo))
        if s <= width + _EPS:
            return 0.0
        up, down = TWO_PI - s, s - width  # to lo counter-clockwise, to lo + width clockwise
        return up if up <= down else -down
    a, b = lim
    best = np.nan
    # The lifted copies of the arc that meet [a, b] (at most three when the span is 2 pi).
    k0 = int(np.floor((a - lo - width) / TWO_PI))
    for k in range(k0, k0 + 4):
        x0, x1 = max(lo + k * TWO_PI, a), min(lo + k * TWO_PI + width, b)
        if x0 <= x1 + _EPS:
            d = float(np.clip(q, x0, x1)) - q
            if np.isnan(best) or abs(d) < abs(best):
                best = d
    return best


def entry_move(q, box: Box, vmax, limits: Limits | None = None) -> Move:
    """The time-optimal motion from q into the box: every joint independently to
    its nearest arc point, the duration set by the slowest (section III-A with
    [9]: reach the box as soon as possible). Infinite duration when, under
    limits, a joint's arc lies wholly outside them."""
    q = np.asarray(q, dtype=float)
    lims = None if limits is None else _check_limits(limits)
    delta = np.array([
        _nearest_on_arc(float(q[j]), float(box.lo[j]), float(box.width[j]),
                        None if lims is None else (float(lims[0][j]), float(lims[1][j])))
        for j in range(q.size)
    ])
    if np.isnan(delta).any():
        return Move(q, q.copy(), np.inf)
    return synchronised(q, delta, vmax)


def nearest_box(q, boxes: Sequence[Box], vmax, limits: Limits | None = None) -> tuple[int, Move]:
    """The box reached soonest from q, and the motion into it."""
    if not boxes:
        raise ArmbridgeError("no SMM bounding box to move into: the task point is out of reach")
    moves = [entry_move(q, b, vmax, limits) for b in boxes]
    i = int(np.argmin([m.duration for m in moves]))
    return i, moves[i]


def inside_delta(box: Box, q_from, q_to) -> np.ndarray:
    """The joint motion from q_from to q_to (both in the box) that stays inside
    the box: along each arc, the short way round only for full-circle joints."""
    q_from = np.asarray(q_from, dtype=float)
    q_to = np.asarray(q_to, dtype=float)
    along = _ccw(q_to - box.lo) - _ccw(q_from - box.lo)
    return np.where(box.full, wrap(q_to - q_from), along)


def move_within(box: Box, q_from, q_to, vmax) -> Move:
    """The fastest straight-line motion from q_from to q_to inside the box."""
    return synchronised(q_from, inside_delta(box, q_from, q_to), vmax)


@dataclass(frozen=True, eq=False)
class Approach:
    """The way to a task point through its box: `entry` into the box of
    curves[curve], then `inside` to a configuration of that curve (the task
    point reached) without leaving the box."""

    curve: int
    box: Box
    entry: Move
    inside: Move

    @property
    def duration(self) -> float:
        return self.entry.duration + self.inside.duration


def approach(q, curves: Sequence[np.ndarray], vmax, limits: Limits | None = None) -> Approach:
    """Figs. 15-17 once the SMMs are known: into the box reached soonest, then
    inside it to the configuration of its curve reached soonest. curves: from
    smm_curves (lifted into the limits when limits are given)."""
    boxes = [curve_box(c) for c in curves]
    i, entry = nearest_box(q, boxes, vmax, limits)
    if not np.isfinite(entry.duration):
        raise ArmbridgeError("no SMM bounding box can be entered within the joint limits")
    v = _check_speeds(vmax, entry.goal.size)
    deltas = np.stack([inside_delta(boxes[i], entry.goal, c) for c in curves[i]])
    k = int(np.argmin(np.max(np.abs(deltas) / v, axis=1)))
    return Approach(i, boxes[i], entry, synchronised(entry.goal, deltas[k], v))


def travel_times(q, configs, vmax, limits: Limits | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Synchronised straight-line motions from q to each of configs (K, n):
    (deltas (K, n), durations (K,)). Without limits each joint goes the short
    way round; with limits configs are lifted into them (q must lie within
    them) and those that do not fit get an infinite duration."""
    q = np.asarray(q, dtype=float)
    configs = np.asarray(configs, dtype=float).reshape(-1, q.size)
    v = _check_speeds(vmax, q.size)
    if limits is None:
        delta = wrap(configs - q)
    else:
        delta = lift(configs, _check_limits(limits)) - q
    t = np.max(np.abs(delta) / v, axis=1)
    return delta, np.where(np.isnan(t), np.inf, t)


# ---------------------------------------------------------------- locked joint


def locked_crossings(points, j: int, v: float) -> np.ndarray:
    """Configurations (K, n) of a closed branch (N, n) whose joint j equals v.

    Between consecutive samples (and from the last back to the first) the
    branch is taken as the short straight segment on the torus; each segment
    over which joint j passes v (circle-aware: passing v + pi is no crossing)
    gives one interpolated configuration, with joint j set to v exactly.
    """
    p = np.asarray(points, dtype=float)
    step = wrap(np.roll(p, -1, axis=0) - p)
    d0 = wrap(p[:, j] - v)
    d1 = d0 + step[:, j]
    hit = ((d0 <= 0) & (d1 > 0)) | ((d0 >= 0) & (d1 < 0))
    f = np.where(hit, d0 / np.where(hit, d0 - d1, 1.0), 0.0)[hit]
    out = wrap(p[hit] + f[:, None] * step[hit])
    out[:, j] = wrap(v)
    return out


def locked_configurations(smm: SmmSet, l: int, j: int, v: float) -> np.ndarray:
    """Every configuration (K, n) on the SMMs of location l with joint j == v:
    where the robot can still reach the task point with joint j locked at v."""
    found = [locked_crossings(b, j, v) for b in smm.branches(l)]
    n = smm.points.shape[-1]
    return np.concatenate(found) if found else np.zeros((0, n))


def recovery_move(q, j: int, configs, vmax, limits: Limits | None = None) -> Move | None:
    """After joint j locks at q[j]: the fastest motion of the healthy joints to
    one of configs (K, n) (configurations with joint j == q[j], e.g. from
    locked_configurations), within limits if given; None when there is none."""
    q = np.asarray(q, dtype=float)
    if not 0 <= j < q.size:
        raise ArmbridgeError(f"locked joint {j + 1} does not exist; the arm has joints 1..{q.size}")
    delta, t = travel_times(q, configs, vmax, limits)
    if t.size == 0 or not np.isfinite(t).any():
        return None
    i = int(np.argmin(t))
    d = delta[i].copy()
    d[j] = 0.0  # the locked joint stays (crossings hold it at q[j] up to rounding)
    return synchronised(q, d, vmax)


def recover(smm: SmmSet, l: int, q, j: int, vmax, limits: Limits | None = None) -> Move | None:
    """Section III-A after a failure: the artificial limits are released and the
    healthy joints move to the nearest configuration of the SMMs of location l
    whose joint j has the locked value q[j]; None when the SMMs never take it."""
    q = np.asarray(q, dtype=float)
    return recovery_move(q, j, locked_configurations(smm, l, j, float(q[j])), vmax, limits)
