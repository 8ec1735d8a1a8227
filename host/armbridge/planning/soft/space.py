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
  (the straight joint-space edge, certified free for the continuous motion
  by conservative advancement, below; `certified=False`: the old check at
  sub-steps chosen so that no point of the arm moves more than `res` metres
  between two checked shapes, which can miss a collision between them),
  clearance (eq. 8: the least distance from any link's surface to any
  obstacle, m; 0 in collision) and link_clearance (each link's, for
  W_s of eq. 20). Its `margin` (m, issue 24 section 2; planning/soft/margin.py
  derives it from the pump controller's tolerance) is the clearance every
  link's surface must keep from every obstacle: the obstacle tests use the
  radius w/2 + margin where they used w/2 (self-collision keeps w).

Certified edges (issue 24 section 1; `edge_code`). The bound: joint i sits
at p_i and turns every link k >= i; along the straight edge
q(t) = qa + t dq, t in [0, 1], a point x on link k (centre line, from p_k to
p_{k+1}) moves with velocity dx/dt = sum_{i<=k} dq_i perp(x - p_i), and
|x - p_i| <= R_ik = L_i + ... + L_k (the chain from joint i to the far end
of link k, whatever the angles), so over any sub-interval of length s

    |x(t + s) - x(t)| <= s B_k,    B_k = sum_{i<=k} |dq_i| R_ik
                                       = B_{k-1} + (|dq_0| + ... + |dq_k|) L_k.

The same argument in the frame of link a (rigid motions keep distances)
bounds how fast link b > a moves relative to it: only joints a+1..b count,
S_ab = sum_{a<i<=b} |dq_i| R_ib. Collision is "a centre line within w/2 of
an obstacle" or "two non-adjacent centre lines within w" (the state check),
and a segment's distance to a set changes by at most the largest
displacement of its points. So with c_k = dist(link k, obstacles) - w/2 and
c_ab = dist(link a, link b) - w at q(t), nothing can touch while
s < min(c_k / B_k, c_ab / S_ab): the edge is free on [t, t + s) and the
check advances to t + s, measures the clearances again and repeats until
t >= 1. No resolution: every state of the edge is covered by an interval
on which its clearance is proven positive. An edge is refused when a
clearance falls to CLEAR_MIN (1 um) or below or after MAX_STEPS steps
(what would otherwise be Zeno's approach to a contact), and at once when a
probe state finds a collision: while the advancement moves slower than the
fixed resolution (s < res / sum_j |dq_j| reach_j) the state one `res`-step
ahead is checked, so a colliding edge costs about what the fixed-resolution
check cost. Before the advancement, the states at 1/2, then 1/4 and 3/4
of the edge (PRESCAN_LEVELS levels, never closer together than res) are
tested, as OMPL's DiscreteMotionValidator tests in bisection order: most
refused edges collide over a long stretch, which one state test finds,
where the advancement would crawl up to the contact first (on OMPL's horn
this made planning 2.6 times faster for every planner). Joint limits: the joint box is convex, so qb inside it is
enough (qa is taken as valid, as before).

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
from armbridge.planning.polygons import (chain_points, obstacle_clearance, points_clearance, points_hit,
                                         polygon_arrays, seg_seg_d2, self_hit)
from armbridge.planning.soft.jtstep import jt_step, tip_jacobian  # noqa: F401  (re-exported: moved to jtstep.py)

#: Default edge resolution: no point of the arm moves more than this between checked shapes (m).
EDGE_RES = 0.002

#: Certified edges: a clearance at or below this refuses the edge (m), as does a need for more steps.
CLEAR_MIN = 1e-6
MAX_STEPS = 20000
#: Certified edges: states probed in bisection order before the advancement (1/2; 1/4, 3/4; ...: this many levels).
PRESCAN_LEVELS = 2

FREE, LIMITS, SELF, NEAR = -1, -2, -4, -8


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
def edge_code_sampled(qa, qb, lengths, reach, base, lo, hi, verts, starts, bbox, r2, self_r2, res, pts, q):
    """The straight edge qa -> qb at fixed resolution res (no point moves more than res between two checked
    states; a collision between them can be missed): (sub-steps checked, first bad state's code or -1)."""
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
def motion_bounds(dq, lengths, B, S):
    """The module doc's bounds for the joint step dq: B[k] bounds the displacement of any point of link k,
    S[a, b] (b >= a + 2) that of link b relative to link a (m per unit of the edge parameter)."""
    n = lengths.size
    acc = 0.0
    prev = 0.0
    for k in range(n):
        acc += abs(dq[k])
        prev += acc * lengths[k]
        B[k] = prev
    for a in range(n):
        rel = 0.0
        acc = 0.0
        for b in range(a + 1, n):
            acc += abs(dq[b])
            rel += acc * lengths[b]
            S[a, b] = rel


@njit(cache=True)
def edge_code(qa, qb, lengths, reach, base, lo, hi, verts, starts, bbox, radius, width, res, pts, q, cl, dq, B, S):
    """The straight edge qa -> qb certified by conservative advancement (module doc; obstacles count within
    `radius` = w/2 + margin of a centre line, links within `width` of each other): (steps, -1 when every
    state of the edge is free, else the code of a colliding probe state, or NEAR when a clearance fell to
    CLEAR_MIN or the steps ran out). qa is taken as valid."""
    n = lengths.size
    move = 0.0
    for j in range(n):
        if not (qb[j] >= lo[j] and qb[j] <= hi[j]):
            return 1, LIMITS
        dq[j] = qb[j] - qa[j]
        move += abs(dq[j]) * reach[j]
    r2 = radius * radius
    w2 = width * width
    level, parts = 1, 2
    while level <= PRESCAN_LEVELS and move / parts > res:
        for i in range(1, parts, 2):
            t = i / parts
            for j in range(n):
                q[j] = qa[j] + t * dq[j]
            code = state_code(q, lengths, base, lo, hi, verts, starts, bbox, r2, w2, pts)
            if code != FREE:
                return 1, code
        level += 1
        parts *= 2
    motion_bounds(dq, lengths, B, S)
    h = res / move if move > 0.0 else 2.0
    t = 0.0
    probed = 0.0
    steps = 0
    while steps < MAX_STEPS:
        steps += 1
        for j in range(n):
            q[j] = qa[j] + t * dq[j]
        chain_points(q, lengths, base[0], base[1], base[2], pts)
        obstacle_clearance(pts, verts, starts, bbox, cl)
        s = np.inf
        for k in range(n):
            c = cl[k] - radius
            if c <= CLEAR_MIN:
                code = state_code(q, lengths, base, lo, hi, verts, starts, bbox, r2, w2, pts)
                return steps, code if code != FREE else NEAR
            if B[k] > 0.0 and c < s * B[k]:
                s = c / B[k]
        for a in range(n - 2):
            for b in range(a + 2, n):
                c = math.sqrt(seg_seg_d2(pts[a, 0], pts[a, 1], pts[a + 1, 0], pts[a + 1, 1],
                                         pts[b, 0], pts[b, 1], pts[b + 1, 0], pts[b + 1, 1])) - width
                if c <= CLEAR_MIN:
                    code = state_code(q, lengths, base, lo, hi, verts, starts, bbox, r2, w2, pts)
                    return steps, code if code != FREE else NEAR
                if S[a, b] > 0.0 and c < s * S[a, b]:
                    s = c / S[a, b]
        if t + s >= 1.0:
            return steps, FREE
        if s < h and t >= probed:
            probed = min(1.0, t + h)
            for j in range(n):
                q[j] = qa[j] + probed * dq[j]
            code = state_code(q, lengths, base, lo, hi, verts, starts, bbox, r2, w2, pts)
            if code != FREE:
                return steps, code
        t += s
    return steps, NEAR


@njit(cache=True)
def link_clearance(q, lengths, base, verts, starts, half_width, pts, out):
    """out[l] = distance from link l's surface (half_width from its centre line) to the nearest obstacle (m),
    negative in collision; returns the least."""
    chain_points(q, lengths, base[0], base[1], base[2], pts)
    points_clearance(pts, verts, starts, out)
    least = np.inf
    for k in range(out.size):
        out[k] -= half_width
        if out[k] < least:
            least = out[k]
    return least


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
    certified: bool = True
    margin: float = 0.0
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
        if not (self.margin >= 0 and math.isfinite(self.margin)):
            raise ArmbridgeError(f"clearance margin must be a finite number >= 0 m, got {self.margin}")
        self.lengths = np.ascontiguousarray(self.lengths, dtype=float)
        self.base = np.ascontiguousarray(self.base, dtype=float).reshape(3)
        self.lower = np.ascontiguousarray(self.lower, dtype=float)
        self.upper = np.ascontiguousarray(self.upper, dtype=float)
        self.reach = np.ascontiguousarray(np.cumsum(self.lengths[::-1])[::-1])
        self.verts, self.starts, self.bbox = polygon_arrays(self.polygons, self.radius)
        n = self.lengths.size
        self._pts = np.empty((n + 1, 2))
        self._q = np.empty(n)
        self._cl = np.empty(n)
        self._dq = np.empty(n)
        self._B = np.empty(n)
        self._S = np.zeros((n, n))

    @classmethod
    def create(cls, robot: Any, polygons: Sequence[Any], *, base: Any = (0.0, 0.0, 0.0), link_width: float = 0.0,
               res: float = EDGE_RES, certified: bool = True, margin: float = 0.0) -> "ChainChecker":
        return cls(robot.link_lengths, np.asarray(base, float), robot.q_min, robot.q_max,
                   tuple(np.asarray(p, float).reshape(-1, 2) for p in polygons), float(link_width), float(res),
                   bool(certified), float(margin))

    @property
    def n(self) -> int:
        return int(self.lengths.size)

    @property
    def half_width(self) -> float:
        """w/2: a link's surface is this far from its centre line."""
        return 0.5 * self.link_width

    @property
    def radius(self) -> float:
        """w/2 + margin: a state is valid only while every centre line keeps more than this from obstacles."""
        return 0.5 * self.link_width + self.margin

    def _args(self) -> tuple:
        return (self.lengths, self.base, self.lower, self.upper, self.verts, self.starts, self.bbox,
                self.radius ** 2, self.link_width ** 2)

    def code(self, q: Any) -> int:
        """state_code of one configuration (-1 free; see module constants)."""
        self.checks += 1
        return int(state_code(*(np.ascontiguousarray(q, dtype=float), *self._args(), self._pts)))

    def is_valid(self, q: Any) -> bool:
        return self.code(q) == FREE

    def motion_steps(self, a: Any, b: Any) -> tuple[int, int]:
        """(states measured, code) of the edge a -> b: edge_code, or edge_code_sampled if not certified."""
        self.checks += 1
        qa, qb = np.ascontiguousarray(a, dtype=float), np.ascontiguousarray(b, dtype=float)
        L, B, lo, hi, V, S, BB, r2, s2 = self._args()
        if self.certified:
            k, c = edge_code(qa, qb, L, self.reach, B, lo, hi, V, S, BB, self.radius, self.link_width, self.res,
                             self._pts, self._q, self._cl, self._dq, self._B, self._S)
        else:
            k, c = edge_code_sampled(qa, qb, L, self.reach, B, lo, hi, V, S, BB, r2, s2, self.res, self._pts,
                                     self._q)
        return int(k), int(c)

    def motion_code(self, a: Any, b: Any) -> int:
        return self.motion_steps(a, b)[1]

    def motion_valid(self, a: Any, b: Any) -> bool:
        """The straight joint-space edge a -> b is free for the whole continuous motion (certified; at
        resolution `res` if not `certified`); a itself is not re-checked."""
        return self.motion_code(a, b) == FREE

    def motion_bounds(self, a: Any, b: Any) -> tuple[np.ndarray, np.ndarray]:
        """(B (n,), S (n, n)) of the module doc for the edge a -> b: per unit of the edge parameter, the
        largest displacement of any point of link k, and of link b relative to link a (b >= a + 2)."""
        B, S = np.empty(self.n), np.zeros((self.n, self.n))
        motion_bounds(np.ascontiguousarray(np.asarray(b, float) - np.asarray(a, float)), self.lengths, B, S)
        return B, S

    def link_clearance(self, q: Any) -> np.ndarray:
        """(n,) each link's surface distance to the nearest obstacle, m (inf with no obstacles)."""
        self.checks += 1
        out = np.empty(self.n)
        link_clearance(np.ascontiguousarray(q, dtype=float), self.lengths, self.base, self.verts, self.starts,
                       self.half_width, self._pts, out)
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
        if code == NEAR:
            return (f"the motion cannot be certified free (a clearance within {CLEAR_MIN * 1e6:g} um"
                    + (f" of the {self.margin * 1000:g} mm margin)" if self.margin > 0 else ")"))
        within = f"comes within the {self.margin * 1000:g} mm margin of" if self.margin > 0 else "hits"
        return f"link {code % self.n + 1} {within} obstacle {code // self.n}"

    def path_problem(self, path: Any) -> str | None:
        """None if path (K, n) starts valid and every straight edge is free (motion_code), else a message."""
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
