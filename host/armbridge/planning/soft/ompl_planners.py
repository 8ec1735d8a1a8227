"""OMPL's RRTConnect, KPIECE1 and STRIDE on a soft-arm scene, with our checker and goal (planning.ompl_bridge).

    from armbridge.planning.soft import ompl_planners
    r = ompl_planners.plan(fixed_scene("three-arm"), "KPIECE1", seed=0, time_limit=1.0)

The problem is the scene's own (`scene.problem(res)`: the same ChainSpace
box, ChainChecker keeping the same clearance margin, and TipGoal, the same goal configurations from the
scene's goal_q and the tip descent of ik.py) that our planners get, so
the checks they count and the paths they return are comparable; OMPL's
paths are checked again by that checker before they count (bench wjrrt).

Projection planners (KPIECE1, and BKPIECE1 / LBKPIECE1) need a
projection of a state to a few coordinates whose grid cells they explore.
projection="tip" (default) projects onto the tip's (x, y), the quantity the
goal is set in (as WJRRT's Jacobian step works in it); "random" leaves
OMPL's default for a RealVectorStateSpace, the random linear projection to
max(2, ceil(log n)) dimensions that OMPL's KinematicChain demo uses too.
Cell sizes are OMPL's inferred ones (1/20 of the projected range).

STRIDE: the PyPI `ompl` 2.0.1 wheel compiles STRIDE into its libompl.so but
binds no Python class for it, so it runs through planning.ext.stride, a
pybind11 shim over Debian's libompl-dev (OMPL 1.5.2) with the same space,
checker callbacks and goal. It keeps OMPL's defaults, which use no
projection (its GNAT works on the full state), so `projection` does not
apply to it (settings "projection": None). `missing("STRIDE")` says what
is absent (libompl-dev, g++, pybind11) and the benchmark reports it as not run.
Table 1's goal / random node split and H do not exist for OMPL's planners
(stats None).
"""
from __future__ import annotations

from typing import Any, Optional

from armbridge.errors import ArmbridgeError
from armbridge.planning import ompl_bridge
from armbridge.planning.base import PlanResult, Problem
from armbridge.planning.ext import stride
from armbridge.planning.margin import check_margin
from armbridge.planning.soft.space import EDGE_RES

#: The OMPL planners of the soft-arm benchmark (bench wjrrt).
OMPL_PLANNERS = ("RRTConnect", "KPIECE1", "STRIDE")
#: Planners that explore a projection's grid.
PROJECTION = frozenset({"KPIECE1", "BKPIECE1", "LBKPIECE1"})
PROJECTIONS = ("tip", "random")


def missing(planner: str) -> Optional[str]:
    """None if `planner` can run here, else why not."""
    if planner == "STRIDE":
        return stride.missing()
    why = ompl_bridge.available()
    if why:
        return f"OMPL is not available ({why})"
    from ompl import geometric as og  # type: ignore[import-untyped]

    if planner not in ompl_bridge.planner_names() and not hasattr(og, planner):
        return f"unknown OMPL planner {planner!r}"
    return None


def _ensure(planner: str) -> None:
    """Register planners the bridge's list lacks but this wheel binds."""
    from ompl import geometric as og

    if planner not in ompl_bridge.planner_names() and hasattr(og, planner):
        ompl_bridge.register_planner(planner, getattr(og, planner))


def tip_projection(problem: Problem) -> tuple[Any, int, None]:
    """(fn, 2, None): the tip position of q under the problem's checker; cells inferred by OMPL."""
    checker = problem.checker

    def tip(q: Any) -> Any:
        return checker.tip(q)

    return tip, 2, None


def solve(problem: Problem, planner: str = "RRTConnect", *, time_limit: float = 1.0,
          iterations: Optional[int] = None, seed: int = 0, range: Optional[float] = None,
          projection: str = "tip") -> PlanResult:
    """One OMPL planner on a soft Problem (module doc) -> PlanResult with Table 1's stats keys."""
    why = missing(planner)
    if why:
        raise ArmbridgeError(f"OMPL {planner}: {why}")
    if projection not in PROJECTIONS:
        raise ArmbridgeError(f"projection must be one of {', '.join(PROJECTIONS)}, got {projection!r}")
    if planner == "STRIDE":
        return stride.solve(problem, time_limit=time_limit, iterations=iterations, seed=seed, range=range)
    _ensure(planner)
    proj = tip_projection(problem) if planner in PROJECTION and projection == "tip" else None
    result = ompl_bridge.solve(problem, planner, time_limit=time_limit, iterations=iterations, range=range,
                               projection=proj, seed=seed)
    result.settings["projection"] = (projection if planner in PROJECTION else None)
    return result


def plan(scene: Any, planner: str = "RRTConnect", *, seed: int = 0, time_limit: float = 1.0,
         iterations: Optional[int] = None, res: float = EDGE_RES, range: Optional[float] = None,
         projection: str = "tip", margin: Optional[float] = None) -> PlanResult:
    """solve() on scene.problem(res, margin): the margined checker our planners get (planners.plan), and the
    same `margin_m` setting and `clearance_min_m` stat."""
    from armbridge.planning.soft.planners import path_clearance

    margin = scene.planning_margin if margin is None else check_margin(margin)
    result = solve(scene.problem(res, margin=margin), planner, time_limit=time_limit, iterations=iterations,
                   seed=seed, range=range, projection=projection)
    result.settings["scene"] = scene.name
    result.settings["margin_m"] = margin
    result.stats["clearance_min_m"] = path_clearance(scene, result.path, res)
    return result
