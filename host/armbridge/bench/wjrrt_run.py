"""One run of `bench wjrrt`: one planner on one scene and seed, and its record.

The unit both the serial loop (bench/wjrrt.py) and the shards (bench/wjrrt_shards.py)
run; the success a planner claims is re-checked with the bench's own checker.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np

OURS = ("wjrrt", "jt-rrt", "birrt")
OMPL = ("RRTConnect", "KPIECE1", "STRIDE")
PLANNERS = OURS + OMPL


def one_run(scene: Any, planner: str, seed: int, time_limit: float, iterations: Optional[int],
            res: float) -> dict[str, Any]:
    """One planner on one scene and seed -> the run's record (module doc: success is re-checked)."""
    from armbridge.planning.soft import ompl_planners, planners

    if planner in OURS:
        r = planners.plan(scene, planner, seed=seed, time_limit=time_limit, iterations=iterations, res=res)
    else:
        r = ompl_planners.plan(scene, planner, seed=seed, time_limit=time_limit, res=res)
    recheck = None
    if r.path is not None:
        chk = scene.checker(res)
        recheck = chk.path_problem(r.path)
        if recheck is None and not bool(np.linalg.norm(chk.tip(r.path[-1]) - scene.goal_point) <= scene.goal_tol):
            recheck = "the last state is not in the goal"
    rec: dict[str, Any] = {"seed": seed, "success": r.path is not None and recheck is None,
                           "planner_success": r.path is not None, "recheck": recheck, "time_s": float(r.time_s),
                           "iterations": int(r.iterations)}
    for key in ("nodes", "track_nodes", "goal_nodes", "random_nodes", "obstacle_checks", "final_H", "tip_error_m"):
        v = r.stats.get(key)
        rec[key] = None if v is None else float(v) if key in ("final_H", "tip_error_m") else int(v)
    if "status" in r.stats:
        rec["status"] = r.stats["status"]
    return rec
