"""The PNG of a soft-arm plan (`armbridge plan soft --png`), from planning/figure.py's planar-chain pieces.

In the scene's world frame (the base at its pose): the obstacles with their
link-width margin and a number inside each, the goal's tolerance circle on top,
the start configuration, the arm at every pump waypoint (lighter = earlier), the
final configuration, the planner's whole tip path and the straight tip path the
board's set points take between the waypoints, each waypoint's tip marked. A
detail panel zooms on the goal; the legend sits beside the data.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import numpy as np

from armbridge.planning import figure as F


def soft_figure(scene: Any, path: np.ndarray, waypoints: Optional[np.ndarray], out: Any, *,
                title: Optional[str] = None, margin: Optional[float] = None) -> Path:
    """Draw scene, the planned path (K, n) and the pump waypoints (m, n) (None: none) to out (PNG). The dashed
    outline around each obstacle is where the links' centre lines keep out of: half the link width and the
    clearance margin (m; default the scene's planning margin)."""
    keep = 0.5 * scene.link_width + (scene.planning_margin if margin is None else float(margin))
    checker = scene.checker()
    path = np.asarray(path, float)
    tips = np.array([checker.tip(q) for q in path])
    wp = None if waypoints is None else np.asarray(waypoints, float)
    shapes = [] if wp is None else [checker.points(q) for q in wp[1:-1]]
    base = np.asarray(scene.base, float)
    reach = float(scene.robot.reach)
    pf = F.plan_axes()

    def layer(ax: Any, legend: bool) -> None:
        lab = (lambda s: s) if legend else (lambda s: None)
        F.draw_obstacles(ax, scene.obstacles, margin=keep, labels=legend)
        F.draw_chain(ax, checker.points(path[0]), role="start", label="" if legend else None)
        if shapes:
            F.draw_shapes(ax, shapes, label=lab("arm at each pump waypoint (lighter = earlier)"))
        F.draw_chain(ax, checker.points(path[-1]), role="final", label="" if legend else None)
        F.draw_tip_path(ax, tips, label=lab(f"planned tip path ({len(path)} nodes)"), color=F.OKABE_ITO["sky"])
        if wp is not None:
            wtips = np.array([checker.tip(q) for q in wp])
            F.draw_tip_path(ax, wtips, label=lab("set-point tip path between waypoints"), ls="--")
            F.draw_points(ax, wtips, label=lab(f"pump waypoints ({len(wp)})"))
        F.draw_goal(ax, scene.goal_point, scene.goal_tol, label="" if legend else None)

    center = (float(base[0]), float(base[1]))
    F.style_workspace(pf.ax, reach, center)
    F.draw_reach(pf.ax, reach, center)
    layer(pf.ax, True)
    if pf.detail is not None:
        layer(pf.detail, False)
        F.zoom(pf, scene.goal_point, max(4 * scene.goal_tol, 0.03))
    pf.ax.set_title(title or f"{scene.name}: {len(path)} planned nodes"
                    + ("" if wp is None else f", {len(wp)} pump waypoints"), fontsize=10)
    return F.finish(pf, out)
