"""Strokes (in metres, placed) -> the pen's path -> a joint-space plan.

The plan moves in straight joint-space lines between waypoints, so the pen
follows a stroke only as closely as the waypoints are dense: every segment
is cut into pieces no longer than `step`. Between strokes the pen travels
up, on a straight line (inside the safe disk, which is convex), sampled the
same way. Each waypoint carries a pen flag: 1 when the move *into* it draws,
0 when the pen is up for it (the first waypoint, the approach, is always up).
"""
from __future__ import annotations

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik.analytic3r import solve_path
from armbridge.plans.format import DURATION_MIN, Plan, make_plan
from armbridge.robots.planar import PlanarChain

STEP = 0.002  # m: longest pen move between two waypoints
APPROACH_S = 2.0  # s: the move from wherever the arm is to the first point
SPEED_RANGE = (0.001, 0.5)  # m/s: the drawing speeds accepted
# The joint-speed check leaves this headroom under the robot's v_max.
V_HEADROOM = 0.95


def densify(points: np.ndarray, step: float) -> np.ndarray:
    """points (k, 2) with every segment cut into equal pieces no longer than step; corners kept."""
    points = np.asarray(points, dtype=float)
    seg = np.diff(points, axis=0)
    n = np.maximum(1, np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / step).astype(int))
    t = np.concatenate([np.arange(k) / k for k in n])
    start = np.repeat(points[:-1], n, axis=0)
    return np.vstack([start + t[:, None] * np.repeat(seg, n, axis=0), points[-1:]])


def pen_path(strokes: list[np.ndarray], step: float = STEP) -> tuple[np.ndarray, np.ndarray]:
    """The pen's points (k, 2) and pen flags (k,) int: 1 = the move into the point draws."""
    if not strokes:
        raise ArmbridgeError("nothing to draw: no strokes")
    pts: list[np.ndarray] = []
    pen: list[np.ndarray] = []
    for s in strokes:
        s = densify(s, step)
        if pts:  # pen-up travel from the last point to this stroke's start (that point excluded)
            travel = densify(np.vstack([pts[-1][-1], s[0]]), step)[1:]
            pts.append(travel)
            pen.append(np.zeros(len(travel), dtype=int))
            s = s[1:]
        else:
            pts.append(s[:1])
            pen.append(np.zeros(1, dtype=int))
            s = s[1:]
        pts.append(s)
        pen.append(np.ones(len(s), dtype=int))
    return np.vstack(pts), np.concatenate(pen)


def durations(robot: PlanarChain, xy: np.ndarray, q: np.ndarray, speed: float) -> np.ndarray:
    """Per-waypoint durations (s): the pen at `speed`, slower where a joint would pass V_HEADROOM * v_max."""
    lo, hi = SPEED_RANGE
    if not lo <= speed <= hi:
        raise ArmbridgeError(f"--speed {speed:g} m/s is outside [{lo:g}, {hi:g}] m/s")
    dist = np.hypot(*np.diff(xy, axis=0).T)
    joint = np.max(np.abs(np.diff(q, axis=0)) / (V_HEADROOM * robot.v_max), axis=1)
    d = np.maximum(np.maximum(dist / speed, joint), DURATION_MIN)
    return np.concatenate([[APPROACH_S], d])


IK_METHODS = ("closed", "paper")  # `armbridge draw --ik`: the closed form, or the paper's ANN + FABRIK + CBF


def check_ik(method: str) -> str:
    """The --ik value, checked: one of IK_METHODS (case-insensitive), else one clear line."""
    m = str(method).strip().lower()
    if m not in IK_METHODS:
        raise ArmbridgeError(f"--ik {method!r}: expected {' or '.join(IK_METHODS)} (closed: the closed-form IK; "
                             f"paper: the paper's ANN + FABRIK + CBF)")
    return m


def joints(robot: PlanarChain, xy: np.ndarray, phi: float, ik: str = "closed") -> tuple[np.ndarray, dict]:
    """The joint path (k, 3) through the pen points xy (k, 2) at orientation phi, and what made it.

    ik "closed": the closed-form IK, one elbow (`ik.analytic3r.solve_path`); "paper": the
    3R paper's ANN + FABRIK with the pen angle held + CBF-QP (`ik.arm3r_pipeline.plan_joints`)."""
    ik = check_ik(ik)
    if ik == "paper":
        from armbridge.ik.arm3r_pipeline import plan_joints

        q, report = plan_joints(robot, xy, phi)
        return q, {**report.to_dict(), "method": "paper"}
    q = solve_path(robot, np.c_[xy, np.full(len(xy), phi)], (robot.q_min + robot.q_max) / 2)
    return q, {"method": "closed", "solver": "closed-form 3R IK at the pen angle (ik/analytic3r.py)"}


def plan_from_joints(robot: PlanarChain, q: np.ndarray, pen: np.ndarray, speed: float, provenance: dict) -> Plan:
    """The plan through joint waypoints q (k, 3), timed by its pen path (FK) at `speed`."""
    xy = np.asarray(robot.ee_point(q))[:, :2]
    return make_plan(robot, q, durations(robot, xy, q, speed), provenance, pen=pen)

