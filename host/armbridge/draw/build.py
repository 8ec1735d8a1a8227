"""One drawing, start to end: lines in -> placed, tidied strokes -> the joint plan.

The joints come from the closed-form IK (`--ik closed`, the default) or the 3R
paper's ANN + FABRIK + CBF pipeline (`--ik paper`, `ik.arm3r_pipeline.plan_joints`);
the plan's provenance["drawing"]["ik"] says which, and what it did.

The joints are filtered by the discrete CBF (`ik.cbf_filter`) before the plan
is made, so every waypoint written and streamed keeps its pen at least
`layout.margin_for(speed)` inside the safe disk, whatever the placement.

Pure: no files are read or written here (the command does that), so every
step is testable on strokes made in memory.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import vpype as vp  # type: ignore[import-untyped]

from armbridge.draw import layout, path, sources
from armbridge.ik.cbf_filter import FilterReport, filter_joints
from armbridge.ik.region import SafeRegion, pen_angle, safe_region
from armbridge.plans.format import Plan
from armbridge.robots.planar import PlanarChain


@dataclass
class Drawing:
    """What `armbridge draw` made: the strokes (m), the pen's path and the plan."""

    strokes: list[np.ndarray]
    xy: np.ndarray  # (k, 2) pen positions at the waypoints, m
    pen: np.ndarray  # (k,) 1 = the move into the waypoint draws
    plan: Plan
    placement: layout.Placement
    tidy: layout.Tidy
    region: SafeRegion  # the disk it was placed in (ik.region)
    phi: float  # the pen orientation it is drawn at, rad
    safety: FilterReport  # what the CBF filter did to the waypoints (margin: placement.margin)
    ik: dict  # which IK made the joints ("method": closed or paper) and what it did

    @property
    def drawn_length(self) -> float:
        """Pen-down length, m."""
        return float(sum(np.sum(np.hypot(*np.diff(s, axis=0).T)) for s in self.strokes))


def build(lines: vp.LineCollection, robot: PlanarChain, *, name: str, source: str,
          size: float | None = None, at=None, speed: float = 0.02, step: float = path.STEP,
          ik: str = "closed") -> Drawing:
    """Place lines in the robot's safe region (as large as fits its margin unless `size` says),
    tidy them (vpype), plan the joints (`ik`: "closed", the closed-form IK, or "paper", the 3R
    paper's ANN + FABRIK + CBF) and filter them (the discrete CBF, on the margin)."""
    ik = path.check_ik(ik)
    reg, phi = safe_region(robot), pen_angle(robot)
    margin = layout.margin_for(speed)
    placed, where = layout.place(lines, reg.center, reg.radius, size=size, at=at, margin=margin)
    tidied, report = layout.tidy(placed)
    strokes = sources.to_strokes(tidied)
    xy, pen = path.pen_path(strokes, step)
    q_ik, ik_report = path.joints(robot, xy, phi, ik)
    q, safety = filter_joints(robot, reg, q_ik, margin)
    xy = np.asarray(robot.ee_point(q))[:, :2]
    provenance = {
        "name": name,
        "drawing": {
            "source": source,
            "safe_region": {"center": list(reg.center), "radius": reg.radius},
            "margin": margin,
            "cbf_filter": safety.to_dict(),
            "ik": ik_report,
            "phi": phi,
            "at": list(where.at),
            "size": where.size,
            "speed": speed,
            "step": step,
            "strokes": len(strokes),
            "drawn_length": float(sum(np.sum(np.hypot(*np.diff(s, axis=0).T)) for s in strokes)),
            "pen_up_travel_before_sort": report.travel_before,
            "pen_up_travel_after_sort": report.travel_after,
        },
    }
    plan = path.plan_from_joints(robot, q, pen, speed, provenance)
    return Drawing(strokes, xy, pen, plan, where, report, reg, phi, safety, ik_report)
