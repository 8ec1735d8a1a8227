"""WJRRT (Khan, Li, Kadry, Nam; Algorithms 2-3) and JT-RRT (Vande Weghe et al. 2007, the paper's [55]).

Both grow one planning.tree.Tree in joint space from the start and aim the
tip at the goal point X_G; each iteration, with probability P_G
(`p_goal`), extends towards the goal, else randomly (Algorithm 2):

* extend_Towards_Goal (Algorithm 3): N_c = the node whose tip is closest to
  X_G (nodes whose goal extension failed `goal_tries` times are skipped);
  theta_c is perturbed by k U(-1, 1) per joint (eq. 16: MATLAB's k*rand is
  one-sided, U(0, 1); we centre it so that no joint is pushed one way), and
  one clipped Jacobian-transpose step (space.jt_step, eq. 17-19: the tip
  aims at most `dx` m towards X_G, rho = <dX, JJ^T dX>/|JJ^T dX|^2 so the
  linearised tip step is at most dx) gives theta_new. While the steps keep
  improving, they are chained: a series of goal nodes per call (section
  III-C-2); the first refused or non-improving step ends the call.
* extend_Randomly: a uniform sample, its nearest node in joint space, a step
  of at most `step` rad towards it; one node.

What "refused" means is the one difference between the two planners:

* wjrrt: theta_new's links each keep more than d_min (m) from every
  obstacle (eq. 7's per-link test H_o(l) = 1/dist_l < 1/d_min; all m links
  must pass, else NULL), W_s = sum_l dist_l > C1 (eq. 20, m), W_d =
  sum_l |theta_new,l - theta_c,l| < C2 (eq. 21, rad, theta_c the node
  extended); a goal step must also lower H = |X_G - F(theta)|^2 +
  lambda / min_l dist_l (eq. 9-10) below the call's H_best (from inf);
* jt-rrt: no weights, thresholds or H: any collision-free step is kept,
  and a goal series continues while the tip distance falls.

Both check every new edge with checker.motion_valid (the arm's sweep at the
checker's resolution). The run stops when a node's tip is within the goal's
tol, after `iterations` iterations or after time_limit seconds.
"""
from __future__ import annotations

import math
import time
from typing import Any, Optional

import numpy as np
from numba import njit

from armbridge.errors import ArmbridgeError
from armbridge.planning.base import PlanResult, Problem
from armbridge.planning.soft.jtstep import jt_step
from armbridge.planning.soft.space import link_clearance
from armbridge.planning.tree import Tree

VARIANTS = ("wjrrt", "jt-rrt")
#: Node kinds in tree.kind: Table 1's Goal nodes and Random nodes.
START, GOAL, RANDOM = 0, 1, 2
#: At most this many chained goal steps per extend_Towards_Goal call.
MAX_SERIES = 200
DEFAULTS: dict[str, Any] = {"p_goal": 0.5, "k": 0.02, "dx": 0.01, "step": 0.1, "goal_tries": 3,
                            "C1": 0.0, "C2": math.inf, "lambda": 0.0, "d_min": 0.0}
_WEIGHTED = ("C1", "C2", "lambda", "d_min")


@njit(cache=True)
def weigh(qc, qn, goal, lengths, base, verts, starts, margin, pts, cl):
    """(tip distance to goal, min_l dist_l, W_s, W_d, |qn - qc|) of theta_new = qn extended from theta_c = qc
    (eq. 8, 20, 21; the last is the edge's joint-space length, the tree's cost); cl gets each link's dist_l."""
    least = link_clearance(qn, lengths, base, verts, starts, margin, pts, cl)
    n = lengths.size
    ws = 0.0
    wd = 0.0
    ln = 0.0
    for j in range(n):
        ws += cl[j]
        wd += abs(qn[j] - qc[j])
        ln += (qn[j] - qc[j]) ** 2
    dx, dy = goal[0] - pts[n, 0], goal[1] - pts[n, 1]
    return math.sqrt(dx * dx + dy * dy), least, ws, wd, math.sqrt(ln)


@njit(cache=True)
def goal_step(qc, u, k, goal, dx, lengths, base, lo, hi, verts, starts, margin, pts, J, cl, qp, qn):
    """One extend_Towards_Goal step from theta_c = qc into qn; returns weigh(qc, qn).

    qp = clip(qc + k (2u - 1)) (eq. 16, u uniform in [0, 1)^n), then qn = jt_step(qp) (eq. 17-19).
    """
    for j in range(lengths.size):
        qp[j] = min(max(qc[j] + k * (2.0 * u[j] - 1.0), lo[j]), hi[j])
    jt_step(qp, goal, dx, lengths, base, lo, hi, pts, J, qn)
    return weigh(qc, qn, goal, lengths, base, verts, starts, margin, pts, cl)


def objective(tip_dist: float, least: float, lam: float) -> float:
    """H of eq. (9)-(10): |X_G - F(theta)|^2 + lambda / min_l dist_l (inf when a link touches)."""
    if lam <= 0:
        return tip_dist * tip_dist
    return tip_dist * tip_dist + (lam / least if least > 0 else math.inf)


def _settings(variant: str, params: dict[str, Any]) -> dict[str, Any]:
    if variant not in VARIANTS:
        raise ArmbridgeError(f"unknown variant {variant!r} (known: {', '.join(VARIANTS)})")
    for key in params:
        if key not in DEFAULTS:
            raise ArmbridgeError(f"{variant}: unknown parameter {key!r} (known: {', '.join(DEFAULTS)})")
        if variant == "jt-rrt" and key in _WEIGHTED:
            raise ArmbridgeError(f"jt-rrt has no weights or thresholds: {key!r} is a wjrrt parameter")
    s = {**DEFAULTS, **params}
    if variant == "jt-rrt":
        s.update({"C1": -math.inf, "C2": math.inf, "lambda": 0.0, "d_min": -math.inf})
    return s


def solve(problem: Problem, *, variant: str = "wjrrt", iterations: int = 1000, seed: int = 0,
          time_limit: Optional[float] = None, **params: Any) -> PlanResult:
    """Plan with WJRRT or JT-RRT (module doc); params as DEFAULTS ("lambda" by name: solve(p, **{"lambda": x}))."""
    s = _settings(variant, params)
    chk, goal = problem.checker, problem.goal
    X_G = np.ascontiguousarray(goal.point, dtype=float)
    tol = float(goal.tol)
    rng = np.random.default_rng(seed)
    n = chk.n
    L, B, V, S, m = chk.lengths, chk.base, chk.verts, chk.starts, chk.half_width
    lo, hi = chk.lower, chk.upper
    pts, J, cl = np.empty((n + 1, 2)), np.empty((2, n)), np.empty(n)
    qp, qn, ones = np.empty(n), np.empty(n), np.ones(n)
    p_goal, k, dx, step, tries = float(s["p_goal"]), float(s["k"]), float(s["dx"]), float(s["step"]), s["goal_tries"]
    C1, C2, lam, d_min = float(s["C1"]), float(s["C2"]), float(s["lambda"]), float(s["d_min"])
    weighted = variant == "wjrrt"
    checks0 = chk.checks
    t0 = time.perf_counter()

    start = np.ascontiguousarray(problem.start, dtype=float)
    if not chk.is_valid(start):
        raise ArmbridgeError(f"{variant}: the start configuration is not valid: {chk.describe(chk.code(start))}")
    tree = Tree(start, capacity=1024, kind=START)
    tip_d = np.full(tree.capacity, math.inf)  # per node: tip distance to X_G, inf once exhausted
    fails = np.zeros(tree.capacity, dtype=np.int64)
    d0 = weigh(start, start, X_G, L, B, V, S, m, pts, cl)[0]
    tip_d[0] = d0
    best_v, best_d = 0, d0  # the node closest to X_G so far and its tip distance

    def accept(qc: np.ndarray, q: np.ndarray, w: tuple[float, float, float, float, float]) -> bool:
        """The step qc -> q with weigh()'s w passes the variant's tests (module doc) and its edge is free."""
        if weighted:
            chk.checks += 1  # WJRRT asked the checker for the links' clearance (JT-RRT uses only the tip)
        if weighted and not (w[1] > d_min and w[2] > C1 and w[3] < C2):
            return False
        return bool(chk.motion_valid(qc, q))

    def add(q: np.ndarray, parent: int, d: float, length: float, kind: int) -> int:
        nonlocal tip_d, fails, best_v, best_d
        v = tree.add(q, parent, tree.cost[parent] + length, kind)
        if tree.capacity > tip_d.size:
            tip_d = np.concatenate([tip_d, np.full(tree.capacity - tip_d.size, math.inf)])
            fails = np.concatenate([fails, np.zeros(tree.capacity - fails.size, dtype=np.int64)])
        tip_d[v] = d
        if d < best_d:
            best_v, best_d = v, d
        return v

    def towards_goal() -> int:
        """Algorithm 3 from the node closest to X_G; returns the last node added or -1."""
        c = int(np.argmin(tip_d[: tree.count]))
        if not math.isfinite(tip_d[c]):
            return -1
        h_best, last, qc = math.inf, -1, tree.Q[c]
        for _ in range(MAX_SERIES):
            w = goal_step(qc, rng.random(n), k, X_G, dx, L, B, lo, hi, V, S, m, pts, J, cl, qp, qn)
            if not accept(qc, qn, w):
                break
            h = objective(w[0], w[1], lam)
            if h >= h_best:
                break
            h_best = h
            last = add(qn.copy(), c if last < 0 else last, w[0], w[4], GOAL)
            qc = tree.Q[last]
            if w[0] <= tol:
                break
        if last < 0:
            fails[c] += 1
            if fails[c] >= tries:
                tip_d[c] = math.inf
        return last

    def randomly() -> int:
        qr = problem.space.sample(rng, 1)[0]
        near = tree.nearest(qr, ones)
        q = np.ascontiguousarray(problem.space.interpolate(tree.Q[near], qr, step))
        w = weigh(tree.Q[near], q, X_G, L, B, V, S, m, pts, cl)
        return add(q, near, w[0], w[4], RANDOM) if accept(tree.Q[near], q, w) else -1

    it, reached = 0, -1
    if d0 <= tol:
        reached = 0
    while reached < 0 and it < iterations and (time_limit is None or time.perf_counter() - t0 < time_limit):
        it += 1
        v = towards_goal() if rng.random() < p_goal else randomly()
        if v >= 0 and tip_d[v] <= tol:
            reached = v
    elapsed = time.perf_counter() - t0
    end = reached if reached >= 0 else best_v
    d_end, least_end, _, _, _ = weigh(tree.Q[end], tree.Q[end], X_G, L, B, V, S, m, pts, cl)
    h_end = objective(d_end, least_end, lam) if weighted else None
    return chain_result(variant, tree, reached, end, it, elapsed, chk.checks - checks0, seed, float(d_end), h_end,
                        {key: s[key] for key in s if weighted or key not in _WEIGHTED})


def chain_result(planner: str, tree: Tree, reached: int, end: int, iterations: int, elapsed: float, checks: int,
                 seed: int, tip_error: float, final_h: Optional[float], settings: dict[str, Any],
                 goal_nodes: bool = True) -> PlanResult:
    """A soft planner's PlanResult with Table 1's columns as stats (docs/planning-soft.md).

    The path (start first) is the tree's path to `reached`, or None (-1); track_nodes counts its nodes but
    the start, goal_nodes / random_nodes those of each kind among them (goal_nodes None for a planner
    without goal-directed steps). tip_error_m and final_H are those of `end`: the last path node, or the
    node that came closest to the goal when none arrived.
    """
    idx = tree.path_to(reached) if reached >= 0 else np.zeros(0, dtype=np.int64)
    kinds = tree.kind[idx[1:]]
    stats = {"nodes": tree.count, "track_nodes": int(max(idx.size - 1, 0)),
             "goal_nodes": int(np.sum(kinds == GOAL)) if goal_nodes else None,
             "random_nodes": int(np.sum(kinds == RANDOM)), "obstacle_checks": checks, "final_H": final_h,
             "tip_error_m": tip_error}
    path = tree.Q[idx].copy() if reached >= 0 else None
    cost = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))) if path is not None else math.inf
    return PlanResult(planner, path, iterations, elapsed, tree.count, checks, seed, cost, stats, settings)
