"""A soft-arm plan on disk: an ordinary joint plan (plans/format.py) whose provenance carries the rest.

The pump board runs joint waypoints like any board, so a soft plan is an
`armbridge-plan` file that `armbridge run` executes as it is (docs/formats.md):
its waypoints are the pump waypoints of planning/soft/waypoints.py, each pose
reached in its move time and then repeated for its settle hold. What only the
soft arm needs rides in `provenance["soft_plan"]`:

    scene        name, file, base (x, y, heading), link_width, obstacles (world frame), goal {point, tol}
    planner      wjrrt | jt-rrt | birrt, seed, iterations, planning_time_s, stats (PlanResult.stats)
    planned_path the planner's whole path (K, n), rad
    waypoints    the selection criterion and its outcome (PumpWaypoints.criterion: nodes kept,
                 tolerance, snapped joints, tracking errors, move and hold times)
    timing       the PumpTiming model the durations came from
    pose_rows    for each pose, the plan row whose move reaches it (a hold, when there is one, is the next row)

`soft_info(plan)` reads it back (one ArmbridgeError naming the field when it is
damaged) and `recording_layers(plan)` gives the executor's recording the scene
to draw beside the arm (obstacles, the planned tip path, the arm at each pose),
in the arm's base frame, which is where the recording draws the arm.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.plans.format import Plan, make_plan

KEY = "soft_plan"


def to_base_frame(points: Any, base: Any) -> np.ndarray:
    """World points (..., 2) in the frame of a base pose (x, y, heading): where robot FK puts them."""
    b = np.asarray(base, float)
    c, s = np.cos(b[2]), np.sin(b[2])
    d = np.asarray(points, float) - b[:2]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


def _rounded(a: Any, nd: int = 6) -> list:
    return np.round(np.asarray(a, float), nd).tolist()


def soft_plan(scene: Any, result: Any, waypoints: Any, timing: Any, *, planner: str, seed: int,
              tool: str = "armbridge plan soft") -> Plan:
    """The Plan of a planned path's pump waypoints (planning.soft.waypoints.PumpWaypoints), validated."""
    rows, durs = waypoints.plan_rows()
    pose_rows, r = [], 0
    for hold in waypoints.hold_s:
        pose_rows.append(r)
        r += 2 if hold > 0 else 1
    section = {
        "scene": {"name": scene.name, "file": str(scene.source) if scene.source is not None else None,
                  "base": _rounded(scene.base), "link_width": float(scene.link_width),
                  "obstacles": [_rounded(p) for p in scene.obstacles],
                  "goal": {"point": _rounded(scene.goal_point), "tol": float(scene.goal_tol)}},
        "planner": planner, "seed": int(seed), "iterations": int(result.iterations),
        "planning_time_s": round(float(result.time_s), 4),
        "stats": {k: (v if isinstance(v, (int, str, type(None))) else float(v)) for k, v in result.stats.items()},
        "planned_path": _rounded(result.path),
        "waypoints": waypoints.criterion(),
        "timing": timing.to_dict(),
        "pose_rows": pose_rows,
    }
    prov = {"tool": tool, "name": f"soft-{scene.name}-{planner}", KEY: section}
    return make_plan(scene.robot, rows, durs, prov)


@dataclass
class SoftInfo:
    """provenance["soft_plan"] read back (module doc)."""

    scene: str
    base: np.ndarray
    link_width: float
    obstacles: list[np.ndarray]
    goal_point: np.ndarray
    goal_tol: float
    planner: str
    planned_path: np.ndarray
    nodes: np.ndarray
    pose_rows: np.ndarray
    tolerance_m: float


def soft_info(plan: Plan) -> SoftInfo | None:
    """The soft section of a plan's provenance, or None for a plan without one."""
    sec = plan.provenance.get(KEY) if isinstance(plan.provenance, dict) else None
    if sec is None:
        return None
    where = f"{plan.source or '<plan>'}: provenance.{KEY}"

    def get(d: Any, path: str) -> Any:
        cur = d
        for part in path.split("."):
            if not isinstance(cur, dict) or part not in cur:
                raise ArmbridgeError(f"{where}: missing field {path!r}")
            cur = cur[part]
        return cur

    def arr(path: str, shape: tuple[int | None, ...]) -> np.ndarray:
        try:
            a = np.asarray(get(sec, path), dtype=float)
        except (TypeError, ValueError):
            raise ArmbridgeError(f"{where}.{path} must be numbers") from None
        if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape)) \
                or not np.all(np.isfinite(a)):
            raise ArmbridgeError(f"{where}.{path} must be finite numbers of shape "
                                 f"{tuple('K' if s is None else s for s in shape)}, got {a.shape}")
        return a

    n = plan.n
    obstacles = get(sec, "scene.obstacles")
    if not isinstance(obstacles, list):
        raise ArmbridgeError(f"{where}.scene.obstacles must be a list of polygons")
    polys = [_poly(p, i, where) for i, p in enumerate(obstacles)]
    path = arr("planned_path", (None, n))
    pose_rows = arr("pose_rows", (None,)).astype(int)
    if pose_rows.size and (pose_rows.min() < 0 or pose_rows.max() >= plan.k):
        raise ArmbridgeError(f"{where}.pose_rows must be plan rows 0..{plan.k - 1}")
    return SoftInfo(scene=str(get(sec, "scene.name")), base=arr("scene.base", (3,)),
                    link_width=float(get(sec, "scene.link_width")), obstacles=polys,
                    goal_point=arr("scene.goal.point", (2,)), goal_tol=float(get(sec, "scene.goal.tol")),
                    planner=str(get(sec, "planner")), planned_path=path,
                    nodes=arr("waypoints.nodes", (None,)).astype(int), pose_rows=pose_rows,
                    tolerance_m=float(get(sec, "waypoints.tolerance_m")))


def _poly(p: Any, i: int, where: str) -> np.ndarray:
    try:
        a = np.asarray(p, dtype=float)
    except (TypeError, ValueError):
        a = np.zeros((0,))
    if a.ndim != 2 or a.shape[1] != 2 or a.shape[0] < 2 or not np.all(np.isfinite(a)):
        raise ArmbridgeError(f"{where}.scene.obstacles[{i}] must be a list of at least 2 [x, y] vertices")
    return a


def recording_layers(plan: Plan) -> dict[str, tuple[list[np.ndarray], tuple[int, int, int]]] | None:
    """What a run's recording draws of a soft plan beside the arm, in the arm's base frame: entity
    path -> (line strips, colour). None for a plan without a soft section."""
    info = soft_info(plan)
    if info is None:
        return None
    robot = plan.robot
    rings = [to_base_frame(np.vstack([p, p[:1]]) if len(p) > 2 else p, info.base) for p in info.obstacles]
    return {
        "world/obstacles": (rings, (200, 60, 60)),
        "plan/planned_tip": ([np.asarray(robot.ee_point(info.planned_path))], (0, 114, 178)),
        "plan/shapes": (list(np.asarray(robot.joint_points(plan.q[info.pose_rows]))), (150, 150, 150)),
    }
