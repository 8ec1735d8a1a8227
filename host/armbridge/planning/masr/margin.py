"""The MASR's execution margin and a path's clearance along the motion convention (issue 24 section 2).

The margin. The MA turns a joint until the angle it estimates is within
ROT_TOL_MRAD (1 mrad) of the set point; the estimate comes through the worm
and its play (firmware/masr_ma/drive.py). With the rotation driver's current
sense the estimate starts where the worm meets the gear, placed within half a
control period's worm travel (1.4 mrad at vmax); a board without it models
BACKLASH_MRAD (3 mrad) with a fresh mesh in its middle, off by half of it.
Either is within 1.5 mrad, so a joint rests within e = ROT_TOL + BACKLASH / 2
= 2.5 mrad of the plan (`joint_tolerance`, read from the firmware's
config.py), and planning.margin.chain_margin turns that into the farthest any
point of the arm can stray: 2.5 mrad x (0.8 + 0.6 + 0.4 + 0.2 + 0.1) m =
5.25 mm for the paper's arm (`execution_margin`). Measured on 20 drawn,
calibrated boards the MA's pose ends 0.77 +- 0.42 mm from the plan, 1.75 mm
at worst (docs/benchmarks.md, issue 23): inside the bound.

Planning keeps the environment's margin (m) beyond half the link width
(Environment.planning_checker): `plan masr --margin MM`, else the
environment file's "margin" field, else this execution bound. The paper's
E1-E3 and the random environments of its Fig. 5 say "margin": 0 (its check,
as published: with the bound E1's plans cost 43 % more and E2 fails a seed
in 5; docs/planning.md, "Clearance"), and `plan masr` reports the bound
beside every plan's least clearance.

The clearance of a path (`path_clearance`): along each action the motion
convention (collision.rotation_order) turns the actuated joints one at a
time; each rotation is sampled so that no point of the arm moves more than
`res` between two measured shapes, and the least distance of any link's
surface (half the link width from its centre line) to any obstacle is the
path's clearance. A link's distance changes at most as much as its points
move, so the true least is within res / 2 below the sampled one.
"""
from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import numpy as np
from numba import njit

from armbridge.planning.margin import CLEARANCE_RES, chain_margin
from armbridge.planning.masr.collision import arm_points, rotation_order
from armbridge.planning.polygons import points_clearance, polygon_arrays


@lru_cache(maxsize=None)
def joint_tolerance() -> float:
    """ROT_TOL_MRAD + BACKLASH_MRAD / 2 of the MA's firmware (module doc), rad."""
    from armbridge.boards import config

    cfg = config("masr_ma")
    return (float(cfg.ROT_TOL_MRAD) + 0.5 * float(cfg.BACKLASH_MRAD)) / 1000.0


def execution_margin(arm: Any) -> float:
    """How far any point of `arm` can stray from a planned shape with every joint within joint_tolerance()
    (planning.margin.chain_margin), m."""
    return chain_margin(arm.link_lengths, joint_tolerance())


@njit(cache=True)
def _shape_clearance(q, lengths, verts, starts, half_width, pts, cl):
    arm_points(q, lengths, pts)
    return points_clearance(pts, verts, starts, cl) - half_width


@njit(cache=True)
def action_clearance(qa, qb, lengths, rj, reach, verts, starts, half_width, res, pts, cl, order):
    """The least link-surface clearance over the shapes of the action qa -> qb along the convention, every
    rotation sampled at most `res` of point motion apart (module doc), m."""
    n = lengths.size
    q = qa.copy()
    least = _shape_clearance(q, lengths, verts, starts, half_width, pts, cl)
    m = rotation_order(qa, qb, rj, order)
    for k in range(m):
        j = order[k]
        th0, dth = qa[j], qb[j] - qa[j]
        steps = max(1, int(math.ceil(abs(dth) * reach[j] / res)))
        for s in range(1, steps + 1):
            q[j] = th0 + dth * s / steps
            c = _shape_clearance(q, lengths, verts, starts, half_width, pts, cl)
            if c < least:
                least = c
    for j in range(n + 1):
        q[j] = qb[j]
    c = _shape_clearance(q, lengths, verts, starts, half_width, pts, cl)
    return min(least, c)


def path_clearance(env: Any, path: Any, res: float = CLEARANCE_RES) -> float:
    """The least clearance (m) of the arm's links over a MASR path (K, n+1) executed along the motion
    convention (module doc); inf with no obstacles."""
    arm = env.arm
    P = np.ascontiguousarray(np.asarray(path, dtype=float).reshape(-1, arm.n + 1))
    verts, starts, _ = polygon_arrays(env.obstacles, 0.0)
    lengths = np.ascontiguousarray(arm.link_lengths, dtype=float)
    reach = np.ascontiguousarray(np.cumsum(lengths[::-1])[::-1])
    rj = np.ascontiguousarray(arm.r, dtype=float)
    pts, cl, order = np.empty((arm.n + 1, 2)), np.empty(arm.n), np.empty(arm.n, dtype=np.int64)
    hw = 0.5 * float(arm.link_width)
    if P.shape[0] == 1:
        return float(action_clearance(P[0], P[0], lengths, rj, reach, verts, starts, hw, res, pts, cl, order))
    return float(min(action_clearance(P[k], P[k + 1], lengths, rj, reach, verts, starts, hw, float(res), pts, cl,
                                      order) for k in range(P.shape[0] - 1)))
