"""OMPL's planners on any of our problems: the same space bounds, the same checker, the same goal.

    from armbridge.planning import ompl_bridge
    if ompl_bridge.available() is None:
        r = ompl_bridge.solve(problem, "RRTConnect", time_limit=1.0)   # -> base.PlanResult

Set-up (PyPI `ompl` 2.x, nanobind bindings; optional extra `armbridge[ompl]`):

* space: a RealVectorStateSpace over the problem space's box [lower, upper]
  (OMPL's own Euclidean metric and straight-line interpolation, which is
  what our joint-box spaces use too);
* state validity: a Python callable that asks our checker (`is_valid`);
* motion validity: a MotionValidator whose checkMotion asks our checker
  (`motion_valid`), so OMPL's edges are checked exactly like ours, at our
  resolution, and every answer counts in `checker.checks` (Table 1's
  "Obstacle Check" column is the difference of that counter). The bindings
  route OMPL's checkMotion(s1, s2, lastValid) overload to the same Python
  method without a last valid state, so KPIECE1 keeps no partial
  motions (its minValidPathFraction never applies);
* goal: a GoalSampleableRegion whose distanceGoal is the goal's own
  `distance` (0 where `is_satisfied`), sampling `problem.goal_states` (known
  goal configurations: RRTConnect grows its goal tree from them, KPIECE1 uses
  them for its goal bias). Without goal states RRTConnect
  cannot start its goal tree and fails at once, as in OMPL;
* projection (KPIECE1 and the other projection planners): the
  caller's `projection` callable (q -> k coordinates; cells given or inferred), or
  else the space's default, OMPL's random linear projection of the joints;
* termination: wall clock `time_limit` and, if given, a number of planner
  iterations, both in one PlannerTerminationCondition; the planners evaluate
  it at the top of every iteration (RRTConnect also inside its connect
  loop), so `iterations` counts the evaluations that let it go on: OMPL's
  iterations, and for RRTConnect its connect steps as well.

STRIDE, which the wheel does not bind, runs through planning.ext.stride
(Debian's OMPL 1.5 behind a C++ shim) with this same set-up.

OMPL's random seed can be set once per process only (`seed_once`: the
first seed asked for stays); every planner object then draws its own seed
from that sequence, so a run of the same queries in the same order is
reproducible, a single query in isolation is not.
Every callback crosses from C++ into Python, which dominates OMPL's time
here (its C++ planners wait on our checker's Python facade, as ours do).
"""
from __future__ import annotations

import builtins
import time
from collections.abc import Callable
from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.planning.base import PlanResult, Problem

#: Planners by name -> the ompl.geometric class name (those the 2.x wheel binds).
PLANNERS = ("RRTConnect", "KPIECE1", "BKPIECE1", "LBKPIECE1", "RRT", "RRTstar", "PRM")

_SEEDED: Optional[int] = None
_EXTRA: dict[str, Callable[[Any], Any]] = {}


def available() -> Optional[str]:
    """None if `ompl` imports, else the reason."""
    try:
        import ompl.base  # type: ignore[import-untyped]  # noqa: F401
        import ompl.geometric  # type: ignore[import-untyped]  # noqa: F401
    except Exception as exc:  # ImportError, or a broken binary wheel
        return f"{type(exc).__name__}: {exc}"
    return None


def require() -> None:
    why = available()
    if why:
        raise ArmbridgeError(f"OMPL is not available ({why}); pip install 'armbridge[ompl]'")


def seed_once(seed: int = 0, quiet: bool = True) -> int:
    """Seed OMPL's generator the first time only (OMPL refuses later seeds); returns the seed in force."""
    from ompl import util as ou  # type: ignore[import-untyped]

    global _SEEDED
    if quiet:
        ou.setLogLevel(ou.LOG_WARN)
    if _SEEDED is None:
        ou.RNG.setSeed(int(seed) + 1)  # OMPL refuses seed 0
        _SEEDED = int(seed)
    return _SEEDED


def register_planner(name: str, make: Callable[[Any], Any]) -> None:
    """Add a planner not in ompl.geometric: make(si) -> an ob.Planner."""
    _EXTRA[name] = make


def planner_names() -> tuple[str, ...]:
    return PLANNERS + tuple(n for n in _EXTRA if n not in PLANNERS)


def make_planner(name: str, si: Any) -> Any:
    from ompl import geometric as og  # type: ignore[import-untyped]

    if name in _EXTRA:
        return _EXTRA[name](si)
    if name not in PLANNERS or not hasattr(og, name):
        raise ArmbridgeError(f"OMPL planner {name!r} unknown; use one of {', '.join(planner_names())}")
    return getattr(og, name)(si)


def real_vector_space(lower: np.ndarray, upper: np.ndarray) -> Any:
    """A RealVectorStateSpace over the box [lower, upper]."""
    from ompl import base as ob

    lo, hi = np.asarray(lower, float).ravel(), np.asarray(upper, float).ravel()
    if lo.shape != hi.shape or lo.size == 0 or not np.all(hi > lo):
        raise ArmbridgeError(f"space bounds must be a non-empty box with upper > lower, got {lo} .. {hi}")
    space = ob.RealVectorStateSpace(int(lo.size))
    bounds = ob.RealVectorBounds(int(lo.size))
    for j in range(lo.size):
        bounds.setLow(j, float(lo[j]))
        bounds.setHigh(j, float(hi[j]))
    space.setBounds(bounds)
    return space


def state_reader(dim: int) -> Callable[[Any], np.ndarray]:
    def to_np(s: Any) -> np.ndarray:
        return np.array([s[i] for i in range(dim)])
    return to_np


def set_state(s: Any, q: np.ndarray) -> None:
    for i in range(q.size):
        s[i] = float(q[i])


def projection_evaluator(space: Any, fn: Callable[[np.ndarray], np.ndarray], dim: int,
                         cell_sizes: Any = None) -> Any:
    """An ob.ProjectionEvaluator calling fn(q) -> (dim,) coordinates.

    Cell sizes: the given ones, or else OMPL's inferred ones (1/20 of the
    projected range of sampled states, ProjectionEvaluator::inferCellSizes).
    The bindings set cell sizes one dimension at a time into an existing
    vector, so they are inferred first and then overwritten. space must be set up.
    """
    from ompl import base as ob

    to_np = state_reader(space.getDimension())
    k = int(dim)

    class Projection(ob.ProjectionEvaluator):
        def getDimension(self) -> int:  # noqa: N802 (OMPL's names)
            return k

        def project(self, state: Any, out: Any) -> None:
            out[:] = fn(to_np(state))

    p = Projection(space)
    p.inferCellSizes()
    if cell_sizes is not None:
        cells = np.asarray(cell_sizes, float).ravel()
        if cells.size != k or not np.all(cells > 0):
            raise ArmbridgeError(f"projection cell sizes must be {k} numbers > 0, got {cells.tolist()}")
        for i in range(k):
            p.setCellSizes(i, float(cells[i]))
    return p


def build(problem: Problem, *, goal_seed: int = 0) -> dict[str, Any]:
    """Space, SpaceInformation (validity + motion callbacks on problem.checker) and ProblemDefinition."""
    from ompl import base as ob

    space = real_vector_space(problem.space.lower, problem.space.upper)
    dim = space.getDimension()
    to_np = state_reader(dim)
    checker, goal = problem.checker, problem.goal
    si = ob.SpaceInformation(space)
    si.setStateValidityChecker(lambda s: bool(checker.is_valid(to_np(s))))

    class CheckerMotion(ob.MotionValidator):
        def checkMotion(self, s1: Any, s2: Any, *rest: Any) -> bool:  # noqa: N802 (OMPL's name)
            return bool(checker.motion_valid(to_np(s1), to_np(s2)))

    motion = CheckerMotion(si)
    si.setMotionValidator(motion)
    si.setup()
    samples = np.asarray(problem.goal_states, float).reshape(-1, dim) if np.size(problem.goal_states) else \
        np.zeros((0, dim))
    rng = np.random.default_rng(goal_seed)

    class ProblemGoal(ob.GoalSampleableRegion):
        def __init__(self, si_: Any) -> None:
            super().__init__(si_)
            self.setThreshold(1e-12)

        def distanceGoal(self, s: Any) -> float:  # noqa: N802
            """0 inside the goal, else the goal's own distance (at least 1e-9, so never taken for inside)."""
            q = to_np(s)
            return 0.0 if goal.is_satisfied(q) else max(float(goal.distance(q)), 1e-9)

        def sampleGoal(self, s: Any) -> None:  # noqa: N802
            set_state(s, samples[rng.integers(samples.shape[0])])

        def maxSampleCount(self) -> int:  # noqa: N802
            return int(samples.shape[0])

        def couldSample(self) -> bool:  # noqa: N802
            return samples.shape[0] > 0

    pdef = ob.ProblemDefinition(si)
    start = space.allocState()
    set_state(start, np.asarray(problem.start, float).ravel())
    pdef.addStartState(start)
    g = ProblemGoal(si)
    pdef.setGoal(g)
    # the Python objects OMPL holds by pointer must live as long as the planner
    return {"space": space, "si": si, "pdef": pdef, "goal": g, "motion": motion, "start": start,
            "to_np": to_np, "goal_states": int(samples.shape[0])}


def solve(problem: Problem, planner: str = "RRTConnect", *, time_limit: float = 1.0,
          iterations: Optional[int] = None, range: Optional[float] = None, goal_bias: Optional[float] = None,
          projection: Optional[tuple[Callable[[np.ndarray], np.ndarray], int, Any]] = None, seed: int = 0,
          simplify: bool = False) -> PlanResult:
    """Plan with OMPL's `planner` until a path into the goal, `time_limit` s or `iterations` iterations.

    projection: (fn, dim, cell_sizes or None) for the projection planners (module doc).
    range: the planner's step (OMPL's "range", joint-space length; its
    default is a fifth of the space's extent); named as OMPL names it.
    The path is the planner's own (un-simplified unless `simplify`); stats
    carry Table 1's columns that exist for OMPL: nodes (its PlannerData
    vertices), track_nodes (path states but the start, before any simplification),
    obstacle_checks (our checker's calls during the solve).
    """
    require()
    from ompl import base as ob
    from ompl import geometric as og

    if not (time_limit > 0):
        raise ArmbridgeError(f"time_limit must be > 0 s, got {time_limit}")
    if iterations is not None and iterations < 1:
        raise ArmbridgeError(f"iterations must be >= 1, got {iterations}")
    seed_in_force = seed_once(seed)
    t_setup = time.perf_counter()
    parts = build(problem, goal_seed=seed)
    si, pdef = parts["si"], parts["pdef"]
    pl = make_planner(planner, si)
    if range is not None and hasattr(pl, "setRange"):
        pl.setRange(float(range))
    if goal_bias is not None and hasattr(pl, "setGoalBias"):
        pl.setGoalBias(float(goal_bias))
    proj = None
    if projection is not None and hasattr(pl, "setProjectionEvaluator"):
        proj = projection_evaluator(parts["space"], *projection)
        pl.setProjectionEvaluator(proj)
    pl.setProblemDefinition(pdef)
    pl.setup()
    setup_s = time.perf_counter() - t_setup

    checker = problem.checker
    checks0 = int(checker.checks)
    count = [0]
    t0 = time.perf_counter()
    deadline = t0 + float(time_limit)
    cap = iterations if iterations is not None else -1

    def stop() -> bool:
        if time.perf_counter() > deadline or (cap > 0 and count[0] >= cap):
            return True
        count[0] += 1
        return False

    status = pl.solve(ob.PlannerTerminationCondition(stop))
    elapsed = time.perf_counter() - t0
    checks = int(checker.checks) - checks0
    to_np = parts["to_np"]
    path = None
    track = 0
    if pdef.hasExactSolution():
        sol = pdef.getSolutionPath()
        track = int(sol.getStateCount()) - 1  # the path's states but the start, as our planners count
        if simplify:
            og.PathSimplifier(si).simplifyMax(sol)
        path = np.array([to_np(sol.getState(i)) for i in builtins.range(sol.getStateCount())])
    pd = ob.PlannerData(si)
    pl.getPlannerData(pd)
    nodes = int(pd.numVertices())
    cost = float(np.sum(problem.space.distance(path[:-1], path[1:]))) if path is not None and len(path) > 1 else \
        (0.0 if path is not None else float("inf"))
    stats = {"nodes": nodes, "track_nodes": track if path is not None else None, "goal_nodes": None,
             "random_nodes": None, "obstacle_checks": checks, "final_H": None,
             "tip_error_m": float(problem.goal.distance(path[-1])) if path is not None else None,
             "status": str(status), "setup_s": setup_s, "goal_states": parts["goal_states"]}
    settings = {"ompl_planner": planner, "time_limit_s": float(time_limit), "iterations_cap": iterations,
                "range": float(pl.getRange()) if hasattr(pl, "getRange") else None,
                "goal_bias": float(pl.getGoalBias()) if hasattr(pl, "getGoalBias") else None,
                "projection": ("given" if proj is not None else
                               ("space default" if hasattr(pl, "setProjectionEvaluator") else None)),
                "ompl_rng_seed": seed_in_force + 1, "simplified": bool(simplify)}
    del parts, pl, proj
    return PlanResult(planner=f"OMPL {planner}", path=path, iterations=count[0], time_s=elapsed,
                      tree_size=nodes, collision_checks=checks, seed=seed, cost=cost, stats=stats, settings=settings)
