"""OMPL's RRT* on a MASR environment, with our collision checker and cost, for comparison.

    from armbridge.planning.masr.ompl_compare import ompl_rrt_star
    r = ompl_rrt_star(fixed_environment("E1"), iterations=1000, seed=0)
    r["time_per_1000_s"], r["cost_s"], r["success"]

Set-up (PyPI `ompl` 2.x, nanobind bindings; optional extra `armbridge[ompl]`).
The generic parts are planning.ompl_bridge's, on the environment's
base.Problem (env.problem(): MasrSpace, MasrChecker, MasrGoal):

* state space: RealVectorStateSpace(n+1) over the space's box, C_f (eq. 5):
  joint bounds +-theta_b, d in [0, l];
* state validity: MasrChecker.is_valid (links as segments, obstacles
  inflated by half the link width);
* motion validator: MasrChecker.motion_valid, our CollisionFree along the
  motion convention, so OMPL's edges are checked exactly like ours,
  direction included; every check counts in the checker's `checks`;
* goal: MasrGoal (the goal check over the joint margin, MasrArm.reaches, as
  our planners) as a GoalSampleableRegion sampling goal configurations found
  by numeric IK (collision-free), so OMPL's goal bias (0.1, as the baseline)
  works;
* seeding: once per process (ompl_bridge.seed_once: the first call's seed).

What is MASR's own here: the objective, eq. (8) as OMPL's motion cost (an
OptimizationObjective with motionCost = MasrSpace.cost, declared
non-symmetric), so OMPL's RRT* minimises tau, eq. (7); `objective="length"`
uses OMPL's default path length (Euclidean in C-space) instead; and the
termination, after `iterations` of RRT*'s own iterations (numIterations) or
`max_time` seconds (ompl_bridge.solve takes no objective, so this runs the
bridge's set-up and its own RRTstar). OMPL's k-nearest RRT* rewiring (k from
its rewire factor) and range (0.2 of the space's extent) are left at their
defaults.

The cost reported is always our eq. (7) on the returned path (un-simplified).
Every callback (validity, motion check, motion cost, goal distance) crosses
from C++ into Python; they call our numba kernels directly, but the crossing
itself dominates OMPL's time.
"""
from __future__ import annotations

import math
import time
from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.planning import ompl_bridge
from armbridge.planning.base import Problem


def ompl_available() -> Optional[str]:
    """None if `ompl` imports, else the reason (ompl_bridge.available)."""
    return ompl_bridge.available()


def goal_states(env: Any, count: int = 64, seed: int = 0) -> np.ndarray:
    """Collision-free goal configurations for OMPL's goal sampling: env.goal_q first, then numeric IK's."""
    from armbridge.planning.masr.environment import find_goal_configs

    good, free, _, _ = find_goal_configs(env.arm, env.goal_pose, env.planning_checker(), e_p=env.e_p, e_phi=env.e_phi,
                                         starts=max(count, 16), seed=seed,
                                         extra_starts=env.goal_q if env.goal_q is not None else None)
    samples = good[free]
    if env.goal_q is not None:
        samples = np.concatenate([np.asarray(env.goal_q, float)[None], samples])
    if samples.shape[0] == 0:
        raise ArmbridgeError(f"{env.name}: no collision-free goal configuration for OMPL's goal sampling")
    return samples


def ompl_rrt_star(env: Any, iterations: int = 1000, seed: int = 0, *, objective: str = "eq8",
                  goal_bias: float = 0.1, goal_configs: int = 64, max_time: float = 120.0,
                  quiet: bool = True) -> dict[str, Any]:
    """Run OMPL's RRT* on env for `iterations` iterations; returns timings and the eq. (7) cost."""
    ompl_bridge.require()
    from ompl import base as ob  # type: ignore[import-untyped]

    if objective not in ("eq8", "length"):
        raise ArmbridgeError(f"objective must be eq8 or length, got {objective!r}")
    seeded = ompl_bridge.seed_once(seed, quiet=quiet)
    base_problem = env.problem()
    problem = Problem(base_problem.space, base_problem.checker, base_problem.start, base_problem.goal,
                      goal_states(env, goal_configs, seed), env.name)
    space, checker = problem.space, problem.checker
    parts = ompl_bridge.build(problem, goal_seed=seed)
    si, pdef, to_np = parts["si"], parts["pdef"], parts["to_np"]

    class ActionTime(ob.OptimizationObjective):
        def stateCost(self, s: Any) -> Any:  # noqa: N802
            return ob.Cost(0.0)

        def motionCost(self, s1: Any, s2: Any) -> Any:  # noqa: N802
            return ob.Cost(space.cost(to_np(s1), to_np(s2)))

        def isSymmetric(self) -> bool:  # noqa: N802
            return False

    obj = ActionTime(si) if objective == "eq8" else ob.PathLengthOptimizationObjective(si)
    pdef.setOptimizationObjective(obj)
    planner = ompl_bridge.make_planner("RRTstar", si)
    planner.setGoalBias(goal_bias)
    planner.setProblemDefinition(pdef)
    planner.setup()

    checks0 = checker.checks
    deadline = time.perf_counter() + max_time
    ptc = ob.PlannerTerminationCondition(
        lambda: planner.numIterations() >= iterations or time.perf_counter() > deadline)
    t0 = time.perf_counter()
    status = planner.solve(ptc)
    elapsed = time.perf_counter() - t0
    done = int(planner.numIterations())
    path = None
    cost = math.inf
    exact = pdef.hasExactSolution()
    if exact:
        sol = pdef.getSolutionPath()
        path = np.array([to_np(sol.getState(i)) for i in range(sol.getStateCount())])
        cost = space.path_cost(path)
    return {
        "planner": "ompl RRTstar",
        "objective": "eq. (8) action time" if objective == "eq8" else "OMPL path length (C-space Euclidean)",
        "status": str(status),
        "success": bool(exact),
        "cost_s": cost if exact else None,
        "ompl_best_cost": float(planner.bestCost().value()),
        "iterations": done,
        "time_s": elapsed,
        "time_per_1000_s": elapsed / max(done, 1) * 1000.0,
        "collision_checks": int(checker.checks - checks0),
        "goal_configurations": int(parts["goal_states"]),
        "path": path,
        "seed": seed,
        "ompl_rng_seed": seeded + 1,
    }
