"""Bi-RRT: RRT-Connect (Kuffner and LaValle 2000), the WJRRT paper's bidirectional baseline [56].

Two planning.tree.Tree objects grow in joint space: one from the start,
one from the goal configurations (problem.goal_states: a scene's goal_q and
those the tip descent of ik.py found; every one is a root of the goal
tree). Each iteration one tree extends a step of at most `step` rad
towards a uniform sample (EXTEND); if it grew, the other tree steps
towards the new node until it reaches it or is blocked (CONNECT); when they
meet, the path is the start tree's branch followed by the goal tree's
branch reversed. Then the trees swap roles. Edges are checked with
checker.motion_valid; there are no weights (the plain collision test).
"""
from __future__ import annotations

import time
from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.planning.base import PlanResult, Problem
from armbridge.planning.soft.jacobian_rrt import RANDOM, START, chain_result
from armbridge.planning.tree import Tree

DEFAULTS: dict[str, Any] = {"step": 0.1}
#: Kind of the goal tree's roots (goal configurations).
GOAL_ROOT = 3


def _grow(tree: Tree, q: np.ndarray, step: float, problem: Problem) -> tuple[int, bool]:
    """One EXTEND step of tree towards q: (the new node or -1, whether it is q itself)."""
    near = tree.nearest(q, np.ones(tree.dim))
    qn = problem.space.interpolate(tree.Q[near], q, step)
    if not problem.checker.motion_valid(tree.Q[near], qn):
        return -1, False
    arrived = bool(np.array_equal(qn, q))
    return tree.add(qn, near, tree.cost[near] + float(np.linalg.norm(qn - tree.Q[near])), RANDOM), arrived


def solve(problem: Problem, *, iterations: int = 1000, seed: int = 0, time_limit: Optional[float] = None,
          step: float = DEFAULTS["step"]) -> PlanResult:
    """Plan with RRT-Connect from problem.start to any of problem.goal_states (module doc)."""
    if not step > 0:
        raise ArmbridgeError(f"birrt: step = {step} rad is outside (0, pi]")
    chk, goal = problem.checker, problem.goal
    roots = np.asarray(problem.goal_states, dtype=float).reshape(-1, chk.n) if problem.goal_states.size else None
    if roots is None:
        raise ArmbridgeError("birrt needs goal configurations (problem.goal_states): Scene.problem() finds them "
                             f"by tip descent, keeping the checker's {getattr(chk, 'margin', 0.0) * 1000:g} mm "
                             "clearance margin; none were found")
    rng = np.random.default_rng(seed)
    checks0 = chk.checks
    t0 = time.perf_counter()
    ta = Tree(problem.start, capacity=1024, kind=START)
    tb = Tree(roots[0], capacity=1024, kind=GOAL_ROOT)
    for r in roots[1:]:
        tb.add(r, -1, 0.0, GOAL_ROOT)
    trees = [ta, tb]  # trees[0] extends, trees[1] connects
    joint: Optional[tuple[int, int]] = None  # (node in ta, node in tb) where they met
    it = 0
    while joint is None and it < iterations and (time_limit is None or time.perf_counter() - t0 < time_limit):
        it += 1
        q_rand = problem.space.sample(rng, 1)[0]
        a, _ = _grow(trees[0], q_rand, step, problem)
        if a >= 0:
            target = trees[0].Q[a].copy()
            while True:
                b, arrived = _grow(trees[1], target, step, problem)
                if b < 0:
                    break
                if arrived:
                    joint = (a, b) if trees[0] is ta else (b, a)
                    break
        trees.reverse()

    elapsed = time.perf_counter() - t0
    if joint is None:
        end = int(np.argmin([goal.distance(q) for q in ta.Q[: ta.count]]))
        result = chain_result("birrt", ta, -1, end, it, elapsed, chk.checks - checks0, seed,
                              goal.distance(ta.Q[end]), None, {"step": step}, goal_nodes=False)
        result.tree_size = result.stats["nodes"] = ta.count + tb.count
        return result
    # The path: start -> ta's meeting node, then tb's meeting node (the same configuration) -> its root.
    ia, ib = ta.path_to(joint[0]), tb.path_to(joint[1])[::-1]
    merged = Tree(problem.start, capacity=ia.size + ib.size, kind=START)
    v = 0
    for q, kind in [*zip(ta.Q[ia[1:]], ta.kind[ia[1:]]), *zip(tb.Q[ib[1:]], tb.kind[ib[1:]])]:
        v = merged.add(q, v, 0.0, int(kind))
    result = chain_result("birrt", merged, v, v, it, elapsed, chk.checks - checks0, seed,
                          goal.distance(merged.Q[v]), None, {"step": step}, goal_nodes=False)
    result.tree_size = result.stats["nodes"] = ta.count + tb.count
    result.stats["random_nodes"] = result.stats["track_nodes"]  # every track node came from EXTEND / CONNECT
    return result
