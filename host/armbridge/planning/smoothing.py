"""Shortcut smoothing of a planned path (any robot): drop the waypoints a straight edge can skip.

A sampling planner's path zigzags (every node is a random step); the
classic remedy (Geraerts and Overmars 2007; OMPL's PathSimplifier
shortcutPath) tries random pairs of waypoints i < j - 1 and, when the
straight edge between them is valid, removes the waypoints in between. The
first and last waypoints never change, so the path still starts at the
start and ends in the goal. Validity is whatever `checker.motion_valid`
says (the planner's own checker, or a stricter one).

With a clearance `objective` (an `edge(a, b)` giving the least clearance
along a straight edge, as OMPL's MaximizeMinClearanceObjective measures it;
planning/soft/margin.py ClearanceObjective), a valid shortcut i -> j is
also required to keep

    objective.edge(P[i], P[j]) >= min(target, least clearance of the edges P[i] .. P[j] it replaces),

so smoothing never brings the path closer to an obstacle than `target`
unless the piece it replaces already came that close, and then never
closer than that piece did: the path's clearance never falls, and where it
exceeded `target` it stays at least `target`.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np


def shortcut(path: np.ndarray, checker: Any, rng: np.random.Generator, tries: int = 100,
             objective: Optional[Any] = None, target: float = 0.0) -> np.ndarray:
    """path (K, d) with shortcuts taken: `tries` random pairs, then one greedy pass from the start; with
    `objective`, only shortcuts that keep min(target, the replaced piece's clearance) (module doc)."""
    P = [np.asarray(q, dtype=float) for q in np.asarray(path, dtype=float)]
    # ec[k]: the clearance of edge P[k] -> P[k + 1] (only with an objective)
    ec = [objective.edge(P[k], P[k + 1]) for k in range(len(P) - 1)] if objective is not None else []

    def take(i: int, j: int) -> Optional[float]:
        """The shortcut P[i] -> P[j]'s clearance (0.0 without an objective) if it may replace P[i..j], else None."""
        if not checker.motion_valid(P[i], P[j]):
            return None
        if objective is None:
            return 0.0
        c = float(objective.edge(P[i], P[j]))
        return c if c >= min(target, min(ec[i:j])) else None

    for _ in range(int(tries)):
        if len(P) < 3:
            break
        i, j = sorted(int(x) for x in rng.choice(len(P), 2, replace=False))
        if j - i >= 2:
            c = take(i, j)
            if c is not None:
                del P[i + 1:j]
                if objective is not None:
                    ec[i:j] = [c]
    out, i = [P[0]], 0
    while i < len(P) - 1:  # greedy: from each kept waypoint, the farthest one reachable in a straight edge
        j = len(P) - 1
        while j > i + 1 and take(i, j) is None:
            j -= 1
        out.append(P[j])
        i = j
    return np.array(out)
