"""One entry point for the soft arm's planners: plan(scene, "wjrrt" | "jt-rrt" | "birrt", seed=...).

The scene's "params" are the defaults (docs/planning-soft.md); keyword
overrides win. Each planner takes only the parameters it has (JT-RRT has no
weights, Bi-RRT only a step), so a scene's WJRRT thresholds never leak into
a baseline. smooth=True shortcuts the path (planning.smoothing) with a
checker whose links are widened by 2 d_min, so the shortcuts keep the
clearance WJRRT kept; the stats stay those of the planner's own path.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.planning.base import PlanResult
from armbridge.planning.smoothing import shortcut
from armbridge.planning.soft import birrt, jacobian_rrt
from armbridge.planning.soft.scene import Scene
from armbridge.planning.soft.space import EDGE_RES

PLANNERS = ("wjrrt", "jt-rrt", "birrt")
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
    raise ArmbridgeError(f"unknown soft planner {planner!r} (known: {', '.join(PLANNERS)})")


def plan(scene: Scene, planner: str = "wjrrt", *, seed: int = 0, iterations: Optional[int] = None,
         time_limit: Optional[float] = None, res: float = EDGE_RES, smooth: bool = False,
         **overrides: Any) -> PlanResult:
    """Plan on a scene with one of PLANNERS; same seed, same plan (one numpy Generator stream per run)."""
    keys = accepted(planner)
    for key in overrides:
        if key not in keys:
            raise ArmbridgeError(f"{planner}: unknown parameter {key!r} (it takes: {', '.join(keys)})")
    params = {k: v for k, v in scene.params.items() if k in keys}
    params.update(overrides)
    iters = int(iterations if iterations is not None else scene.params.get("iterations", ITERATIONS))
    problem = scene.problem(res)
    if planner == "birrt":
        result = birrt.solve(problem, iterations=iters, seed=seed, time_limit=time_limit, **params)
    else:
        result = jacobian_rrt.solve(problem, variant=planner, iterations=iters, seed=seed, time_limit=time_limit,
                                    **params)
    result.settings["scene"] = scene.name
    if smooth and result.path is not None:
        d_min = max(float(params.get("d_min", 0.0)), 0.0)
        strict = scene.checker(res, link_width=scene.link_width + 2.0 * d_min)
        result.path = shortcut(result.path, strict, np.random.default_rng([seed, 1]))
        result.cost = float(np.sum(np.linalg.norm(np.diff(result.path, axis=0), axis=1)))
        result.settings["smoothed"] = True
    return result
