"""OMPL's STRIDE on any of our problems, through the stride.cpp shim over Debian's OMPL 1.5.

    from armbridge.planning.ext import stride
    if stride.missing() is None:
        r = stride.solve(problem, time_limit=1.0, seed=0)     # -> base.PlanResult

Why a shim: the PyPI ompl wheel (2.0.1) compiles STRIDE (Gipson, Moll &
Kavraki, ICRA 2013) into its libompl.so but binds no Python class for it.
The set-up is ompl_bridge's (module doc there), only in C++: a
RealVectorStateSpace over the problem's box, validity and motion validity
asked of `problem.checker` (so every check counts in `checker.checks`, Table
1's "Obstacle Check" column), a GoalSampleableRegion whose distance is the
goal's own (0 where `is_satisfied`, threshold 1e-12) and which samples
`problem.goal_states` (STRIDE's goal bias, 0.05), and a wall-clock plus
optional iteration PlannerTerminationCondition evaluated once per STRIDE
iteration. STRIDE keeps its defaults: its GNAT over the full state (no
projection; `projection` switches on its projected distance), range a fifth
of the space's extent (OMPL's SelfConfig) unless `range` is given.

Seed: the shim's OMPL is another library than the wheel's, with its own
generator, seeded once per process like ompl_bridge.seed_once (the first
seed stays: OMPL refuses later ones).
"""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.planning.base import PlanResult, Problem
from armbridge.planning.ext import build


def missing() -> Optional[str]:
    """None if STRIDE can run here (the shim is built or can be), else what is missing."""
    why = build.missing()
    return f"the STRIDE shim cannot be built: {why}" if why else None


def goal_distance(goal: Any) -> Callable[[np.ndarray], float]:
    """0 inside the goal, else the goal's own distance (at least 1e-9, so never taken for inside)."""
    def dist(q: np.ndarray) -> float:
        return 0.0 if goal.is_satisfied(q) else max(float(goal.distance(q)), 1e-9)
    return dist


def solve(problem: Problem, *, time_limit: float = 1.0, iterations: Optional[int] = None, seed: int = 0,
          range: Optional[float] = None,
          projection: Optional[tuple[Callable[[np.ndarray], np.ndarray], int]] = None) -> PlanResult:
    """STRIDE until a path into the goal, `time_limit` s or `iterations` iterations -> PlanResult.

    stats carry Table 1's columns that exist for OMPL, as ompl_bridge.solve's
    do: nodes (PlannerData vertices), track_nodes (path states but the
    start), obstacle_checks (our checker's calls during the solve).
    """
    if not (time_limit > 0):
        raise ArmbridgeError(f"time_limit must be > 0 s, got {time_limit}")
    if iterations is not None and iterations < 1:
        raise ArmbridgeError(f"iterations must be >= 1, got {iterations}")
    lo, hi = np.asarray(problem.space.lower, float).ravel(), np.asarray(problem.space.upper, float).ravel()
    if lo.shape != hi.shape or lo.size == 0 or not np.all(hi > lo):
        raise ArmbridgeError(f"space bounds must be a non-empty box with upper > lower, got {lo} .. {hi}")
    mod = build.stride_module()
    goals = np.asarray(problem.goal_states, float).reshape(-1, lo.size) if np.size(problem.goal_states) else \
        np.zeros((0, lo.size))
    checker, goal = problem.checker, problem.goal
    checks0 = int(checker.checks)
    t0 = time.perf_counter()
    out = mod.solve(lo.tolist(), hi.tolist(), np.asarray(problem.start, float).ravel().tolist(), goals.tolist(),
                    lambda q: bool(checker.is_valid(q)), lambda a, b: bool(checker.motion_valid(a, b)),
                    goal_distance(goal), 1e-12, float(time_limit), int(seed), float(range or 0.0),
                    int(iterations or 0), projection[0] if projection else None,
                    int(projection[1]) if projection else 2)
    wall = time.perf_counter() - t0
    checks = int(checker.checks) - checks0
    path = np.array(out["path"], float) if out["solved"] else None
    cost = float(np.sum(problem.space.distance(path[:-1], path[1:]))) if path is not None and len(path) > 1 else \
        (0.0 if path is not None else float("inf"))
    stats = {"nodes": int(out["vertices"]), "track_nodes": len(path) - 1 if path is not None else None,
             "goal_nodes": None, "random_nodes": None, "obstacle_checks": checks, "final_H": None,
             "tip_error_m": float(goal.distance(path[-1])) if path is not None else None,
             "status": str(out["status"]), "setup_s": max(wall - float(out["time_s"]), 0.0),
             "goal_states": int(goals.shape[0])}
    settings = {"ompl_planner": "STRIDE", "ompl": f"Debian libompl {mod.ompl_version()} (stride.cpp shim)",
                "time_limit_s": float(time_limit), "iterations_cap": iterations, "range": float(out["range"]),
                "goal_bias": float(out["goal_bias"]), "projection": "given" if projection else None,
                "ompl_rng_seed": int(out["seed_in_force"]) + 1, "simplified": False}
    return PlanResult(planner="OMPL STRIDE", path=path, iterations=int(out["iterations"]),
                      time_s=float(out["time_s"]), tree_size=int(out["vertices"]), collision_checks=checks, seed=seed,
                      cost=cost, stats=stats, settings=settings)
