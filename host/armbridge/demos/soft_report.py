"""What the soft-arm demo reports about an executed plan, from the run's own recording.

`read_trace` takes the telemetry (board time, measured angles) and the board's
START/DONE events back out of the .rrd (rerun's reader); `soft_report` (pure)
compares them with the plan:

* per pump waypoint: the angles the arm rested at (the last sample before the
  next move began) against the target, each joint inside the settle tolerance
  (the dead band and a sensor count, executor/settle.py); the settle time (the
  slowest joint's, executor/summary.py settle_table); the tip error (settled tip
  to the target's tip, m);
* the executed tip path against the planned one (each measured tip's distance to
  the planner's tip polyline: max and mean, m);
* the executed shapes against the obstacles: the least clearance over every
  telemetry sample (the scene's checker, eq. 8's dist; negative = a collision),
  and over the executed joint path (`executed_clearance_min_mm`: between two
  samples the straight joint-space edge, measured as planning measures a plan's
  clearance, planning/soft/margin.py ClearanceObjective), beside the margin the
  plan was planned for (`margin_mm`, from the plan's soft section) and whether
  the arm kept it (`keeps_margin`); the angles are the board's readings, which
  on the emulator's nominal plant are the true ones;
* the executed time (START of the first waypoint to the arm settled at the goal)
  against the planned (to the end of the last move, and with the last hold).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from armbridge.executor.tracking import settle_table


@dataclass
class Trace:
    """A run's telemetry and events: t (M,) s, q (M, n) rad, done/start: plan row -> board time (s)."""

    t: np.ndarray
    q: np.ndarray
    done: dict[int, float]
    start: dict[int, float]


def read_trace(rrd: Path | str, joint_names: list[str]) -> Trace:
    """The measured angles (joints/<joint>/q) and the START/DONE events of a run's recording."""
    import pyarrow as pa  # type: ignore[import-untyped]
    from rerun.chunk import RrdReader

    series: dict[str, list[tuple[int, float]]] = {n: [] for n in joint_names}
    done: dict[int, float] = {}
    start: dict[int, float] = {}
    for chunk in RrdReader(Path(rrd)).stream():
        path = chunk.entity_path.lstrip("/")
        if chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        if "board_time" not in rb.schema.names:
            continue
        t = rb.column("board_time").cast(pa.int64()).to_pylist()
        if path == "events":
            for ns, text in zip(t, rb.column("TextLog:text").to_pylist()):
                words = (text[0] if isinstance(text, list) else text).split()
                if len(words) >= 2 and words[0] in ("DONE", "START") and words[1].isdigit():
                    (done if words[0] == "DONE" else start).setdefault(int(words[1]), ns / 1e9)
        elif path.startswith("joints/") and path.endswith("/q") and path.split("/")[1] in series:
            vals = rb.column("Scalars:scalars").to_pylist()
            series[path.split("/")[1]].extend((ns, v[0]) for ns, v in zip(t, vals))
    cols = [sorted(series[n]) for n in joint_names]
    if not cols or not cols[0]:
        return Trace(np.zeros(0), np.zeros((0, len(joint_names))), done, start)
    m = min(len(c) for c in cols)
    t = np.array([c[0] for c in cols[0][:m]]) / 1e9
    q = np.array([[c[i][1] for c in cols] for i in range(m)])
    return Trace(t, q, done, start)


def _f(x: float, nd: int = 4) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


def _polyline_distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """(M,) each point's least distance to the polyline (L, 2)."""
    a, b = line[:-1], line[1:]
    if len(a) == 0:
        return np.linalg.norm(points - line[0], axis=1)
    ab = b - a
    ap = points[:, None, :] - a[None, :, :]
    s = np.clip(np.einsum("mlk,lk->ml", ap, ab) / np.maximum(np.einsum("lk,lk->l", ab, ab), 1e-18), 0.0, 1.0)
    close = a[None] + s[..., None] * ab[None]
    return np.min(np.linalg.norm(points[:, None, :] - close, axis=2), axis=1)


def _executed_clearance(trace: Trace, checker: Any) -> dict[str, Any]:
    """The least clearance along the executed joint path (mm; straight between telemetry samples), when (s,
    board time) and what came closest there (ChainChecker.describe of the touch check, or "free")."""
    from armbridge.planning.soft.margin import ClearanceObjective

    if trace.q.shape[0] == 0:
        return {"executed_clearance_min_mm": None, "executed_clearance_t_s": None, "executed_contact": None}
    obj = ClearanceObjective(checker)
    per = [obj.state(trace.q[0])] + [obj.edge(a, b) for a, b in zip(trace.q[:-1], trace.q[1:])]
    k = int(np.argmin(per))
    contact = "free"
    if per[k] <= 0:
        code = checker.code(trace.q[k])
        contact = checker.describe(code) if code != -1 else "between two telemetry samples"
    return {"executed_clearance_min_mm": round(float(per[k]) * 1000, 3), "executed_clearance_t_s": _f(trace.t[k], 3),
            "executed_contact": contact}


def soft_report(plan: Any, info: Any, trace: Trace, tolerance: Any, checker: Any) -> dict[str, Any]:
    """The demo's summary (module doc) of `plan` (its soft section `info`, plans.soft.SoftInfo) run as
    `trace`; tolerance (n,) rad per joint; checker: the scene's (tips, clearance)."""
    q_plan = np.asarray(plan.q, float)
    rows = [int(r) for r in info.pose_rows]
    end_t = float(trace.t[-1]) if trace.t.size else math.nan
    tolerance = np.asarray(tolerance, float)
    table = settle_table(trace.t, trace.q, q_plan, trace.done, tolerance, end_t)
    poses: list[dict[str, Any]] = []
    for i, row in enumerate(rows):
        nxt = rows[i + 1] if i + 1 < len(rows) else None
        until = trace.done.get(nxt - 1, end_t) if nxt is not None else end_t
        idx = np.nonzero(trace.t <= until + 1e-9)[0]
        settled = trace.q[idx[-1]] if idx.size else np.full(plan.n, np.nan)
        err = settled - q_plan[row]
        times = table[row][~np.isnan(table[row])]
        unsettled = bool(np.any(np.isinf(times)))
        tip_err = float(np.linalg.norm(checker.tip(settled) - checker.tip(q_plan[row]))) if idx.size else math.nan
        poses.append({"node": int(info.nodes[i]) if i < len(info.nodes) else None, "row": row,
                      "target": [_f(x) for x in q_plan[row]], "settled": [_f(x) for x in settled],
                      "error_rad": [_f(x) for x in err],
                      "inside_band": bool(np.all(np.abs(err) <= tolerance + 1e-9)),
                      "settle_s": None if unsettled else _f(float(times.max(initial=0.0)), 3),
                      "tip_error_m": _f(tip_err, 5)})
    tips = np.array([p["tip_error_m"] for p in poses if p["tip_error_m"] is not None])
    joint_err = np.degrees(np.abs(np.array([p["error_rad"] for p in poses], dtype=float)))
    joint_err = joint_err[np.isfinite(joint_err)]
    settles = np.array([p["settle_s"] for p in poses if p["settle_s"] is not None])
    measured_tips = np.array([checker.tip(q) for q in trace.q]).reshape(-1, 2)
    planned_tips = np.array([checker.tip(q) for q in info.planned_path])
    dev = _polyline_distance(measured_tips, planned_tips) if len(measured_tips) else np.zeros(0)
    clearance = np.array([checker.clearance(q) for q in trace.q])
    executed = _executed_clearance(trace, checker)
    last = rows[-1]
    t0 = trace.start.get(0, trace.done.get(0, math.nan) - float(plan.durations[0]))
    last_settle = poses[-1]["settle_s"]
    arrival = trace.done.get(last, math.nan) + (float(last_settle) if last_settle is not None else math.nan)
    final_tip = measured_tips[-1] if len(measured_tips) else np.full(2, np.nan)
    return {
        "scene": info.scene, "planner": info.planner,
        "planned_nodes": int(len(info.planned_path)), "waypoints": len(poses), "plan_rows": int(plan.k),
        "all_settled": all(p["inside_band"] and p["settle_s"] is not None for p in poses),
        "settle_tolerance_rad": [_f(x) for x in tolerance],
        "settle_s": {"max": _f(settles.max(), 3) if settles.size else None,
                     "mean": _f(settles.mean(), 3) if settles.size else None},
        "settled_joint_error_deg": {"max": _f(joint_err.max(), 3) if joint_err.size else None,
                                    "mean": _f(joint_err.mean(), 3) if joint_err.size else None},
        "tip_error_m": {"max": _f(tips.max(), 5) if tips.size else None,
                        "mean": _f(tips.mean(), 5) if tips.size else None},
        "path_deviation_m": {"max": _f(dev.max(), 5) if dev.size else None,
                             "mean": _f(dev.mean(), 5) if dev.size else None},
        "min_clearance_m": _f(clearance.min(), 5) if clearance.size else None,
        **executed,
        "margin_mm": info.margin_mm,
        "keeps_margin": (None if info.margin_mm is None or executed["executed_clearance_min_mm"] is None
                         else bool(executed["executed_clearance_min_mm"] >= info.margin_mm)),
        "collision_free": bool(clearance.size and clearance.min() > 0 and executed["executed_contact"] == "free"),
        "goal_distance_m": _f(float(np.linalg.norm(final_tip - info.goal_point)), 5), "goal_tol_m": info.goal_tol,
        "planned_s": _f(plan.total_duration, 3),
        "planned_arrival_s": _f(float(np.sum(plan.durations[:last + 1])), 3),
        "executed_s": _f(arrival - t0, 3),
        "telemetry_samples": int(trace.t.size),
        "poses": poses,
    }
