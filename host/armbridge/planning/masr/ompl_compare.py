"""OMPL's RRT* on a MASR environment, with our collision checker and cost, for comparison.

    from armbridge.planning.masr.ompl_compare import ompl_rrt_star
    r = ompl_rrt_star(fixed_environment("E1"), iterations=1000, seed=0)
    r["time_per_1000_s"], r["cost_s"], r["success"]

Set-up (PyPI `ompl` 2.x, nanobind bindings; optional extra `armbridge[ompl]`):

* state space: RealVectorStateSpace(n+1) over C_f (eq. 5): joint bounds
  +-theta_b, d in [0, l];
* state validity: our CollisionChecker (links as segments, obstacles inflated
  by half the link width);
* motion validator: our CollisionFree along the motion convention
  (`CollisionChecker.edge_free(q_a, q_b)`), so OMPL's edges are checked
  exactly like ours, direction included;
* objective: eq. (8) as OMPL's motion cost (an OptimizationObjective with
  motionCost = MasrArm.action_cost, declared non-symmetric), so OMPL's RRT*
  minimises tau, eq. (7); `objective="length"` uses OMPL's default path
  length (Euclidean in C-space) instead;
* goal: the goal check as a GoalSampleableRegion (distance = max(dp / e_p,
  dphi / e_phi) over every d within the joint margin, inf within it of a
  joint: MasrArm.reaches, as our planners; threshold 1), which samples goal configurations found by
  numeric IK (collision-free), so OMPL's goal bias (0.1, as the baseline)
  works; OMPL's own k-nearest RRT* rewiring (k from its rewire factor) and
  range (0.2 of the space's extent) are left at their defaults.

The cost reported is always our eq. (7) on the returned path (un-simplified).
Planning runs until OMPL has done `iterations` iterations (a termination
condition on numIterations) or `max_time` seconds. Every callback (motion
check, motion cost, goal distance) crosses from C++ into Python; they call
our numba kernels directly, but the crossing itself dominates OMPL's time.
OMPL's random seed can be set only once per process (the first call's seed).
"""
from __future__ import annotations

import math
import time
from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError


_SEEDED: Optional[int] = None


def ompl_available() -> Optional[str]:
    """None if `ompl` imports, else the reason."""
    try:
        import ompl.base  # type: ignore[import-untyped]  # noqa: F401
        import ompl.geometric  # type: ignore[import-untyped]  # noqa: F401
    except Exception as exc:  # ImportError, or a broken binary wheel
        return f"{type(exc).__name__}: {exc}"
    return None


def ompl_rrt_star(env: Any, iterations: int = 1000, seed: int = 0, *, objective: str = "eq8",
                  goal_bias: float = 0.1, goal_configs: int = 64, max_time: float = 120.0,
                  quiet: bool = True) -> dict[str, Any]:
    """Run OMPL's RRT* on env for `iterations` iterations; returns timings and the eq. (7) cost."""
    why = ompl_available()
    if why:
        raise ArmbridgeError(f"OMPL is not available ({why}); pip install 'armbridge[ompl]'")
    from ompl import base as ob  # type: ignore[import-untyped]
    from ompl import geometric as og  # type: ignore[import-untyped]
    from ompl import util as ou  # type: ignore[import-untyped]

    from armbridge.planning.masr.collision import config_hit, edge_hit, feasible
    from armbridge.robots.masr import MARGIN_TOL
    from armbridge.robots.masr_kernels import action_cost, ma_pose, span_score
    from armbridge.planning.masr.environment import find_goal_configs

    if objective not in ("eq8", "length"):
        raise ArmbridgeError(f"objective must be eq8 or length, got {objective!r}")
    global _SEEDED
    if quiet:
        ou.setLogLevel(ou.LOG_WARN)
    if _SEEDED is None:
        ou.RNG.setSeed(int(seed) + 1)  # OMPL refuses seed 0; it can be set once per process
        _SEEDED = int(seed)
    arm = env.arm
    n = arm.n
    chk = env.checker()

    space = ob.RealVectorStateSpace(n + 1)
    bounds = ob.RealVectorBounds(n + 1)
    for j in range(n):
        bounds.setLow(j, -float(arm.theta_b[j]))
        bounds.setHigh(j, float(arm.theta_b[j]))
    bounds.setLow(n, 0.0)
    bounds.setHigh(n, float(arm.total_length))
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)

    def to_np(s: Any) -> np.ndarray:
        return np.array([s[i] for i in range(n + 1)])

    counts = {"states": 0, "motions": 0}
    # the numba kernels directly: the Python facade's checks would dominate OMPL's time
    K = (chk.lengths, chk.rj, chk.reach, chk.theta_b, float(arm.total_length), chk.verts, chk.starts, chk.bbox,
         chk.r2, chk.sweep_res)
    rj, inv_ms, inv_js = chk.rj, 1.0 / arm.ma_speed, 1.0 / arm.joint_speed
    pts = np.empty((n + 1, 2))

    def valid(s: Any) -> bool:
        counts["states"] += 1
        q = to_np(s)
        return bool(feasible(q, chk.theta_b, K[4])) and config_hit(q, chk.lengths, chk.verts, chk.starts,
                                                                  chk.bbox, chk.r2, pts) < 0

    si.setStateValidityChecker(valid)

    class ConventionMotion(ob.MotionValidator):
        def checkMotion(self, s1: Any, s2: Any, *rest: Any) -> bool:  # noqa: N802 (OMPL's name)
            counts["motions"] += 1
            return edge_hit(to_np(s1), to_np(s2), *K, False) == -1

    mv = ConventionMotion(si)
    si.setMotionValidator(mv)
    si.setup()

    class ActionTime(ob.OptimizationObjective):
        def stateCost(self, s: Any) -> Any:  # noqa: N802
            return ob.Cost(0.0)

        def motionCost(self, s1: Any, s2: Any) -> Any:  # noqa: N802
            return ob.Cost(float(action_cost(to_np(s1), to_np(s2), rj, inv_ms, inv_js)))

        def isSymmetric(self) -> bool:  # noqa: N802
            return False

    good, free, _, _ = find_goal_configs(arm, env.goal_pose, chk, e_p=env.e_p, e_phi=env.e_phi,
                                         starts=max(goal_configs, 16), seed=seed,
                                         extra_starts=env.goal_q if env.goal_q is not None else None)
    samples = good[free]
    if env.goal_q is not None:
        samples = np.concatenate([np.asarray(env.goal_q, float)[None], samples])
    if samples.shape[0] == 0:
        raise ArmbridgeError(f"{env.name}: no collision-free goal configuration for OMPL's goal sampling")
    rng = np.random.default_rng(seed)
    goal_x = np.ascontiguousarray(env.goal_pose, dtype=float)
    inner, d_margin = [float(r) for r in arm.r[1:]], float(arm.d_margin)

    class PoseGoal(ob.GoalSampleableRegion):
        def __init__(self, si_: Any) -> None:
            super().__init__(si_)
            self.setThreshold(1.0)

        def distanceGoal(self, s: Any) -> float:  # noqa: N802
            """The goal check in tolerance units: the span score over the joint margin (<= 1: in the goal)."""
            q = to_np(s)
            if any(abs(q[n] - r) < d_margin - MARGIN_TOL for r in inner):  # MasrArm.holds_margin, per state
                return math.inf
            x, y, phi = ma_pose(q, chk.lengths, rj, K[4], pts)[:3]
            return float(span_score(goal_x, x, y, phi, min(max(q[n], 0.0), K[4]), K[4], d_margin,
                                    env.e_p, env.e_phi))

        def sampleGoal(self, s: Any) -> None:  # noqa: N802
            q = samples[rng.integers(samples.shape[0])]
            for i in range(n + 1):
                s[i] = float(q[i])

        def maxSampleCount(self) -> int:  # noqa: N802
            return int(samples.shape[0])

    pdef = ob.ProblemDefinition(si)
    start = space.allocState()
    for i in range(n + 1):
        start[i] = float(env.start[i])
    pdef.addStartState(start)
    goal = PoseGoal(si)
    pdef.setGoal(goal)
    obj = ActionTime(si) if objective == "eq8" else ob.PathLengthOptimizationObjective(si)
    pdef.setOptimizationObjective(obj)
    planner = og.RRTstar(si)
    planner.setGoalBias(goal_bias)
    planner.setProblemDefinition(pdef)
    planner.setup()

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
        cost = float(arm.path_time(path)) if len(path) > 1 else 0.0
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
        "state_checks": counts["states"],
        "motion_checks": counts["motions"],
        "goal_configurations": int(samples.shape[0]),
        "path": path,
        "seed": seed,
        "ompl_rng_seed": None if _SEEDED is None else _SEEDED + 1,
    }
