"""Strokes (in metres, placed) -> the pen's path -> a joint-space plan.

The plan moves in straight joint-space lines between waypoints, so the pen
follows a stroke only as closely as the waypoints are dense: every segment
is cut into pieces no longer than `step`. Between strokes the pen travels
up in one move, straight to the next stroke's start (a plotter's rapid), at
its own speed (`--travel-speed`) unless a joint's speed limit makes it
slower. One joint-space move bows the pen off the straight line, so
`split_travel` checks each pen-up move's whole swept path (FK along the joint
line) against the safe disc less the margin and cuts one that would leave it
at its Cartesian midpoint, as often as needed (the disc is convex: a midpoint
of two points inside is inside). Each waypoint carries a pen flag: 1 when the
move *into* it draws, 0 when the pen is up for it (the first waypoint, the
approach, is always up). `settle` adds a still waypoint after each pen change
(the pen's own settle time beyond the board's PEN_SETTLE_MS).
"""
from __future__ import annotations

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik.analytic3r import ik, solve_path
from armbridge.plans.format import DURATION_MIN, Plan, make_plan
from armbridge.robots.planar import PlanarChain

STEP = 0.002  # m: longest pen-down move between two waypoints
SWEEP_SAMPLES = 32  # points along a pen-up joint move checked against the safe disc
SPLIT_DEPTH = 8  # a pen-up move is halved at most this often (2**8 pieces)
SETTLE_RANGE = (0.0, 5.0)  # s: the extra settle accepted after a pen change
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


def pen_path(strokes: list[np.ndarray], step: float = STEP, *,
             direct: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The pen's points (k, 2) and pen flags (k,) int: 1 = the move into the point draws.
    `direct`: one pen-up move between strokes (else cut to `step` like the strokes)."""
    if not strokes:
        raise ArmbridgeError("nothing to draw: no strokes")
    pts: list[np.ndarray] = []
    pen: list[np.ndarray] = []
    for s in strokes:
        s = densify(s, step)
        if pts:  # pen-up travel from the last point to this stroke's start (that point excluded)
            travel = s[:1] if direct else densify(np.vstack([pts[-1][-1], s[0]]), step)[1:]
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


def check_speed(speed: float, option: str = "--speed") -> float:
    """A pen speed (m/s) checked against SPEED_RANGE: one clear line naming it when outside."""
    lo, hi = SPEED_RANGE
    if not lo <= speed <= hi:
        raise ArmbridgeError(f"{option} {speed:g} m/s is outside [{lo:g}, {hi:g}] m/s")
    return float(speed)


def sweep(robot: PlanarChain, q0: np.ndarray, q1: np.ndarray, n: int = SWEEP_SAMPLES) -> np.ndarray:
    """The pen's points (n + 1, 2) along the joint-space line q0 -> q1 (what the board moves)."""
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    return np.asarray(robot.ee_point(q0 * (1 - t) + q1 * t))[:, :2]


def durations(robot: PlanarChain, xy: np.ndarray, q: np.ndarray, speed: float, *,
              pen: np.ndarray | None = None, travel_speed: float | None = None) -> np.ndarray:
    """Per-waypoint durations (s): the pen at `speed` (pen-up moves, with `pen`, at `travel_speed`
    along their swept path), slower where a joint would pass V_HEADROOM * v_max."""
    check_speed(speed)
    dist = np.hypot(*np.diff(xy, axis=0).T)
    v = np.full(len(dist), float(speed))
    if pen is not None and travel_speed is not None:
        up = np.flatnonzero(np.asarray(pen)[1:] == 0)
        v[up] = check_speed(travel_speed, "--travel-speed")
        for i in up:  # a long joint move bows: its pen path is longer than the chord
            dist[i] = float(np.sum(np.hypot(*np.diff(sweep(robot, q[i], q[i + 1]), axis=0).T)))
    joint = np.max(np.abs(np.diff(q, axis=0)) / (V_HEADROOM * robot.v_max), axis=1)
    d = np.maximum(np.maximum(dist / v, joint), DURATION_MIN)
    return np.concatenate([[APPROACH_S], d])


def split_travel(robot: PlanarChain, q: np.ndarray, pen: np.ndarray, center, radius: float,
                 ) -> tuple[np.ndarray, np.ndarray, int]:
    """Pen-up moves (pen[i] == 0, i >= 1) whose swept pen path leaves the disc (center, radius)
    cut at their Cartesian midpoints (closed-form IK at the pen angle, the elbow of the move's
    start) until every piece stays inside, or SPLIT_DEPTH halvings. -> (q, pen, moves cut)."""
    c = np.asarray(center, float)
    out_q, out_pen, cut = [q[0]], [int(pen[0])], 0

    def inside(a: np.ndarray, b: np.ndarray) -> bool:
        return bool(np.all(np.sum((sweep(robot, a, b) - c) ** 2, axis=1) <= radius**2 + 1e-12))

    def pieces(a: np.ndarray, b: np.ndarray, depth: int) -> list[np.ndarray]:
        if depth >= SPLIT_DEPTH or inside(a, b):
            return [b]
        mid_xy = (np.asarray(robot.ee_point(a))[:2] + np.asarray(robot.ee_point(b))[:2]) / 2
        mid, ok = ik(robot, np.r_[mid_xy, a.sum()], a)
        if not bool(ok):
            return [b]
        return pieces(a, mid, depth + 1) + pieces(mid, b, depth + 1)

    for i in range(1, len(q)):
        parts = pieces(q[i - 1], q[i], 0) if pen[i] == 0 else [q[i]]
        cut += len(parts) > 1
        out_q.extend(parts)
        out_pen.extend([int(pen[i])] * len(parts))
    return np.array(out_q), np.array(out_pen, dtype=int), cut


def check_settle(value: str) -> tuple[float, float]:
    """--pen-settle DOWN[,UP] in ms -> (down, up) in s, each within SETTLE_RANGE."""
    lo, hi = SETTLE_RANGE
    try:
        parts = [float(x) / 1000.0 for x in str(value).split(",")]
    except ValueError:
        parts = []
    if len(parts) not in (1, 2) or not all(lo <= x <= hi for x in parts):
        raise ArmbridgeError(f"--pen-settle {value!r}: expected MS or DOWN,UP in ms, each in "
                             f"[{lo * 1000:g}, {hi * 1000:g}]")
    return parts[0], parts[-1]


def settle(q: np.ndarray, pen: np.ndarray, dur: np.ndarray, down_s: float, up_s: float,
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A still waypoint (the previous pose, for down_s or up_s) ahead of each move whose pen
    differs from the move before it: the pen changes, the board waits its own settle, then this
    wait, then the move."""
    qs, ps, ds = [q[0]], [int(pen[0])], [float(dur[0])]
    for i in range(1, len(q)):
        wait = down_s if pen[i] == 1 else up_s
        if pen[i] != pen[i - 1] and wait > 0:
            qs.append(q[i - 1])
            ps.append(int(pen[i]))
            ds.append(max(wait, DURATION_MIN))
        qs.append(q[i])
        ps.append(int(pen[i]))
        ds.append(float(dur[i]))
    return np.array(qs), np.array(ps, dtype=int), np.array(ds)


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


def plan_from_joints(robot: PlanarChain, q: np.ndarray, pen: np.ndarray, speed: float, provenance: dict, *,
                     travel_speed: float | None = None, pen_settle: tuple[float, float] = (0.0, 0.0)) -> Plan:
    """The plan through joint waypoints q (k, 3), timed by its pen path (FK) at `speed` (pen-up
    moves at `travel_speed`, default `speed`), with `pen_settle` (down, up) s after pen changes."""
    xy = np.asarray(robot.ee_point(q))[:, :2]
    dur = durations(robot, xy, q, speed, pen=pen, travel_speed=speed if travel_speed is None else travel_speed)
    q, pen, dur = settle(q, pen, dur, *pen_settle)
    return make_plan(robot, q, dur, provenance, pen=pen)

