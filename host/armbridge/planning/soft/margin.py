"""The clearance a soft-arm plan keeps, and the path's clearance (issue 24 section 2).

The margin. The pump firmware settles a joint until its reading is within
SETTLE_FINE_MRAD (3 mrad) of the set point and leaves it at rest until the
error grows past SETTLE_RESEEK_MRAD (8 mrad; firmware/arduino_pump/config.h,
read by `joint_tolerance()`): a resting joint can be up to e = 8 mrad from
where the plan put it. What that does to the arm follows from space.py's motion bound:
joint i sits at p_i and turns every link k >= i; a joint error delta with
|delta_i| <= e moves the arm as the straight joint-space edge q -> q + delta
does, and along it a point x of link k moves at most

    sum_{i<=k} |delta_i| |x - p_i|  <=  e sum_{i<=k} R_ik,    R_ik = L_i + ... + L_k

(|x - p_i| is at most the chain from joint i to the far end of link k,
whatever the angles): space.motion_bounds's B_k for dq = (e, ..., e). The
largest is the last link's, B_{n-1} = e (reach_0 + ... + reach_{n-1}) with
reach_i = L_i + ... + L_{n-1}: for soft3 (3 x 0.1 m) e (0.3 + 0.2 + 0.1) =
0.6 e = 4.8 mm; soft2 2.4 mm; soft7 (7 x 60 mm) 13.4 mm. `execution_margin`
computes it; a plan keeps it from every obstacle, so the arm resting anywhere
within its controller's tolerance of a planned state still touches nothing.
On 20 drawn, calibrated boards the true joint error was 0.14 deg mean /
0.78 deg max (13.6 mrad, on one joint: the sensor's own calibration error
adds to the reading's 8 mrad) and the true tip error at most 3.9 mm, within
soft3's 4.8 mm. A scene's "margin" field (m) and `armbridge plan soft
--margin MM` override it (MARGIN_MAX_M at most).

The clearance objective (OMPL's MaximizeMinClearanceObjective): the cost of
a state is its clearance (the least distance of any link's surface to any
obstacle, space.ChainChecker.clearance), of a path the least over its
states; larger is better. `ClearanceObjective.edge` measures a straight
joint-space edge at states no more than `res` of point motion apart
(CLEARANCE_RES = 0.2 mm, a tenth of the certified check's probe spacing);
the distance of a link to an obstacle changes by at most the motion of its
points, so the true least is within res / 2 below the sampled one. The
margined checker certifies every state of an edge (space.edge_code), so a
plan's sampled clearance is at least its margin.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Optional

import numpy as np
from numba import njit

from armbridge.planning.margin import CLEARANCE_RES, chain_margin
from armbridge.planning.polygons import chain_points, obstacle_clearance



@lru_cache(maxsize=None)
def joint_tolerance() -> float:
    """The pump controller's rest tolerance per joint (rad): it re-seeks a joint once its error passes
    SETTLE_RESEEK_MRAD (the firmware's config.h)."""
    from armbridge.boards import config

    return float(config("arduino_pump").SETTLE_RESEEK_MRAD) / 1000.0


def execution_margin(lengths: Any, joint_error: Optional[float] = None) -> float:
    """The largest displacement of any point of a chain of link `lengths` (m; or a robot) when every joint
    is off by at most `joint_error` (rad; default joint_tolerance()): planning.margin.chain_margin, which
    is space.motion_bounds's B_{n-1} for dq = (e, ..., e) (module doc), m."""
    return chain_margin(lengths, joint_tolerance() if joint_error is None else joint_error)


@njit(cache=True)
def edge_least_clearance(qa, qb, lengths, reach, base, verts, starts, bbox, half_width, res, pts, q, out):
    """The least link-surface clearance over states of qa -> qb (both ends included) no more than res of
    point motion apart (m); bbox: the polygons' boxes (grown boxes are still lower bounds)."""
    n = lengths.size
    move = 0.0
    for j in range(n):
        move += abs(qb[j] - qa[j]) * reach[j]
    steps = max(1, int(math.ceil(move / res)))
    least = np.inf
    for s in range(steps + 1):
        t = s / steps
        for j in range(n):
            q[j] = qa[j] + t * (qb[j] - qa[j])
        chain_points(q, lengths, base[0], base[1], base[2], pts)
        c = obstacle_clearance(pts, verts, starts, bbox, out) - half_width
        if c < least:
            least = c
    return least


@dataclass(eq=False)
class ClearanceObjective:
    """Path clearance as OMPL's MaximizeMinClearanceObjective: a path's cost is its least state clearance
    (m, sampled at `res`; module doc), and a larger one is better. `checker`: a space.ChainChecker."""

    checker: Any
    res: float = CLEARANCE_RES

    def __post_init__(self) -> None:
        n = self.checker.n
        self._pts, self._q, self._out = np.empty((n + 1, 2)), np.empty(n), np.empty(n)

    def state(self, q: Any) -> float:
        return float(self.checker.clearance(q))

    def edge(self, a: Any, b: Any) -> float:
        """The least clearance along the straight joint-space edge a -> b (m)."""
        c = self.checker
        c.checks += 1
        return float(edge_least_clearance(np.ascontiguousarray(a, dtype=float), np.ascontiguousarray(b, dtype=float),
                                          c.lengths, c.reach, c.base, c.verts, c.starts, c.bbox, c.half_width,
                                          float(self.res),
                                          self._pts, self._q, self._out))

    def path(self, path: Any) -> float:
        """The least clearance along a path (K, n) of straight edges (m); inf for an empty one."""
        P = np.asarray(path, dtype=float)
        if P.shape[0] == 1:
            return self.state(P[0])
        return min((self.edge(P[k], P[k + 1]) for k in range(P.shape[0] - 1)), default=math.inf)

    @staticmethod
    def is_better(a: float, b: float) -> bool:
        return a > b
