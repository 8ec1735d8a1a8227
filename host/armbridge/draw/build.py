"""One drawing, start to end: lines in -> placed, tidied strokes -> the joint plan.

The joints come from the closed-form IK (`--ik closed`, the default) or the 3R
paper's ANN + FABRIK + CBF pipeline (`--ik paper`, `ik.arm3r_pipeline.plan_joints`);
the plan's provenance["drawing"]["ik"] says which, and what it did.

The joints are filtered by the discrete CBF (`ik.cbf_filter`) before the plan
is made, so every waypoint written and streamed keeps its pen at least
`layout.margin_for` of the fastest pen speed (drawing or travel) inside the
safe disk, whatever the placement; the direct pen-up moves are then cut where
their swept path would leave that disc (`path.split_travel`).

Pure: no files are read or written here (the command does that), so every
step is testable on strokes made in memory.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import vpype as vp  # type: ignore[import-untyped]

from armbridge.draw import layout, path, sources
from armbridge.draw.page import Page, rotated
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
    page: Page | None = None  # the sheet it is drawn on (draw.page), centred on placement.at
    travel_cuts: int = 0  # pen-up moves cut to keep their swept path inside the disc

    @property
    def drawn_length(self) -> float:
        """Pen-down length, m."""
        return float(sum(np.sum(np.hypot(*np.diff(s, axis=0).T)) for s in self.strokes))


def build(lines: vp.LineCollection, robot: PlanarChain, *, name: str, source: str,
          size: float | None = None, at=None, speed: float = 0.02, step: float = path.STEP,
          ik: str = "closed", travel_speed: float | None = None, page: Page | None = None,
          rotate: float = 0.0, sort: str = "2opt", merge_tolerance: float = layout.MERGE_TOLERANCE,
          min_length: float = 0.0, pen_settle: tuple[float, float] = (0.0, 0.0)) -> Drawing:
    """Place lines in the robot's safe region (as large as fits its margin, and `page` less its
    margin, unless `size` says; turned by `rotate` degrees), tidy them (vpype: merge, simplify,
    drop strokes under `min_length`, `sort`), plan the joints (`ik`: "closed", the closed-form
    IK, or "paper", the 3R paper's ANN + FABRIK + CBF), filter them (the discrete CBF, on the
    margin), keep the direct pen-up moves (at `travel_speed`, default `speed`) inside it and
    add the pen's `pen_settle` (down, up) s after each pen change."""
    ik = path.check_ik(ik)
    speed = path.check_speed(speed)
    travel = speed if travel_speed is None else path.check_speed(travel_speed, "--travel-speed")
    reg, phi = safe_region(robot), pen_angle(robot)
    margin = layout.margin_for(max(speed, travel))
    box = page.printable if page is not None else None
    placed, where = layout.place(rotated(lines, rotate), reg.center, reg.radius, size=size, at=at, margin=margin,
                                 box=box)
    tidied, report = layout.tidy(placed, sort=sort, merge_tolerance=merge_tolerance, min_length=min_length)
    strokes = sources.to_strokes(tidied)
    xy, pen = path.pen_path(strokes, step)
    q_ik, ik_report = path.joints(robot, xy, phi, ik)
    q, safety = filter_joints(robot, reg, q_ik, margin)
    q, pen, cuts = path.split_travel(robot, q, pen, reg.center, reg.radius - margin)
    drawn = float(sum(np.sum(np.hypot(*np.diff(s, axis=0).T)) for s in strokes))
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
            "rotate_deg": rotate,
            "page": page.to_dict() if page is not None else None,
            "speed": speed,
            "travel_speed": travel,
            "travel_cuts": cuts,
            "pen_settle_s": list(pen_settle),
            "step": step,
            "strokes": len(strokes),
            "strokes_dropped": report.dropped,
            "drawn_length": drawn,
            "sort": report.sort,
            "pen_up_travel_before_sort": report.travel_before,
            "pen_up_travel_greedy": report.travel_greedy,
            "pen_up_travel_after_sort": report.travel_after,
        },
    }
    plan = path.plan_from_joints(robot, q, pen, speed, provenance, travel_speed=travel, pen_settle=pen_settle)
    xy = np.asarray(robot.ee_point(plan.q))[:, :2]
    assert plan.pen is not None
    return Drawing(strokes, xy, plan.pen, plan, where, report, reg, phi, safety, ik_report, page, cuts)
