"""How far the drawn line is from the drawing: pure, on a plan's pen flags and a pen trace, in metres.

A plan with pen flags (docs/formats.md §1) says which moves draw; every run of
one reports how far the executed pen trace was from those strokes (the run
summary's `drawing`: `run_drawing_report`), the recording draws both
(`pen_strips`, `trace_strips`), and `armbridge draw` and `bench arm3r` measure
their drawings the same way. It lives with the plan format because it reads
nothing but a plan and samples of the arm.

Both directions are reported because each misses what the other sees: the
trace-from-target distance catches a pen that wandered off the strokes, the
target-from-trace distance catches a part of a stroke the pen never drew (a
stroke cut short, a lifted pen). Distances are from points to polylines (every
segment, not only its vertices), so the sampling of either side does not count
as error; the points measured are the trace samples, and the strokes densified
to `step`.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

STEP = 0.0005  # m: spacing of the points taken along the target strokes


@dataclass(frozen=True)
class DrawingError:
    """Distances in m (to_dict: mm); nan where a side is empty."""

    trace_mean: float  # pen trace -> nearest target stroke
    trace_max: float
    target_mean: float  # target strokes -> nearest pen trace
    target_max: float
    trace_points: int

    def to_dict(self) -> dict:
        d = {k: round(v * 1000, 4) for k, v in asdict(self).items() if k != "trace_points"}
        return {f"{k}_mm": (None if not np.isfinite(v) else v) for k, v in d.items()} | {
            "trace_points": self.trace_points}


def point_polyline_distance(points: np.ndarray, strips: list[np.ndarray]) -> np.ndarray:
    """Distance (n,) from each point (n, 2) to the nearest segment of any strip (m_i, 2);
    a one-point strip is a point. inf when there are no strips."""
    points = np.asarray(points, float).reshape(-1, 2)
    best = np.full(len(points), np.inf)
    for s in strips:
        s = np.asarray(s, float).reshape(-1, 2)
        if len(s) == 0:
            continue
        a, b = (s[:-1], s[1:]) if len(s) > 1 else (s, s)
        ab = b - a  # (m, 2)
        ap = points[:, None, :] - a[None]  # (n, m, 2)
        den = np.einsum("ij,ij->i", ab, ab)
        f = np.where(den > 0, np.einsum("nmj,mj->nm", ap, ab) / np.where(den > 0, den, 1), 0.0)
        f = np.clip(f, 0.0, 1.0)
        d = np.hypot(*(ap - f[..., None] * ab[None]).transpose(2, 0, 1)).min(axis=1)
        best = np.minimum(best, d)
    return best


def _densify(strip: np.ndarray, step: float) -> np.ndarray:
    strip = np.asarray(strip, float).reshape(-1, 2)
    if len(strip) < 2:
        return strip
    seg = np.diff(strip, axis=0)
    n = np.maximum(1, np.ceil(np.hypot(*seg.T) / step).astype(int))
    t = np.concatenate([np.arange(k) / k for k in n])
    return np.vstack([np.repeat(strip[:-1], n, axis=0) + t[:, None] * np.repeat(seg, n, axis=0), strip[-1:]])


def _stats(d: np.ndarray) -> tuple[float, float]:
    d = d[np.isfinite(d)]
    return (float(np.mean(d)), float(np.max(d))) if d.size else (float("nan"), float("nan"))


def drawing_error(target: list[np.ndarray], trace: list[np.ndarray], step: float = STEP) -> DrawingError:
    """Mean and max distance of the trace's points from the target strokes, and of
    the target's points (densified to step) from the trace, both as polylines."""
    trace_pts = np.vstack([np.asarray(s, float).reshape(-1, 2) for s in trace] or [np.zeros((0, 2))])
    target_pts = np.vstack([_densify(s, step) for s in target] or [np.zeros((0, 2))])
    tm, tx = _stats(point_polyline_distance(trace_pts, target))
    gm, gx = _stats(point_polyline_distance(target_pts, trace))
    return DrawingError(tm, tx, gm, gx, len(trace_pts))


def pen_strips(points: np.ndarray, pen: np.ndarray) -> list[np.ndarray]:
    """The pen-down strips of a path: points (k, 2) with pen[i] = 1 when the move into
    point i draws. A strip starts at the point before its first pen-down move."""
    points = np.asarray(points, float)
    pen = np.asarray(pen).astype(bool)
    strips, i, k = [], 1, len(points)
    while i < k:
        if pen[i]:
            j = i
            while j < k and pen[j]:
                j += 1
            strips.append(points[i - 1 : j])
            i = j
        else:
            i += 1
    return strips


def trace_strips(points: np.ndarray, down: np.ndarray) -> list[np.ndarray]:
    """The pen trace: runs of consecutive samples (n, 2) taken while the pen was down."""
    points = np.asarray(points, float).reshape(-1, 2)
    down = np.asarray(down).astype(bool)
    edges = np.flatnonzero(np.diff(np.r_[0, down.astype(int), 0]))
    return [points[a:b] for a, b in zip(edges[::2], edges[1::2])]


def safe_excursion(points: np.ndarray, center, radius: float) -> dict:
    """How the pen samples (n, 2) kept to the safe disc (center, radius): `safe_outside`, the samples
    outside it; `safe_excess_max_mm`, the largest |p - c| - radius (< 0: all inside by that much)."""
    points = np.asarray(points, float).reshape(-1, 2)
    excess = np.linalg.norm(points - np.asarray(center, float), axis=1) - float(radius)
    return {"safe_outside": int((excess > 0).sum()),
            "safe_excess_max_mm": round(float(excess.max()) * 1000, 4) if len(excess) else None}


def run_drawing_report(plan, q: np.ndarray, active: np.ndarray, duration_s: float,
                       touched: np.ndarray | None = None) -> dict:
    """The drawing section of a run's summary: the error of the measured pen trace
    (FK of the measured q (n, dof) while the active segment's pen flag is 1) against
    the plan's pen-down strokes (FK of its waypoints), in mm, and for text the time
    per character (duration_s / the characters in the plan's provenance). A plan that names its
    safe region (`armbridge draw`'s provenance) also gets how many samples of the executed pen,
    pen up or down, were outside that disc and the largest excess (`safe_excursion`). `touched`
    (an emulated board, which knows where its pen tip is: one bool per sample) adds
    `pen_down_samples` and `pen_untouched`, the pen-down samples whose pen was off the paper
    (travelling to it in the settle dwell, or held above it by a down width that does not reach it)."""
    robot = plan.robot
    target = pen_strips(np.asarray(plan.ee_path())[:, :2], plan.pen)
    q = np.asarray(q, float).reshape(-1, plan.n)
    active = np.asarray(active, int)
    down = np.zeros(len(active), bool)
    ok = (active >= 0) & (active < plan.k)
    down[ok] = plan.pen[active[ok]] == 1
    tips = np.asarray(robot.ee_point(q))[:, :2] if len(q) else np.zeros((0, 2))
    out = drawing_error(target, trace_strips(tips, down)).to_dict()
    if touched is not None and len(touched) == len(down):
        out["pen_down_samples"] = int(down.sum())
        out["pen_untouched"] = int((down & ~np.asarray(touched, bool)).sum())
    region = ((plan.provenance or {}).get("drawing") or {}).get("safe_region")
    if region:
        out |= safe_excursion(tips, region["center"], region["radius"])
    chars = ((plan.provenance or {}).get("drawing") or {}).get("characters")
    if chars:
        out["characters"] = int(chars)
        out["s_per_character"] = (round(duration_s / chars, 3) if np.isfinite(duration_s) else None)
    return out
