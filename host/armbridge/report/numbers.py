"""The numbers a run's report shows (`armbridge report --json`), from its recording (data.RunData):

    recording, robot, plan     the file, the robot's name, the plan's first line of text
    missing                    what the recording does not hold, in words
    summary                    the run's summary as `armbridge run --json` wrote it (docs/formats.md §3),
                               or null for a recording made before it was logged there
    status                     completed, stopped, failed or incomplete (from the summary), else null
    link                       the link statistics of the summary (lines, errors, timeouts, resyncs)
    telemetry                  samples, first and last board time (s), duration (s)
    joints                     per joint: unit, last measured and set-point value, the set point's
                               error (rms and max |target - q|) over the whole recording
    tip                        the plan's last waypoint, the measured tip at the end, the distance
                               between them (mm), and the measured trace's distance from the planned
                               path (mean and max, mm; a MASR run with --home includes its set-up)
    obstacles                  how many obstacles the recording draws
    events, errors             counts; faults: the lines logged at level ERROR (latched states,
                               failures, e-stops), with their board time
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from armbridge.report.data import RunData

LINK_KEYS = ("lines_sent", "line_errors", "board_lines_lost", "timeouts", "spurious_timeouts", "seq_errors",
             "resyncs", "waypoints_retransmitted", "longest_quiet_s", "slow_events")
MILLI = {"rad": "mrad", "m": "mm"}


def _num(x: Any) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def unit_of(data: RunData, joint: str) -> str:
    units = (data.summary or {}).get("joint_units") or {}
    return str(units.get(joint) or ("m" if joint == "d" else "rad"))


def status(summary: dict | None) -> str | None:
    if summary is None:
        return None
    if summary.get("completed"):
        return "completed"
    if summary.get("stopped_by_user"):
        return f"stopped by {summary.get('stopped_by') or 'user'}"
    if summary.get("error"):
        return f"failed: {summary['error']}"
    return "incomplete"


def polyline_distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Each point's distance to the polyline `line` (k, d)."""
    points = np.asarray(points, float)
    line = np.asarray(line, float)
    if len(line) == 1:
        return np.linalg.norm(points - line[0], axis=1)
    a, b = line[:-1], line[1:]
    ab = b - a
    den = np.maximum(np.sum(ab * ab, axis=1), 1e-18)
    best = np.full(len(points), np.inf)
    for start in range(0, len(points), 2048):  # bounded memory: points x segments at a time
        p = points[start:start + 2048, None, :]
        f = np.clip(np.sum((p - a) * ab, axis=2) / den, 0.0, 1.0)
        d = np.linalg.norm(p - (a + f[..., None] * ab), axis=2)
        best[start:start + 2048] = d.min(axis=1)
    return best


def _tip(data: RunData) -> dict[str, Any]:
    plan = data.strips.get("plan/path")
    trace = data.strips.get("trace/tip")
    out: dict[str, Any] = {"plan_end": None, "executed_end": None, "end_off_plan_mm": None,
                           "trace_from_plan_mm": None}
    if plan:
        out["plan_end"] = plan[0][-1].tolist()
    if trace:
        out["executed_end"] = trace[0][-1].tolist()
    if plan and trace:
        out["end_off_plan_mm"] = float(np.linalg.norm(trace[0][-1] - plan[0][-1]) * 1000)
        d = polyline_distance(trace[0], plan[0]) * 1000
        out["trace_from_plan_mm"] = {"mean": float(d.mean()), "max": float(d.max())}
    return out


def _joint(data: RunData, name: str) -> dict[str, Any]:
    series = data.joints.get(name, {})
    q, tg = series.get("q"), series.get("target")
    out: dict[str, Any] = {"unit": unit_of(data, name), "samples": 0, "final_q": None, "final_target": None,
                           "setpoint_error_rms": None, "setpoint_error_max": None}
    if q is not None and len(q[1]):
        out["samples"] = len(q[1])
        out["final_q"] = _num(q[1][-1])
    if tg is not None and len(tg[1]):
        out["final_target"] = _num(tg[1][-1])
    if q is not None and tg is not None and len(q[1]) == len(tg[1]) and len(q[1]):
        e = tg[1] - q[1]
        e = e[np.isfinite(e)]
        if e.size:
            out["setpoint_error_rms"] = float(np.sqrt(np.mean(e ** 2)))
            out["setpoint_error_max"] = float(np.max(np.abs(e)))
    return out


def faults(data: RunData) -> list[dict[str, Any]]:
    """The lines of the event and error logs at level ERROR, in board-time order."""
    lines = [(t, "events", text) for t, lv, text in data.events if lv.upper() == "ERROR"]
    lines += [(t, "errors", text) for t, lv, text in data.errors if lv.upper() == "ERROR"]
    return [{"t": t, "log": log, "text": text} for t, log, text in sorted(lines, key=lambda x: x[0])]


def numbers(data: RunData) -> dict[str, Any]:
    """The report's numbers (module docstring)."""
    s = data.summary
    span = data.time_span()
    samples = max((len(j["q"][1]) for j in data.joints.values() if "q" in j), default=0)
    plan_line = (data.plan_info or "").splitlines()[0] if data.plan_info else None
    if plan_line and plan_line.startswith("plan: "):
        plan_line = plan_line[len("plan: "):]
    if s is not None and s.get("plan"):  # the plan's file (or its name, for a plan made in memory)
        plan_line = str(s["plan"])
    return {
        "recording": str(data.path),
        "robot": data.robot,
        "plan": plan_line,
        "missing": data.missing,
        "summary": s,
        "status": status(s),
        "link": {k: s.get(k) for k in LINK_KEYS} if s is not None else None,
        "telemetry": {"samples": samples, "start_s": span[0] if span else None, "end_s": span[1] if span else None,
                      "duration_s": span[1] - span[0] if span else None},
        "joints": {name: _joint(data, name) for name in data.joint_names},
        "tip": _tip(data),
        "obstacles": len(data.strips.get("world/obstacles", [])),
        "events": len(data.events),
        "errors": len(data.errors),
        "faults": faults(data),
    }


def _f(x: Any, nd: int = 3, scale: float = 1.0) -> str:
    v = _num(x)
    return "-" if v is None else f"{v * scale:.{nd}f}"


def summary_rows(doc: dict) -> list[tuple[str, str]]:
    """The report's table of numbers: the run's summary (like `armbridge run`'s table) when the
    recording has it, then what the recording itself shows (`numbers`)."""
    rows: list[tuple[str, str]] = []
    s = doc.get("summary")
    if s is not None:
        rows.append(("status", doc["status"] or "-"))
        if s.get("final_state"):
            estop = (", e-stop confirmed" if s.get("estop_confirmed") else
                     ", e-stop sent, not confirmed" if s.get("estop_sent") else "")
            rows.append(("final board state", s["final_state"] + estop))
        if s.get("fault"):
            rows.append(("fault", str(s["fault"])))
        rows.append(("board", f"{s.get('fw')} {s.get('fw_version')}" if s.get("fw") else "-"))
        rows.append(("port", str(s.get("port"))))
        rows.append(("waypoints done / total", f"{s.get('waypoints_done')} / {s.get('waypoints_total')}"))
        rows.append(("waypoints sent / acknowledged", f"{s.get('waypoints_sent')} / {s.get('waypoints_acked')}"))
        link = doc["link"] or {}
        rows.append(("lines sent / retransmitted waypoints",
                     f"{link.get('lines_sent')} / {link.get('waypoints_retransmitted')}"))
        rows.append(("line errors / board lines lost", f"{link.get('line_errors')} / {link.get('board_lines_lost')}"))
        rows.append(("timeouts (spurious) / ER SEQ / resyncs",
                     f"{link.get('timeouts')} ({link.get('spurious_timeouts')}) / {link.get('seq_errors')} / "
                     f"{link.get('resyncs')}"))
        rows.append(("longest the host was quiet", f"{_f(link.get('longest_quiet_s'))} s"))
        rows.append(("duration planned / measured",
                     f"{_f(s.get('planned_duration_s'))} s / {_f(s.get('measured_duration_s'))} s"))
        for name, tr in (s.get("tracking_setpoint") or {}).items():
            tp = (s.get("tracking_plan") or {}).get(name) or {}
            unit = MILLI.get(unit_of_doc(s, name), "m" + unit_of_doc(s, name))
            rows.append((f"tracking {name} (rms / max, {unit})",
                         f"set point {_f(tr.get('rms'), 1, 1000)} / {_f(tr.get('max'), 1, 1000)}; "
                         f"plan {_f(tp.get('rms'), 1, 1000)} / {_f(tp.get('max'), 1, 1000)}"))
        if s.get("masr"):
            m = s["masr"]
            rows.append(("MA pose error at the end", f"{_f(m.get('dp_mm'), 2)} mm / {_f(m.get('dphi_deg'), 2)} deg"))
        if s.get("drawing"):
            d = s["drawing"]
            rows.append(("drawing error, trace from strokes (mean / max)",
                         f"{_f(d.get('trace_mean_mm'), 2)} / {_f(d.get('trace_max_mm'), 2)} mm"))
        if s.get("goal"):
            g = s["goal"]
            rows.append((f"goal: {g.get('what')} off / tolerance",
                         f"{_f(g.get('distance_mm'), 2)} / {_f(g.get('tolerance_mm'), 2)} mm: "
                         + ("reached" if g.get("reached") else "MISSED")))
    tel, tip = doc["telemetry"], doc["tip"]
    rows.append(("telemetry samples / board time", f"{tel['samples']} / {_f(tel['duration_s'])} s"))
    if tip["end_off_plan_mm"] is not None:
        rows.append(("tip at the end from the plan's last waypoint", f"{_f(tip['end_off_plan_mm'], 2)} mm"))
        tr = tip["trace_from_plan_mm"]
        rows.append(("measured tip from the planned path (mean / max)", f"{_f(tr['mean'], 2)} / {_f(tr['max'], 2)} mm"))
    rows.append(("events / errors logged / at level ERROR", f"{doc['events']} / {doc['errors']} / {len(doc['faults'])}"))
    return rows


def unit_of_doc(summary: dict, joint: str) -> str:
    return str((summary.get("joint_units") or {}).get(joint) or "rad")
