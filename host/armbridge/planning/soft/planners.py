"""One entry point for the soft arm's planners: plan(scene, "wjrrt" | "jt-rrt" | "birrt", seed=...).

The scene's "params" are the defaults (docs/planning-soft.md); keyword
overrides win. Each planner takes only the parameters it has (JT-RRT has no
weights, Bi-RRT only a step), so a scene's WJRRT thresholds never leak into
a baseline. Every planner checks with the scene's planning checker: every
link keeps the clearance margin (m; `margin`, else the scene's planning
margin, planning/soft/margin.py) from every obstacle, for every state of
every edge. smooth=True shortcuts the path (planning.smoothing) with the
same margined checker and the clearance objective (margin.ClearanceObjective):
a shortcut keeps min(smooth_target, the clearance of the piece it replaces),
smooth_target = max(2 margin, d_min) (our choice: twice the margin, or the
clearance WJRRT asks of its nodes); the stats stay those of the planner's own
path but for `clearance_min_m`, the returned path's least clearance (m,
sampled at margin.CLEARANCE_RES; None without a path). settings["margin_m"]
is the margin planned for.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.planning.base import PlanResult
from armbridge.planning.smoothing import shortcut
from armbridge.planning.soft import birrt, connect, jacobian_rrt
from armbridge.planning.margin import check_margin
from armbridge.planning.soft.margin import ClearanceObjective
from armbridge.planning.soft.scene import Scene
from armbridge.planning.soft.space import EDGE_RES

PLANNERS = ("wjrrt", "jt-rrt", "birrt", "wjrrt-connect")
#: Iterations when neither the scene nor the call gives any.
ITERATIONS = 1000


def accepted(planner: str) -> tuple[str, ...]:
    """The parameter names a planner takes (besides iterations, seed, time_limit)."""
    if planner == "birrt":
        return tuple(birrt.DEFAULTS)
    if planner == "jt-rrt":
        return tuple(k for k in jacobian_rrt.DEFAULTS if k not in jacobian_rrt._WEIGHTED)
    if planner == "wjrrt":
        return tuple(jacobian_rrt.DEFAULTS)
    if planner == "wjrrt-connect":
        return tuple(connect.DEFAULTS)
    raise ArmbridgeError(f"unknown soft planner {planner!r} (known: {', '.join(PLANNERS)})")


def plan(scene: Scene, planner: str = "wjrrt", *, seed: int = 0, iterations: Optional[int] = None,
         time_limit: Optional[float] = None, res: float = EDGE_RES, smooth: bool = False,
         margin: Optional[float] = None, **overrides: Any) -> PlanResult:
    """Plan on a scene with one of PLANNERS; same seed, same plan (one numpy Generator stream per run).
    margin (m): the clearance to keep (default: scene.planning_margin)."""
    keys = accepted(planner)
    for key in overrides:
        if key not in keys:
            raise ArmbridgeError(f"{planner}: unknown parameter {key!r} (it takes: {', '.join(keys)})")
    params = {k: v for k, v in scene.params.items() if k in keys and not (planner == "wjrrt-connect"
                                                                          and k in connect.OWN)}
    params.update(overrides)
    iters = int(iterations if iterations is not None else scene.params.get("iterations", ITERATIONS))
    margin = scene.planning_margin if margin is None else check_margin(margin)
    problem = scene.problem(res, margin=margin)
    if planner == "birrt":
        result = birrt.solve(problem, iterations=iters, seed=seed, time_limit=time_limit, **params)
    elif planner == "wjrrt-connect":
        result = connect.solve(problem, iterations=iters, seed=seed, time_limit=time_limit, **params)
    else:
        result = jacobian_rrt.solve(problem, variant=planner, iterations=iters, seed=seed, time_limit=time_limit,
                                    **params)
    result.settings["scene"] = scene.name
    result.settings["margin_m"] = margin
    if smooth and result.path is not None:
        d_min = max(float(params.get("d_min", 0.0)), 0.0)
        checker = scene.planning_checker(res, margin=margin)
        result.path = shortcut(result.path, checker, np.random.default_rng([seed, 1]),
                               objective=ClearanceObjective(checker), target=max(2.0 * margin, d_min))
        result.cost = float(np.sum(np.linalg.norm(np.diff(result.path, axis=0), axis=1)))
        result.settings["smoothed"] = True
    result.stats["clearance_min_m"] = path_clearance(scene, result.path, res)
    return result


def path_clearance(scene: Scene, path: Optional[np.ndarray], res: float = EDGE_RES) -> Optional[float]:
    """The least link-surface clearance along path (m; margin.ClearanceObjective on a fresh touch checker),
    None without a path."""
    if path is None:
        return None
    return ClearanceObjective(scene.checker(res)).path(path)
