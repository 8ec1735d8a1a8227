"""Shortcut smoothing of a planned path (any robot): drop the waypoints a straight edge can skip.

A sampling planner's path zigzags (every node is a random step); the
classic remedy (Geraerts and Overmars 2007; OMPL's PathSimplifier
shortcutPath) tries random pairs of waypoints i < j - 1 and, when the
straight edge between them is valid, removes the waypoints in between. The
first and last waypoints never change, so the path still starts at the
start and ends in the goal. Validity is whatever `checker.motion_valid`
says (the planner's own checker, or a stricter one: planners.plan smooths
soft-arm paths with links widened by the clearance the planner kept).
"""
from __future__ import annotations

from typing import Any

import numpy as np


def shortcut(path: np.ndarray, checker: Any, rng: np.random.Generator, tries: int = 100) -> np.ndarray:
    """path (K, d) with shortcuts taken: `tries` random pairs, then one greedy pass from the start."""
    P = [np.asarray(q, dtype=float) for q in np.asarray(path, dtype=float)]
    for _ in range(int(tries)):
        if len(P) < 3:
            break
        i, j = sorted(int(x) for x in rng.choice(len(P), 2, replace=False))
        if j - i >= 2 and checker.motion_valid(P[i], P[j]):
            del P[i + 1:j]
    out, i = [P[0]], 0
    while i < len(P) - 1:  # greedy: from each kept waypoint, the farthest one reachable in a straight edge
        j = len(P) - 1
        while j > i + 1 and not checker.motion_valid(P[i], P[j]):
            j -= 1
        out.append(P[j])
        i = j
    return np.array(out)
