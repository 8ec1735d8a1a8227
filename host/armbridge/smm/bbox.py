"""SMM bounding boxes (Clark and Xie, section III-A): boxes on the circle.

A locked joint can still reach a task point when its value lies within the
range of the task point's SMMs: the bounding box of the SMMs (Fig. 2a) gives
artificial joint limits inside which every single-joint lock is recoverable.
This module holds those boxes, pure numpy: the smallest arc per joint covering
an SMM branch (a joint that winds all the way round gets the full circle), per
branch and per location, and their intersections for several task points
(Fig. 2b); with joint limits, the runs of a branch within them (`smm_curves`),
each with its own box.

Angles are radians. A box's arcs are `lo` plus up to `width` counter-clockwise.
Joint limits (lo, hi), when given, must span at most 2 pi; configurations
under limits are lifted into [lo, hi] (`lift`).

Apart from the motions and the recovery (smm/faulttolerant.py) because this is
the geometry the strategy plans with (arcs, hulls, intersections on the
torus of joint angles), whoever moves the arm.
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
EPS = 1e-9  # rad: slack of the containment and limit tests

Limits = tuple[np.ndarray, np.ndarray]  # (lo, hi) per joint, rad


def ccw(a) -> np.ndarray:
    """Angles mod 2 pi in [0, 2 pi): the counter-clockwise distance from 0."""
    return np.mod(np.asarray(a, dtype=float), TWO_PI)


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
        return self.width >= TWO_PI - EPS

    def contains(self, q, tol: float = EPS) -> np.ndarray:
        """Whether configurations q (..., n) lie in the box (within tol rad)."""
        s = ccw(np.asarray(q, dtype=float) - self.lo + tol)
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
    if hi - lo >= TWO_PI - EPS:
        return float(wrap(theta[0])), TWO_PI
    return float(wrap(lo)), hi - lo


def arc_hull(arcs: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """The smallest arc covering a union of arcs: the complement of the largest
    gap the union leaves on the circle."""
    if not arcs:
        raise ArmbridgeError("arc_hull needs at least one arc")
    if any(w >= TWO_PI - EPS for _, w in arcs):
        return float(wrap(arcs[0][0])), TWO_PI
    # Arcs as intervals of [0, 2 pi], the ones passing 2 pi split in two; merged.
    ivs: list[tuple[float, float]] = []
    for lo, w in arcs:
        a = float(ccw(lo))
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
    if gaps[i] <= EPS:
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
    lo, hi = check_limits(limits)
    return Box(wrap(lo), hi - lo)


def check_limits(limits: Limits) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = (np.asarray(x, dtype=float) for x in limits)
    if lo.shape != hi.shape or lo.ndim != 1:
        raise ArmbridgeError(f"joint limits must be two vectors of the same length, got {lo.shape} and {hi.shape}")
    bad = np.nonzero(~((hi > lo) & (hi - lo <= TWO_PI + EPS)))[0]
    if bad.size:
        j = int(bad[0])
        raise ArmbridgeError(f"joint limits of joint {j + 1}: [{lo[j]:.4f}, {hi[j]:.4f}] rad must have lo < hi "
                             f"and span at most 2 pi")
    return lo, hi


def lift(q, limits: Limits) -> np.ndarray:
    """q (..., n) moved by whole turns into [lo, hi]; NaN where no turn fits."""
    lo, hi = (np.asarray(x, dtype=float) for x in limits)
    x = lo + ccw(np.asarray(q, dtype=float) - lo + EPS) - EPS
    return np.where(x <= hi + EPS, np.clip(x, lo, hi), np.nan)


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
    limits = check_limits(limits)
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
    if a[1] >= TWO_PI - EPS:
        return [b]
    if b[1] >= TWO_PI - EPS:
        return [a]
    out = []
    # b's start as seen from a's start, and a's start as seen from b's start.
    s = float(ccw(b[0] - a[0]))
    if s <= a[1]:
        out.append((b[0], min(b[1], a[1] - s)))
    t = float(ccw(a[0] - b[0]))
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
