"""A soft-arm plan as the planner writes it: an ordinary plan with its `soft` section.

The pump board runs joint waypoints like any board: `soft_plan` turns a planned
path's pump waypoints (planning/soft/waypoints.py) into a plan file's rows, each
pose reached in its move time and then repeated for its settle hold, and fills
the plan's `soft` section (plans/soft.py: the scene, the planner's path, the
waypoint criterion, the timing model, the pose rows), which the executor, the
recording and the demo read back there.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np

from armbridge.plans.format import Plan, make_plan


def _rounded(a: Any, nd: int = 6) -> list:
    return np.round(np.asarray(a, float), nd).tolist()


def soft_plan(scene: Any, result: Any, waypoints: Any, timing: Any, *, planner: str, seed: int,
              tool: str = "armbridge plan soft", clearance: Optional[dict[str, float]] = None) -> Plan:
    """The Plan of a planned path's pump waypoints (planning.soft.waypoints.PumpWaypoints), validated.
    clearance: margin_mm (planned for), clearance_min_mm (the waypoints' segments), planned_clearance_min_mm
    (the planner's path), as planning.soft.command computes them; written into the section as they are."""
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
        **{k: float(v) for k, v in (clearance or {}).items()},
    }
    prov = {"tool": tool, "name": f"soft-{scene.name}-{planner}"}
    return make_plan(scene.robot, rows, durs, prov, soft=section)
