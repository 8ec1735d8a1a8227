"""One run of `bench wjrrt`: one planner on one scene and seed, and its record.

The unit both the serial loop (bench/wjrrt.py) and the shards (bench/wjrrt_shards.py)
run; the success a planner claims is re-checked with the bench's own checker.
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, Optional

import numpy as np

OURS = ("wjrrt", "jt-rrt", "birrt", "wjrrt-connect")
OMPL = ("RRTConnect", "KPIECE1", "STRIDE")
PLANNERS = OURS + OMPL
#: Planners warmed up in this process (warm_up).
_WARM: set[str] = set()


def warm_scene() -> Any:
    """The warm-up's tiny scene: soft2 reaching over a block (goal q given, one polygon, 15 mm links)."""
    from armbridge.planning.soft.scene import FORMAT, VERSION, scene_from_dict
    from armbridge.robots.catalog import get_robot

    goal_q = [0.5, 0.9]
    doc = {"format": FORMAT, "version": VERSION, "name": "warm-up", "robot": "soft2", "link_width": 0.015,
           "obstacles": [[[0.17, 0.09], [0.19, 0.09], [0.19, 0.11], [0.17, 0.11]]], "start": [0.0, 0.0],
           "goal": {"point": get_robot("soft2").ee_point(np.array(goal_q)).tolist(), "tol": 0.004, "q": goal_q},
           "params": {"iterations": 60, "d_min": 0.002, "C1": 0.01}}
    return scene_from_dict(doc, "bench wjrrt warm-up")


def warm_up(planners: Sequence[str], res: Optional[float] = None) -> float:
    """Run each planner once on warm_scene() (ours 60 iterations, OMPL's 0.05 s), once per process: numba
    compiles (or loads from its cache) every jitted function the planners and the re-check use, OMPL and
    the STRIDE shim are imported and built, before any run's budget starts. Returns the seconds it took."""
    from armbridge.planning import ompl_bridge
    from armbridge.planning.soft import ompl_planners, planners as ours
    from armbridge.planning.soft.space import EDGE_RES

    todo = [pl for pl in planners if pl not in _WARM]
    if not todo:
        return 0.0
    t0 = time.perf_counter()
    scene = warm_scene()
    res = EDGE_RES if res is None else float(res)
    for pl in todo:
        if pl in OURS:
            r = ours.plan(scene, pl, seed=0, res=res)
        else:
            ompl_bridge.seed_once(0)  # as seed_shard does: the first seed of a process stays
            r = ompl_planners.plan(scene, pl, seed=0, time_limit=0.05, res=res)
        if r.path is not None:  # one_run's re-check
            chk = scene.planning_checker(res)
            chk.path_problem(r.path)
            chk.tip(r.path[-1])
        _WARM.add(pl)
    return time.perf_counter() - t0


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
        chk = scene.planning_checker(res)  # with the margin the planners kept (planning/soft/margin.py)
        recheck = chk.path_problem(r.path)
        if recheck is None and not bool(np.linalg.norm(chk.tip(r.path[-1]) - scene.goal_point) <= scene.goal_tol):
            recheck = "the last state is not in the goal"
    rec: dict[str, Any] = {"seed": seed, "success": r.path is not None and recheck is None,
                           "planner_success": r.path is not None, "recheck": recheck, "time_s": float(r.time_s),
                           "iterations": int(r.iterations)}
    for key in ("nodes", "track_nodes", "goal_nodes", "random_nodes", "obstacle_checks", "final_H", "tip_error_m",
                "clearance_min_m"):
        v = r.stats.get(key)
        rec[key] = None if v is None else float(v) if key in ("final_H", "tip_error_m", "clearance_min_m") else int(v)
    if "status" in r.stats:
        rec["status"] = r.stats["status"]
    return rec
