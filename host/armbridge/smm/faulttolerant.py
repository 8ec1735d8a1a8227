"""Fault-tolerant planning with SMM bounding boxes (Clark and Xie, section III-A): the motions.

The boxes themselves (smm/bbox.py) give artificial joint limits inside which
every single-joint lock is recoverable; this module moves the arm with them,
pure numpy:

* the time-optimal motion into a box under per-joint speed limits;
* the motion between two configurations inside a box that never leaves it;
* locked-joint recovery: the configurations on the SMMs whose locked joint has
  the locked value, and the fastest motion to one of them with the healthy joints.

Angles are radians. Motions under joint limits never wrap around the circle
(a joint cannot cross its stops), so their configurations are lifted into
[lo, hi].
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.geometry import wrap_angle as wrap  # angles in [-pi, pi), as in SmmSet
from armbridge.smm.bbox import EPS, TWO_PI, Box, Limits, ccw, check_limits, curve_box, lift
from armbridge.smm.manifold import SmmSet


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
        if width >= TWO_PI - EPS:
            return 0.0
        s = float(ccw(q - lo))
        if s <= width + EPS:
            return 0.0
        up, down = TWO_PI - s, s - width  # to lo counter-clockwise, to lo + width clockwise
        return up if up <= down else -down
    a, b = lim
    best = np.nan
    # The lifted copies of the arc that meet [a, b] (at most three when the span is 2 pi).
    k0 = int(np.floor((a - lo - width) / TWO_PI))
    for k in range(k0, k0 + 4):
        x0, x1 = max(lo + k * TWO_PI, a), min(lo + k * TWO_PI + width, b)
        if x0 <= x1 + EPS:
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
    lims = None if limits is None else check_limits(limits)
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
    along = ccw(q_to - box.lo) - ccw(q_from - box.lo)
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
    bbox.smm_curves (lifted into the limits when limits are given)."""
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
        delta = lift(configs, check_limits(limits)) - q
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
