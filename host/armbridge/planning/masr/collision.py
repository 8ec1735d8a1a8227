"""Collision checking for MASR planning (masr paper, Fig. 3a and `CollisionFree`), in numba.

The arm is a polyline of n segments (base, joints, tip: `MasrArm.joint_points`);
obstacles are polygons inflated by half the link width r = 0.5 w. A segment
hits an inflated polygon exactly when its distance to the polygon is <= r
(0 when it crosses an edge or lies inside), so the inflation is the exact
Minkowski sum with a disc of radius r, not a buffered approximation.

The MA rides on the links, so it is covered by the link segments and not
modelled separately.

Along an action q_a -> q_b the motion convention (section II-C,
`MasrArm.action_sequence`) turns the actuated joints one at a time; moves of
the MA do not change the arm's shape. `edge_free` checks:

* q_b in C_f (eq. 5), and optionally q_a in C_free;
* the arm after every rotation of the convention, in the convention's order
  (the paper's check), and
* with `sweep_res > 0` (default 0.01 m) every rotation's whole continuous
  sweep, certified by conservative advancement (`rotation_hit`, issue 24
  section 1), `sweep_res` being only the spacing of its probe states.
  `sweep_res = 0` is the paper's literal check (only after each rotation).

The bound: turning joint j (at p_j) by dth turns links k >= j rigidly about
p_j; a point x of link k is within R_jk = L_j + ... + L_k of p_j, so over a
fraction s of the rotation it moves at most s |dth| R_jk, and the link's
distance to any polygon changes at most as much (links k < j do not move;
MA moves do not change the shape: the MA rides on the links). With
c_k = dist(link k, polygons) - r at the current angle, nothing can touch
while s < min_k c_k / (|dth| R_jk): the check advances by that fraction,
measures again and repeats to the rotation's end, so no shape between two
checks is left out. A rotation is refused when a clearance is <= CLEAR_MIN
(1 um; code NEAR, -8) or after MAX_STEPS steps, and at once when a probe
state one `sweep_res` of point motion ahead collides (taken only while the
advancement moves slower than that), so colliding sweeps cost about what the
sub-stepped check cost. The earlier check (sub-steps `sweep_res` apart,
which could miss a collision between them) is gone.

Kernels take plain arrays so the planner's own numba code can call them;
`CollisionChecker` wraps them for Python callers.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numba import njit

from armbridge.errors import ArmbridgeError
from armbridge.planning.polygons import chain_points, points_hit, polygon_arrays
from armbridge.planning.polygons import obstacle_clearance
from armbridge.planning.soft.space import CLEAR_MIN, MAX_STEPS, NEAR
from armbridge.robots.masr import ANGLE_TOL, POS_TOL, MasrArm

#: Default sweep resolution in m (see module doc).
SWEEP_RES = 0.01


# ----------------------------------------------------------------- primitives
@njit(cache=True)
def arm_points(q, lengths, pts):
    """Fill pts (n+1, 2) with the arm polyline of configuration q (base at the origin, heading 0)."""
    chain_points(q, lengths, 0.0, 0.0, 0.0, pts)


@njit(cache=True)
def config_hit(q, lengths, verts, starts, bbox, r2, pts):
    """points_hit for configuration q (pts is scratch space (n+1, 2))."""
    arm_points(q, lengths, pts)
    return points_hit(pts, verts, starts, bbox, r2)


@njit(cache=True)
def batch_hit(Q, lengths, verts, starts, bbox, r2):
    """config_hit for every row of Q (B, n+1) -> (B,) int."""
    out = np.empty(Q.shape[0], dtype=np.int64)
    pts = np.empty((lengths.size + 1, 2))
    for b in range(Q.shape[0]):
        out[b] = config_hit(Q[b], lengths, verts, starts, bbox, r2, pts)
    return out


@njit(cache=True)
def feasible(q, theta_b, total):
    """q in C_f, eq. (5), bounds included."""
    n = theta_b.size
    for j in range(n):
        if not (abs(q[j]) <= theta_b[j]):
            return False
    return q[n] >= 0.0 and q[n] <= total


@njit(cache=True)
def rotation_order(qa, qb, rj, order):
    """Joints (0-based) the convention turns for qa -> qb, in order; returns how many.

    Same rule as MasrArm.action_sequence: the joint under the MA first, then
    for delta d > 0 the joints below d_c (nearest first) and then above,
    otherwise above first.
    """
    n = rj.size
    dc = qa[n]
    m = 0
    for j in range(n):
        if abs(qb[j] - qa[j]) > ANGLE_TOL and abs(rj[j] - dc) <= POS_TOL:
            order[m] = j
            m += 1
    for g in range(2):
        below = (g == 0) == (qb[n] - dc > 0.0)
        if below:
            for j in range(n - 1, -1, -1):
                if abs(qb[j] - qa[j]) > ANGLE_TOL and abs(rj[j] - dc) > POS_TOL and rj[j] < dc:
                    order[m] = j
                    m += 1
        else:
            for j in range(n):
                if abs(qb[j] - qa[j]) > ANGLE_TOL and abs(rj[j] - dc) > POS_TOL and rj[j] > dc:
                    order[m] = j
                    m += 1
    return m


@njit(cache=True)
def rotation_hit(q, j, th0, dth, lengths, verts, starts, bbox, r2, res, pts, cl):
    """The continuous rotation of joint j from th0 by dth (q's other entries fixed), certified by
    conservative advancement (module doc): -1 free, else a colliding probe's points_hit code or NEAR.
    Leaves q[j] at the last state measured."""
    n = lengths.size
    r = math.sqrt(r2)
    a = abs(dth)
    move = 0.0
    for k in range(j, n):
        move += lengths[k]
    move *= a
    h = res / move if move > 0.0 else 2.0
    t = 0.0
    probed = 0.0
    steps = 0
    while steps < MAX_STEPS:
        steps += 1
        q[j] = th0 + t * dth
        arm_points(q, lengths, pts)
        obstacle_clearance(pts, verts, starts, bbox, cl)
        s = np.inf
        R = 0.0
        for k in range(j, n):
            R += lengths[k]
            c = cl[k] - r
            if c <= CLEAR_MIN:
                hit = points_hit(pts, verts, starts, bbox, r2)
                return hit if hit >= 0 else NEAR
            b = a * R
            if b > 0.0 and c < s * b:
                s = c / b
        if t + s >= 1.0:
            return -1
        if s < h and t >= probed:
            probed = min(1.0, t + h)
            q[j] = th0 + probed * dth
            hit = config_hit(q, lengths, verts, starts, bbox, r2, pts)
            if hit >= 0:
                return hit
        t += s
    return NEAR


@njit(cache=True)
def edge_hit(qa, qb, lengths, rj, reach, theta_b, total, verts, starts, bbox, r2, sweep_res, check_start):
    """Check the action qa -> qb along the convention.

    Returns -3 if qb (or qa) is outside C_f, -1 if free, NEAR (-8) if a rotation cannot be certified
    free (a clearance within CLEAR_MIN), else the points_hit code of the first shape found colliding.
    sweep_res > 0: every rotation certified (rotation_hit); 0: the shapes after each rotation only.
    """
    n = lengths.size
    if not feasible(qb, theta_b, total):
        return -3
    pts = np.empty((n + 1, 2))
    cl = np.empty(n)
    q = qa.copy()
    if check_start:
        if not feasible(qa, theta_b, total):
            return -3
        h = config_hit(q, lengths, verts, starts, bbox, r2, pts)
        if h >= 0:
            return h
    order = np.empty(n, dtype=np.int64)
    m = rotation_order(qa, qb, rj, order)
    for k in range(m):
        j = order[k]
        th0 = qa[j]
        dth = qb[j] - th0
        if sweep_res > 0.0:
            h = rotation_hit(q, j, th0, dth, lengths, verts, starts, bbox, r2, sweep_res, pts, cl)
            if h != -1:
                return h
        q[j] = qb[j]
        if k < m - 1:
            h = config_hit(q, lengths, verts, starts, bbox, r2, pts)
            if h >= 0:
                return h
    # the final shape: exactly qb (joints below ANGLE_TOL take qb's values)
    return config_hit(qb, lengths, verts, starts, bbox, r2, pts)


@njit(cache=True)
def path_hit(P, lengths, rj, reach, theta_b, total, verts, starts, bbox, r2, sweep_res):
    """(edge index, code) of the first bad edge of the path P (K, n+1), or (-1, -1) if free."""
    pts = np.empty((lengths.size + 1, 2))
    if not feasible(P[0], theta_b, total):
        return -1, -3
    h = config_hit(P[0], lengths, verts, starts, bbox, r2, pts)
    if h >= 0:
        return -1, h
    for k in range(P.shape[0] - 1):
        h = edge_hit(P[k], P[k + 1], lengths, rj, reach, theta_b, total, verts, starts, bbox, r2, sweep_res, False)
        if h != -1:
            return k, h
    return -1, -1


# -------------------------------------------------------------- Python facade
@dataclass(frozen=True, eq=False)
class CollisionChecker:
    """The arm against polygonal obstacles inflated by `margin` (default half the link width).

    polygons: a list of (k, 2) vertex lists (not closed; any orientation).
    """

    arm: MasrArm
    polygons: tuple
    margin: float
    sweep_res: float
    lengths: np.ndarray
    rj: np.ndarray
    reach: np.ndarray
    theta_b: np.ndarray
    verts: np.ndarray
    starts: np.ndarray
    bbox: np.ndarray

    @classmethod
    def create(cls, arm: MasrArm, polygons: Sequence[Any], margin: float | None = None,
               sweep_res: float = SWEEP_RES) -> "CollisionChecker":
        r = 0.5 * arm.link_width if margin is None else float(margin)
        if r < 0 or not math.isfinite(r):
            raise ArmbridgeError(f"collision margin must be a finite number >= 0 m, got {margin}")
        if sweep_res < 0 or not math.isfinite(sweep_res):
            raise ArmbridgeError(f"sweep_res must be a finite number >= 0 m, got {sweep_res}")
        verts, starts, bbox = polygon_arrays(polygons, r)
        lengths = np.ascontiguousarray(arm.link_lengths, dtype=float)
        reach = np.ascontiguousarray(np.cumsum(lengths[::-1])[::-1])
        return cls(arm, tuple(np.asarray(p, float).reshape(-1, 2) for p in polygons), r, float(sweep_res),
                   lengths, np.ascontiguousarray(arm.r, dtype=float), reach,
                   np.ascontiguousarray(arm.theta_b, dtype=float), verts, starts, bbox)

    @property
    def r2(self) -> float:
        return self.margin * self.margin

    def _decode(self, code: int) -> tuple[int, int]:
        return int(code) // self.arm.n, int(code) % self.arm.n

    def hits(self, q: Any) -> np.ndarray:
        """(...,) int: -1 where q is collision-free, else poly * n + link (0-based) of the first hit."""
        q = self.arm._q(q)
        flat = np.ascontiguousarray(q.reshape(-1, self.arm.n + 1), dtype=float)
        out = batch_hit(flat, self.lengths, self.verts, self.starts, self.bbox, self.r2)
        return out.reshape(q.shape[:-1])

    def free(self, q: Any) -> np.ndarray:
        """(...,) bool: q is in C_free (eq. 5 and no obstacle within the margin of any link)."""
        q = self.arm._q(q)
        return (self.hits(q) < 0) & self.arm.within_limits(q)

    def first_hit(self, q: Any) -> tuple[int, int] | None:
        """(polygon index, link index), 0-based, of the first collision of one configuration, or None."""
        h = int(self.hits(np.asarray(q, float).reshape(self.arm.n + 1)))
        return None if h < 0 else self._decode(h)

    def edge_code(self, q_a: Any, q_b: Any, check_start: bool = True) -> int:
        qa = np.ascontiguousarray(self.arm._q(q_a).reshape(self.arm.n + 1), dtype=float)
        qb = np.ascontiguousarray(self.arm._q(q_b).reshape(self.arm.n + 1), dtype=float)
        return int(edge_hit(qa, qb, self.lengths, self.rj, self.reach, self.theta_b, self.arm.total_length,
                            self.verts, self.starts, self.bbox, self.r2, self.sweep_res, check_start))

    def edge_free(self, q_a: Any, q_b: Any, check_start: bool = True) -> bool:
        """CollisionFree(q_a, q_b): the action q_a -> q_b along the motion convention stays in C_free."""
        return self.edge_code(q_a, q_b, check_start) == -1

    def path_problem(self, path: Any) -> str | None:
        """None if every edge of path (K, n+1) is collision-free along the convention, else a message."""
        P = np.ascontiguousarray(self.arm._q(path, "path"), dtype=float)
        if P.ndim != 2 or P.shape[0] == 0:
            raise ArmbridgeError(f"path must have shape (K, {self.arm.n + 1}) with K >= 1, got {P.shape}")
        k, code = path_hit(P, self.lengths, self.rj, self.reach, self.theta_b, self.arm.total_length,
                           self.verts, self.starts, self.bbox, self.r2, self.sweep_res)
        if code == -1:
            return None
        where = "the first configuration" if k < 0 else f"edge {k} -> {k + 1}"
        if code == -3:
            return f"{where}: outside the joint limits or the arm (eq. 5)"
        if code == NEAR:
            return f"{where}: a rotation cannot be certified free (a clearance within {CLEAR_MIN * 1e6:g} um)"
        p, link = self._decode(code)
        return f"{where}: link {link + 1} hits obstacle {p}"
