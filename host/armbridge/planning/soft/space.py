"""State space and validity checker of a planar serial chain among polygons (WJRRT paper, section II).

The chain is a robots.PlanarChain placed at a base pose (x, y, heading);
its links are segments of width w, so a link collides when its centre line
comes within w/2 of an obstacle (planning.polygons: the exact Minkowski sum)
and two non-adjacent links collide when their centre lines come within w of
each other. Joint limits are the robot's [q_min, q_max].

* ChainSpace: uniform sampling in the joint box, the Euclidean metric in
  joint space (rad), straight-line interpolation, edge cost = joint-space
  length.
* ChainChecker: is_valid (limits, obstacles, self-collision), motion_valid
  (the straight joint-space edge, checked at sub-steps chosen so that no
  point of the arm moves more than `res` metres between two checked shapes:
  a point beyond joint j moves at most |dq_j| * reach_j, reach_j = the
  length from joint j to the tip), clearance (eq. 8: the least distance
  from any link's surface to any obstacle, m; negative in collision) and
  link_clearance (each link's, for W_s of eq. 20).

Every call counts in `checks` (Table 1's "Obstacle Check" column counts the
checker's answers).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from numba import njit

from armbridge.errors import ArmbridgeError
from armbridge.planning.polygons import chain_points, points_clearance, points_hit, polygon_arrays, self_hit

#: Default edge resolution: no point of the arm moves more than this between checked shapes (m).
EDGE_RES = 0.002

FREE, LIMITS, SELF = -1, -2, -4


@njit(cache=True)
def state_code(q, lengths, base, lo, hi, verts, starts, bbox, r2, self_r2, pts):
    """-1 free, -2 outside the joint limits, -4 self-collision, else points_hit's poly * n + link."""
    n = lengths.size
    for j in range(n):
        if not (q[j] >= lo[j] and q[j] <= hi[j]):
            return LIMITS
    chain_points(q, lengths, base[0], base[1], base[2], pts)
    h = points_hit(pts, verts, starts, bbox, r2)
    if h >= 0:
        return h
    if self_hit(pts, self_r2):
        return SELF
    return FREE


@njit(cache=True)
def edge_code(qa, qb, lengths, reach, base, lo, hi, verts, starts, bbox, r2, self_r2, res, pts, q):
    """The straight edge qa -> qb: (sub-steps checked, first bad state's code or -1). qa is taken as valid."""
    n = lengths.size
    move = 0.0
    for j in range(n):
        move += abs(qb[j] - qa[j]) * reach[j]
    steps = max(1, int(math.ceil(move / res)))
    for s in range(1, steps + 1):
        t = s / steps
        for j in range(n):
            q[j] = qa[j] + t * (qb[j] - qa[j])
        c = state_code(q, lengths, base, lo, hi, verts, starts, bbox, r2, self_r2, pts)
        if c != FREE:
            return s, c
    return steps, FREE


@njit(cache=True)
def link_clearance(q, lengths, base, verts, starts, margin, pts, out):
    """out[l] = distance from link l's surface to the nearest obstacle (m); returns the least."""
    chain_points(q, lengths, base[0], base[1], base[2], pts)
    points_clearance(pts, verts, starts, out)
    least = np.inf
    for k in range(out.size):
        out[k] -= margin
        if out[k] < least:
            least = out[k]
    return least


@njit(cache=True)
def tip_jacobian(q, lengths, base, pts, J):
    """Tip position (x, y) of q and d(tip)/dq into J (2, n): column j is perp(tip - joint j)."""
    n = lengths.size
    chain_points(q, lengths, base[0], base[1], base[2], pts)
    tx, ty = pts[n, 0], pts[n, 1]
    for j in range(n):
        J[0, j] = -(ty - pts[j, 1])
        J[1, j] = tx - pts[j, 0]
    return tx, ty


@njit(cache=True)
def jt_step(q, goal, dx, lengths, base, lo, hi, pts, J, out):
    """One Jacobian-transpose step of the tip towards goal into out, clipped to [lo, hi]; returns the tip's
    distance to goal before the step (m).

    WJRRT eq. (17)-(19): dX = goal - tip shortened to at most dx (m); dq = rho J^T dX with
    rho = <dX, J J^T dX> / |J J^T dX|^2, the rho that brings the linearised tip step J dq closest to dX
    (Buss's choice for the transpose method), so the predicted tip step is never longer than dX; out = q + dq.
    """
    n = lengths.size
    tx, ty = tip_jacobian(q, lengths, base, pts, J)
    ex, ey = goal[0] - tx, goal[1] - ty
    d = math.sqrt(ex * ex + ey * ey)
    if d > dx:
        ex *= dx / d
        ey *= dx / d
    vx = 0.0
    vy = 0.0
    for j in range(n):
        g = J[0, j] * ex + J[1, j] * ey
        out[j] = g
        vx += J[0, j] * g
        vy += J[1, j] * g
    den = vx * vx + vy * vy
    rho = (ex * vx + ey * vy) / den if den > 0.0 else 0.0
    for j in range(n):
        out[j] = min(max(q[j] + rho * out[j], lo[j]), hi[j])
    return d


@dataclass(frozen=True, eq=False)
class ChainSpace:
    """The joint box of a planar chain with the Euclidean metric (module doc)."""

    lower: np.ndarray
    upper: np.ndarray

    @property
    def dim(self) -> int:
        return int(self.lower.size)

    def sample(self, rng: np.random.Generator, count: int) -> np.ndarray:
        return self.lower + rng.random((count, self.dim)) * (self.upper - self.lower)

    def distance(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.linalg.norm(np.asarray(b, float) - np.asarray(a, float), axis=-1)

    def interpolate(self, a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
        """The point at most `step` (rad, joint-space length) from a towards b."""
        d = b - a
        norm = float(np.sqrt(d @ d))
        return b.copy() if norm <= step else a + (step / norm) * d

    def cost(self, a: np.ndarray, b: np.ndarray) -> float:
        return float(self.distance(a, b))

    def clip(self, q: np.ndarray) -> np.ndarray:
        return np.minimum(np.maximum(q, self.lower), self.upper)


@dataclass(eq=False)
class ChainChecker:
    """A planar chain at `base` among polygons, links of width `link_width` (module doc)."""

    lengths: np.ndarray
    base: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    polygons: tuple
    link_width: float
    res: float
    reach: np.ndarray = field(init=False)
    verts: np.ndarray = field(init=False)
    starts: np.ndarray = field(init=False)
    bbox: np.ndarray = field(init=False)
    checks: int = 0

    def __post_init__(self) -> None:
        if not (self.link_width >= 0 and math.isfinite(self.link_width)):
            raise ArmbridgeError(f"link width must be a finite number >= 0 m, got {self.link_width}")
        if not (self.res > 0 and math.isfinite(self.res)):
            raise ArmbridgeError(f"edge resolution must be a finite number > 0 m, got {self.res}")
        self.lengths = np.ascontiguousarray(self.lengths, dtype=float)
        self.base = np.ascontiguousarray(self.base, dtype=float).reshape(3)
        self.lower = np.ascontiguousarray(self.lower, dtype=float)
        self.upper = np.ascontiguousarray(self.upper, dtype=float)
        self.reach = np.ascontiguousarray(np.cumsum(self.lengths[::-1])[::-1])
        self.verts, self.starts, self.bbox = polygon_arrays(self.polygons, self.margin)
        n = self.lengths.size
        self._pts = np.empty((n + 1, 2))
        self._q = np.empty(n)
        self._cl = np.empty(n)

    @classmethod
    def create(cls, robot: Any, polygons: Sequence[Any], *, base: Any = (0.0, 0.0, 0.0), link_width: float = 0.0,
               res: float = EDGE_RES) -> "ChainChecker":
        return cls(robot.link_lengths, np.asarray(base, float), robot.q_min, robot.q_max,
                   tuple(np.asarray(p, float).reshape(-1, 2) for p in polygons), float(link_width), float(res))

    @property
    def n(self) -> int:
        return int(self.lengths.size)

    @property
    def margin(self) -> float:
        return 0.5 * self.link_width

    def _args(self) -> tuple:
        return (self.lengths, self.base, self.lower, self.upper, self.verts, self.starts, self.bbox,
                self.margin ** 2, self.link_width ** 2)

    def code(self, q: Any) -> int:
        """state_code of one configuration (-1 free; see module constants)."""
        self.checks += 1
        return int(state_code(*(np.ascontiguousarray(q, dtype=float), *self._args(), self._pts)))

    def is_valid(self, q: Any) -> bool:
        return self.code(q) == FREE

    def motion_code(self, a: Any, b: Any) -> int:
        self.checks += 1
        L, B, lo, hi, V, S, BB, r2, s2 = self._args()
        return int(edge_code(np.ascontiguousarray(a, dtype=float), np.ascontiguousarray(b, dtype=float), L,
                             self.reach, B, lo, hi, V, S, BB, r2, s2, self.res, self._pts, self._q)[1])

    def motion_valid(self, a: Any, b: Any) -> bool:
        """The straight joint-space edge a -> b is free at resolution `res` (a itself is not re-checked)."""
        return self.motion_code(a, b) == FREE

    def link_clearance(self, q: Any) -> np.ndarray:
        """(n,) each link's surface distance to the nearest obstacle, m (inf with no obstacles)."""
        self.checks += 1
        out = np.empty(self.n)
        link_clearance(np.ascontiguousarray(q, dtype=float), self.lengths, self.base, self.verts, self.starts,
                       self.margin, self._pts, out)
        return out

    def clearance(self, q: Any) -> float:
        """min over links of link_clearance (eq. 8's min_l dist_l), m."""
        return float(self.link_clearance(q).min())

    def points(self, q: Any) -> np.ndarray:
        """(n+1, 2) base, joints and tip of configuration q."""
        pts = np.empty((self.n + 1, 2))
        chain_points(np.ascontiguousarray(q, dtype=float), self.lengths, self.base[0], self.base[1], self.base[2],
                     pts)
        return pts

    def tip(self, q: Any) -> np.ndarray:
        return self.points(q)[-1]

    def describe(self, code: int) -> str:
        """A message for a state_code."""
        if code == FREE:
            return "free"
        if code == LIMITS:
            return "outside the joint limits"
        if code == SELF:
            return "two links collide (self-collision)"
        return f"link {code % self.n + 1} hits obstacle {code // self.n}"

    def path_problem(self, path: Any) -> str | None:
        """None if path (K, n) starts valid and every straight edge is free at `res`, else a message."""
        P = np.asarray(path, dtype=float)
        if P.ndim != 2 or P.shape[1] != self.n or P.shape[0] == 0:
            raise ArmbridgeError(f"path must have shape (K, {self.n}) with K >= 1, got {P.shape}")
        c = self.code(P[0])
        if c != FREE:
            return f"the first configuration: {self.describe(c)}"
        for k in range(P.shape[0] - 1):
            c = self.motion_code(P[k], P[k + 1])
            if c != FREE:
                return f"edge {k} -> {k + 1}: {self.describe(c)}"
        return None
