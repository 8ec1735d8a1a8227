"""Pump waypoints from a planned soft-arm path: which nodes to send, and how long each move takes.

A WJRRT path is hundreds of small steps (the paper's two-arm run: 367 nodes, of
which the authors picked 20 by hand for the pump, section V-C). The syringe-pump
board (docs/pump.md) moves each joint's set point linearly from one waypoint to
the next and drives the joint with the P controller of eq. 24 and a dead band, so
a waypoint every few milliradians is below what it resolves. `subsample` picks
the waypoints by a stated criterion instead of by hand:

(a) Tracking tolerance. The shape distance of two configurations is the largest
    distance between corresponding points of the two arms (points at the same
    length along the arm from the base). Between corresponding points of a link
    that distance is convex in the position along the link, so it is the largest
    over the joints and the tip: d(q, q') = max_i |p_i(q) - p_i(q')|. A segment
    between two chosen nodes a < b is accepted when the Hausdorff distance, under
    d, between the shapes along the straight joint-space segment q_a -> q_b (what
    the board's set point does) and the shapes along the planned path from node a
    to node b (its own straight edges) is at most `tol` metres. Both sets are
    sampled so that no arm point moves more than h = tol / 4 between samples
    (|dq_j| times the length from joint j to the tip bounds any point's motion, as
    the checker's edges do, planning/soft/space.py); the sampled distance is then
    within h / 2 of the true one, so a segment is accepted when the sampled value
    is at most tol - h / 2, and its true distance is at most tol.
(b) Collision. Every chosen segment is free per the scene's checker
    (`motion_valid`, at the checker's edge resolution).
    The fewest nodes meeting (a) and (b), start and goal always among them, is a
    shortest path over the nodes (an edge a -> b wherever (a) and (b) hold; the
    planned path's own edges always do): `select_nodes`.
(c) Dead band. A change of a joint smaller than its dead band is below what the P
    controller resolves (it rests anywhere within the band of its set point), so
    consecutive waypoints differ in a joint by at least the band or not at all: a
    smaller change is snapped to a hold of the joint's previous value (`snap`); the
    goal keeps its planned value (its last move is merged back until it is at least
    the band, or it is the only move). Each snapped segment is checked for collision
    again; one that collides gets its waypoint's planned values back. (c) wins over
    (a): a held joint is up to a band from its node, which moves the tip by up to the
    band times the joint's length to the tip, so a snapped segment may stray from the
    planned path by more than `tol`; `PumpWaypoints.error_m` is the error after (c).
(d) Timing, from the inflation/deflation asymmetry (planning/soft/pump_timing.py: `PumpTiming`,
    `durations`).

The path's own nodes are untouched: `PumpWaypoints` holds the chosen node indices,
the (snapped) waypoint poses, each move's duration and the hold after it, and each
segment's tracking error after snapping.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from armbridge.errors import ArmbridgeError
from armbridge.planning.polygons import chain_points
from armbridge.planning.soft.pump_timing import MOVE_MIN_S, RATE_FRACTION, Opening, PumpTiming, durations, pump_timing

__all__ = ["MOVE_MIN_S", "RATE_FRACTION", "TOLERANCE_M", "Opening", "PumpTiming", "PumpWaypoints", "durations",
           "pump_timing", "reach_of", "select_nodes", "shape_distance", "snap", "subsample", "tracking_error"]

#: Default tracking tolerance of (a), m.
TOLERANCE_M = 0.01


# ---------------------------------------------------------------- (a) the tracking error

@njit(cache=True)
def _samples(path, reach, h):
    """path (M, n)'s straight edges sampled so that no arm point moves more than h between samples."""
    m, n = path.shape
    count = 1
    for k in range(m - 1):
        move = 0.0
        for j in range(n):
            move += abs(path[k + 1, j] - path[k, j]) * reach[j]
        count += max(1, int(math.ceil(move / h)))
    out = np.empty((count, n))
    out[0] = path[0]
    i = 1
    for k in range(m - 1):
        move = 0.0
        for j in range(n):
            move += abs(path[k + 1, j] - path[k, j]) * reach[j]
        steps = max(1, int(math.ceil(move / h)))
        for s in range(1, steps + 1):
            t = s / steps
            for j in range(n):
                out[i, j] = path[k, j] + t * (path[k + 1, j] - path[k, j])
            i += 1
    return out


@njit(cache=True)
def _shapes(qs, lengths):
    """(M, n+1, 2) arm points of each configuration (base at the origin: d is invariant to the base pose)."""
    out = np.empty((qs.shape[0], lengths.size + 1, 2))
    for i in range(qs.shape[0]):
        chain_points(qs[i], lengths, 0.0, 0.0, 0.0, out[i])
    return out


@njit(cache=True)
def _directed(A, B, limit):
    """max over shapes of A of the least shape distance to B; stops as soon as it exceeds limit.
    A's shapes are visited from the middle outwards (where a long segment strays farthest)."""
    na, nb, npts = A.shape[0], B.shape[0], A.shape[1]
    mid = na // 2
    worst = 0.0
    for s in range(na):
        i = mid + ((s + 1) // 2) * (1 if s % 2 == 1 else -1)
        if i < 0 or i >= na:
            continue
        best = np.inf
        for k in range(nb):
            d = 0.0
            for p in range(1, npts):
                dx = A[i, p, 0] - B[k, p, 0]
                dy = A[i, p, 1] - B[k, p, 1]
                dd = dx * dx + dy * dy
                if dd > d:
                    d = dd
                    if d >= best:
                        break
            if d < best:
                best = d
        if best > worst:
            worst = best
            if worst > limit * limit:
                return math.sqrt(worst)
    return math.sqrt(worst)


@njit(cache=True)
def segment_error(qa, qb, planned, lengths, reach, h, limit):
    """Sampled Hausdorff shape distance (m) between the straight segment qa -> qb and the planned
    path (M, n) (module doc, (a)); a value above `limit` may be returned early (any value > limit)."""
    seg = np.empty((2, qa.size))
    seg[0] = qa
    seg[1] = qb
    A = _shapes(_samples(planned, reach, h), lengths)
    B = _shapes(_samples(seg, reach, h), lengths)
    e = _directed(A, B, limit)
    if e > limit:
        return e
    return max(e, _directed(B, A, limit))


def tracking_error(planned: Any, lengths: Any, qa: Any, qb: Any, h: float) -> float:
    """The sampled error of (a) (m) of the straight segment qa -> qb against the planned path (M, n),
    sampled every h m of arm motion: within h / 2 of the true Hausdorff shape distance."""
    P = np.ascontiguousarray(planned, dtype=float)
    L = np.ascontiguousarray(lengths, dtype=float)
    return float(segment_error(np.ascontiguousarray(qa, dtype=float), np.ascontiguousarray(qb, dtype=float), P, L,
                               reach_of(L), float(h), np.inf))


def shape_distance(lengths: np.ndarray, q: Any, q2: Any) -> float:
    """d(q, q2) of (a): the largest distance between corresponding arm points, m."""
    s = _shapes(np.ascontiguousarray([q, q2], dtype=float), np.ascontiguousarray(lengths, dtype=float))
    return float(np.max(np.linalg.norm(s[0] - s[1], axis=-1)))


def reach_of(lengths: np.ndarray) -> np.ndarray:
    """(n,) the length from each joint to the tip (bounds how far a point moves per rad of that joint)."""
    return np.ascontiguousarray(np.cumsum(np.asarray(lengths, float)[::-1])[::-1])


class _Errors:
    """Tracking errors of candidate segments against a planned path, at tolerance tol."""

    def __init__(self, path: np.ndarray, lengths: Any, tol: float) -> None:
        if not (math.isfinite(tol) and tol > 0):
            raise ArmbridgeError(f"tracking tolerance must be a finite number > 0 m, got {tol}")
        self.path = np.ascontiguousarray(path, dtype=float)
        self.lengths = np.ascontiguousarray(lengths, dtype=float)
        self.reach = reach_of(self.lengths)
        self.h = tol / 4.0
        self.limit = tol - self.h / 2.0

    def of(self, a: int, b: int, qa: np.ndarray | None = None, qb: np.ndarray | None = None,
           limit: float | None = None) -> float:
        """Error of the segment qa -> qb (default: nodes a and b) against the planned nodes a..b."""
        qa = self.path[a] if qa is None else np.ascontiguousarray(qa, dtype=float)
        qb = self.path[b] if qb is None else np.ascontiguousarray(qb, dtype=float)
        return float(segment_error(qa, qb, self.path[a:b + 1], self.lengths, self.reach, self.h,
                                   np.inf if limit is None else limit))

    def ok(self, a: int, b: int) -> bool:
        return self.of(a, b, limit=self.limit) <= self.limit


def select_nodes(path: Any, lengths: Any, tol: float, edge_ok: Callable[[np.ndarray, np.ndarray], bool]) -> np.ndarray:
    """The fewest node indices of path (K, n), 0 and K-1 included, whose consecutive straight segments
    meet (a) at `tol` m and (b) `edge_ok` (the checker's motion_valid): a shortest path over the nodes,
    each node reached from the candidate with the fewest nodes before it (ties: the earliest)."""
    P = np.asarray(path, dtype=float)
    if P.ndim != 2 or P.shape[0] < 1:
        raise ArmbridgeError(f"a planned path has shape (K, n) with K >= 1, got {P.shape}")
    K = P.shape[0]
    err = _Errors(P, lengths, tol)
    best = np.zeros(K, dtype=int)
    prev = np.full(K, -1)
    for b in range(1, K):
        order = sorted(range(b), key=lambda a: (best[a], a))
        for a in order:
            if (a == b - 1 or err.ok(a, b)) and edge_ok(P[a], P[b]):
                best[b], prev[b] = best[a] + 1, a
                break
        else:
            raise ArmbridgeError(f"the planned path's edge {b - 1} -> {b} collides: it is not a valid plan")
    nodes = [K - 1]
    while nodes[-1] != 0:
        nodes.append(int(prev[nodes[-1]]))
    return np.array(nodes[::-1], dtype=int)


# ---------------------------------------------------------------- (c) the dead band

def _snap_joint(v: np.ndarray, band: float, frozen: np.ndarray) -> np.ndarray:
    """One joint's values v (m,) snapped per (c): hold the previous value while a change is below
    band; v[0], v[-1] and frozen waypoints keep theirs. The goal's last move is merged back (the run
    of holds before it takes the goal's value) until it is at least band or the joint's only move."""
    u = v.copy()
    m = len(v)
    for i in range(1, m - 1):
        if not frozen[i] and abs(v[i] - u[i - 1]) < band:
            u[i] = u[i - 1]
    last = m - 1
    while last > 0:
        step = abs(u[last] - u[last - 1])
        r = last - 1                      # the run of equal values before the goal: u[r:last]
        if step == 0.0 or step >= band or r == 0 or frozen[r]:
            break
        while r - 1 >= 1 and u[r - 1] == u[r] and not frozen[r - 1]:
            r -= 1
        u[r:last] = u[last]
        last = r
    return u


def snap(q: Any, band: Any, edge_ok: Callable[[np.ndarray, np.ndarray], bool]) -> tuple[np.ndarray, np.ndarray]:
    """Waypoints (m, n) snapped per (c) with dead bands band (n,) rad; a segment that collides after
    snapping gets its waypoint's own values back (and, if that one was already unsnapped, the one
    before it), until every segment is free. Returns (snapped q, which joints were changed (m, n))."""
    Q = np.asarray(q, dtype=float)
    band = np.broadcast_to(np.asarray(band, dtype=float), (Q.shape[1],))
    frozen = np.zeros(len(Q), dtype=bool)
    while True:
        S = np.column_stack([_snap_joint(Q[:, j], float(band[j]), frozen) for j in range(Q.shape[1])])
        bad = next((i for i in range(1, len(S)) if not edge_ok(S[i - 1], S[i])), None)
        if bad is None:
            return S, S != Q
        if frozen[bad] or not np.any(S[bad] != Q[bad]):
            bad -= 1                      # the waypoint before it was snapped into the way
            while bad > 0 and frozen[bad]:
                bad -= 1
        if bad <= 0:
            raise ArmbridgeError("the waypoints collide even with their planned values")
        frozen[bad] = True


# ---------------------------------------------------------------- all of it

@dataclass
class PumpWaypoints:
    """The waypoints of a planned path for the pump board (module doc)."""

    nodes: np.ndarray        # (m,) indices into the planned path, 0 and K-1 included
    q: np.ndarray            # (m, n) the waypoint poses (after (c))
    snapped: np.ndarray      # (m, n) True where (c) changed the node's value
    move_s: np.ndarray       # (m,) each move's duration (the first from the rest pose)
    hold_s: np.ndarray       # (m,) the hold after it
    error_m: np.ndarray      # (m-1,) each segment's tracking error after (c), m
    tolerance_m: float
    planned_nodes: int

    def plan_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """The plan's waypoints: each pose reached in move_s, then (hold_s > 0) repeated for hold_s."""
        rows, durs = [], []
        for qi, mv, hd in zip(self.q, self.move_s, self.hold_s):
            rows.append(qi)
            durs.append(mv)
            if hd > 0:
                rows.append(qi)
                durs.append(hd)
        return np.array(rows), np.array(durs)

    def criterion(self) -> dict[str, Any]:
        """The selection, as the plan's provenance records it."""
        return {"rule": "fewest nodes: straight joint-space segments within the tracking tolerance of the "
                        "planned path (Hausdorff, largest distance of corresponding arm points) and collision-free;"
                        " joint changes below the dead band held; durations from the pump's inflation and "
                        "deflation rates, with a settle hold",
                "tolerance_m": self.tolerance_m, "planned_nodes": self.planned_nodes, "waypoints": int(len(self.q)),
                "nodes": [int(x) for x in self.nodes],
                "snapped": [[int(i), int(j)] for i, j in zip(*np.nonzero(self.snapped))],
                "tracking_error_m": [round(float(e), 6) for e in self.error_m],
                "move_s": [round(float(x), 4) for x in self.move_s],
                "hold_s": [round(float(x), 4) for x in self.hold_s]}


def subsample(path: Any, checker: Any, timing: PumpTiming, tol: float = TOLERANCE_M) -> PumpWaypoints:
    """(a)-(d) of the module doc on a planned path (K, n) of a scene's checker (lengths, motion_valid)."""
    P = np.asarray(path, dtype=float)
    nodes = select_nodes(P, checker.lengths, tol, checker.motion_valid)
    q, snapped = snap(P[nodes], timing.band, checker.motion_valid)
    err = _Errors(P, checker.lengths, tol)
    errors = np.array([err.of(int(a), int(b), q[i], q[i + 1]) for i, (a, b) in enumerate(zip(nodes[:-1], nodes[1:]))])
    move, hold = durations(q, timing)
    return PumpWaypoints(nodes, q, snapped, move, hold, errors, float(tol), int(len(P)))
