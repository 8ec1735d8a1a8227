"""The soft arm's section of a plan: its scene, its planner's path and its pump waypoints.

The pump board runs joint waypoints like any board, so a soft plan is an
ordinary plan file (plans/format.py; docs/formats.md) that `armbridge run`
executes as it is: its waypoints are the pump waypoints of
planning/soft/waypoints.py, each pose reached in its move time and then
repeated for its settle hold. What only the soft arm needs is its `soft`
section (version 1 files carried it in `provenance["soft_plan"]`, read the same):

    scene        name, file, base (x, y, heading), link_width, obstacles (world frame), goal {point, tol}
    planner      wjrrt | jt-rrt | birrt, seed, iterations, planning_time_s, stats (PlanResult.stats)
    planned_path the planner's whole path (K, n), rad
    waypoints    the selection criterion and its outcome (PumpWaypoints.criterion: nodes kept,
                 tolerance, snapped joints, tracking errors, move and hold times)
    timing       the PumpTiming model the durations came from
    pose_rows    for each pose, the plan row whose move reaches it (a hold, when there is one, is the next row)
    margin_mm    the clearance margin the plan was planned for: every link keeps it from every obstacle
                 (planning/soft/margin.py; absent in plans written before it)
    clearance_min_mm          the least link clearance along the pump waypoints' straight segments
    planned_clearance_min_mm  the same along the planner's path (both sampled at 0.2 mm of point motion)

`read_section` checks it at load (one ArmbridgeError naming the field when it is
damaged), `soft_info(plan)` reads it back, and `recording_layers(plan)` gives the
executor's recording the scene to draw beside the arm (obstacles, the planned tip
path, the arm at each pose), in the arm's base frame, which is where the recording
draws the arm. planning/soft/plan_file.py writes it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.plans.checks import polygon

KEY_V1 = "soft_plan"  # where version 1 kept the section: provenance["soft_plan"]


def to_base_frame(points: Any, base: Any) -> np.ndarray:
    """World points (..., 2) in the frame of a base pose (x, y, heading): where robot FK puts them."""
    b = np.asarray(base, float)
    c, s = np.cos(b[2]), np.sin(b[2])
    d = np.asarray(points, float) - b[:2]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


@dataclass
class SoftInfo:
    """A plan's soft section read back (module doc)."""

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
    margin_mm: float | None = None
    clearance_min_mm: float | None = None


def soft_info(plan: Any) -> SoftInfo | None:
    """The soft section of a plan, or None for a plan without one."""
    if plan.soft is None:
        return None
    return read_section(plan.soft, plan.n, plan.k, f"{plan.source or '<plan>'}: soft")


def read_section(sec: Any, n: int, k: int, where: str) -> SoftInfo:
    """The section `sec` of a plan of k waypoints of n joints, checked; ArmbridgeError names the field."""
    if not isinstance(sec, dict):
        raise ArmbridgeError(f"{where} must be an object")

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

    obstacles = get(sec, "scene.obstacles")
    if not isinstance(obstacles, list):
        raise ArmbridgeError(f"{where}.scene.obstacles must be a list of polygons")
    polys = [polygon(p, f"{where}.scene.obstacles[{i}]") for i, p in enumerate(obstacles)]
    path = arr("planned_path", (None, n))
    pose_rows = arr("pose_rows", (None,)).astype(int)
    extra: dict[str, float | None] = {}
    for key in ("margin_mm", "clearance_min_mm"):
        v = sec.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v)):
            raise ArmbridgeError(f"{where}.{key} must be a finite number (mm), got {v!r}")
        extra[key] = None if v is None else float(v)
    if pose_rows.size and (pose_rows.min() < 0 or pose_rows.max() >= k):
        raise ArmbridgeError(f"{where}.pose_rows must be plan rows 0..{k - 1}")
    return SoftInfo(scene=str(get(sec, "scene.name")), base=arr("scene.base", (3,)),
                    link_width=float(get(sec, "scene.link_width")), obstacles=polys,
                    goal_point=arr("scene.goal.point", (2,)), goal_tol=float(get(sec, "scene.goal.tol")),
                    planner=str(get(sec, "planner")), planned_path=path,
                    nodes=arr("waypoints.nodes", (None,)).astype(int), pose_rows=pose_rows,
                    tolerance_m=float(get(sec, "waypoints.tolerance_m")), **extra)


def recording_layers(plan: Any) -> dict[str, tuple[list[np.ndarray], tuple[int, int, int]]] | None:
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
