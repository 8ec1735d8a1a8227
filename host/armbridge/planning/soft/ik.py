"""Goal configurations for a tip goal: multi-start Jacobian-transpose descent (no inverse kinematics).

The WJRRT paper plans without IK (section III-B); a bidirectional planner
(Bi-RRT, OMPL's RRTConnect) needs configurations in the goal to root its
goal tree, and a scene loader needs to know the goal point is reachable
inside the joint limits. Both use this: from uniform random starts in the
joint box, repeat the clipped transpose step of eq. (17)-(19) (space.jt_step)
until the tip is within tol of the point; keep the collision-free results.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np
from numba import njit

from armbridge.planning.soft.jtstep import jt_step
from armbridge.planning.soft.space import ChainChecker

#: Tip step of one descent iteration (m); large enough to cross the arm's workspace in a few dozen steps.
DESCENT_DX = 0.05
DESCENT_ITERS = 300


@njit(cache=True)
def tip_descent(q0, goal, tol, dx, iters, lengths, base, lo, hi, pts, J, q):
    """Repeat jt_step from q0 (into q) until the tip is within tol of goal; returns the final tip distance."""
    n = lengths.size
    nxt = np.empty(n)
    for j in range(n):
        q[j] = q0[j]
    for _ in range(iters):
        d = jt_step(q, goal, dx, lengths, base, lo, hi, pts, J, nxt)
        if d <= tol:
            return d
        for j in range(n):
            q[j] = nxt[j]
    return jt_step(q, goal, dx, lengths, base, lo, hi, pts, J, nxt)  # the distance at the last q


def goal_configs(checker: ChainChecker, point: Any, tol: float, *, starts: int = 64, seed: int = 0,
                 extra: Optional[np.ndarray] = None) -> tuple[np.ndarray, float]:
    """(collision-free configurations with the tip within tol of point (m, n), the closest tip distance found).

    The descent aims at tol / 2 so that every result is strictly inside the goal; `extra` configurations
    (the start, a file's goal q) are tried first.
    """
    rng = np.random.default_rng(seed)
    n = checker.n
    q0 = checker.lower + rng.random((starts, n)) * (checker.upper - checker.lower)
    if extra is not None:
        q0 = np.concatenate([np.asarray(extra, float).reshape(-1, n), q0])
    goal = np.ascontiguousarray(point, dtype=float)
    pts, J, q = np.empty((n + 1, 2)), np.empty((2, n)), np.empty(n)
    found, best = [], np.inf
    for s in q0:
        d = tip_descent(np.ascontiguousarray(s), goal, 0.5 * tol, DESCENT_DX, DESCENT_ITERS, checker.lengths,
                        checker.base, checker.lower, checker.upper, pts, J, q)
        best = min(best, d)
        if d <= tol and checker.is_valid(q):
            found.append(q.copy())
    return (np.array(found) if found else np.zeros((0, n))), float(best)


#: Tip step of the goal's last approach (m): small, so the state it adds is a short, checked edge away.
SETTLE_DX = 0.002
SETTLE_ITERS = 2000


def onto_goal(path: np.ndarray, checker: ChainChecker, point: Any, tol: float) -> np.ndarray:
    """The path with one more state whose tip is on the goal point (aiming at tol / 20,
    taken within tol / 4), when that state and the edge to it are free; else the
    path as it is.

    Why: a tip-goal planner stops at the first state inside the goal disc
    (WJRRT's Algorithm 2: X_G and its radius), which is usually on the disc's
    rim (1.95 mm from a 2 mm goal on the soft demo), so an arm that executes
    it with any error at all ends outside. The same clipped transpose descent
    (eq. (17)-(19)) as goal_configs, from the path's last state, in short steps.
    """
    n = checker.n
    last = np.ascontiguousarray(path[-1], dtype=float)
    pts, J, q = np.empty((n + 1, 2)), np.empty((2, n)), np.empty(n)
    goal = np.ascontiguousarray(point, dtype=float)
    d = tip_descent(last, goal, tol / 20, SETTLE_DX, SETTLE_ITERS, checker.lengths, checker.base,
                    checker.lower, checker.upper, pts, J, q)
    if d > tol / 4 or not checker.is_valid(q) or not checker.motion_valid(last, q):
        return path
    return np.vstack([path, q[None, :]])
