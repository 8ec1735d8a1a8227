"""Placement and line clean-up, on vpype's LineCollection.

`place` scales and moves a drawing into the safe disk (`ik.region.safe_region`)
at the size and position the user asked for, or as large as fits inside the
disk less a margin (`margin_for`: what the executed pen strays from the
commanded one, measured); a drawing that cannot fit the disk is an error
naming by how much it overflows. `tidy` then runs
vpype's own steps on the placed lines: merging strokes whose ends meet,
simplifying (the shapely simplification vpype's `linesimplify` uses) and
sorting to cut pen-up travel (vpype's `linesort`: its greedy nearest-end
search over `vpype.LineIndex`, kept only where it helps).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import vpype as vp  # type: ignore[import-untyped]

from armbridge.errors import ArmbridgeError
from armbridge.ik.region import MARGIN_BY_SPEED, margin_for  # noqa: F401 - the drawing's margin, by pen speed

MERGE_TOLERANCE = 1e-4  # m: stroke ends closer than this are joined (0.1 mm)
SIMPLIFY_TOLERANCE = 5e-5  # m: a simplified stroke stays this close to the original (0.05 mm)
FIT_SLACK = 1e-9  # m: rounding slack on the fit check

@dataclass(frozen=True)
class Placement:
    """Where a drawing went: its scale (m per source unit), its centre and its size (m)."""

    scale: float
    at: tuple[float, float]
    size: float  # the longer side of its bounding box, m
    largest: float  # the largest size that fits at `at` keeping the margin (what --fit gives), m
    margin: float = 0.0  # m: what --fit kept inside the disk's edge


def _points(lc: vp.LineCollection) -> np.ndarray:
    return np.concatenate([np.c_[ln.real, ln.imag] for ln in lc]) if len(lc) else np.empty((0, 2))


def _mm(x: float) -> str:
    return f"{x * 1000:.1f} mm"


def fit_scale(d: np.ndarray, a: np.ndarray, radius: float) -> float:
    """Largest s with |a + s d_i| <= radius for every offset d_i (n, 2); a = centre - disk centre."""
    dd = np.sum(d * d, axis=1)
    ad = d @ a
    c = float(a @ a) - radius**2  # < 0: the centre is inside the disk
    keep = dd > 0
    roots = (-ad[keep] + np.sqrt(ad[keep] ** 2 - dd[keep] * c)) / dd[keep]
    return float(np.min(roots)) if roots.size else np.inf


def place(lc: vp.LineCollection, center, radius: float, *, size: float | None = None,
          at=None, margin: float = 0.0) -> tuple[vp.LineCollection, Placement]:
    """The drawing scaled and moved into the disk (center, radius), and where it went.

    The bounding box's centre goes to `at` (default: the disk's centre). With
    `size` (m) the box's longer side is that long; without it the drawing is
    as large as fits `margin` (m) inside the disk's edge. Raises ArmbridgeError
    when it does not fit the disk, naming the overflow and the largest size that
    would; with a margin, also the largest that keeps it (a drawing between the
    two is accepted: the CBF filter presses its edge onto the margin)."""
    center = np.asarray(center, dtype=float)
    pts = _points(lc)
    if pts.size == 0:
        raise ArmbridgeError("nothing to draw: no strokes")
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    extent = float(np.max(hi - lo))
    if extent <= 0:
        raise ArmbridgeError("nothing to draw: every stroke is a single point")
    target = center if at is None else np.asarray(at, dtype=float)
    a = target - center
    off = float(np.hypot(*a))
    where = f"the safe region (centre ({center[0]:.4f}, {center[1]:.4f}) m, radius {radius:.4f} m)"
    if off >= radius:
        raise ArmbridgeError(f"--at ({target[0]:.4f}, {target[1]:.4f}) m is outside {where}: "
                             f"{_mm(off - radius)} beyond its edge")
    if off >= radius - margin:
        raise ArmbridgeError(f"--at ({target[0]:.4f}, {target[1]:.4f}) m is inside {where} but within the "
                             f"{_mm(margin)} margin its edge keeps: nothing fits there")
    if size is not None and not size > 0:
        raise ArmbridgeError(f"--size must be above 0 m, got {size}")
    d = pts - (lo + hi) / 2
    s_fit = fit_scale(d, a, radius - margin - FIT_SLACK)  # FIT_SLACK: the IK round trip stays inside
    s = s_fit if size is None else size / extent
    placed = np.linalg.norm(a + s * d, axis=1)
    over = float(placed.max()) - radius
    if over > FIT_SLACK:
        keeps = f" ({s_fit * extent:.4f} m keeps the {_mm(margin)} margin, as --fit does)" if margin > 0 else ""
        raise ArmbridgeError(f"the drawing at --size {size:g} m overflows {where} by {_mm(over)}; "
                             f"the largest size that fits at ({target[0]:.4f}, {target[1]:.4f}) m "
                             f"is {fit_scale(d, a, radius) * extent:.4f} m{keeps}")
    out = lc.clone()
    out.extend(lc)
    out.translate(-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2)
    out.scale(s)
    out.translate(float(target[0]), float(target[1]))
    return out, Placement(scale=s, at=(float(target[0]), float(target[1])), size=s * extent,
                          largest=s_fit * extent, margin=margin)


def pen_up_travel(lc: vp.LineCollection) -> float:
    """Total pen-up distance between consecutive strokes (vpype's pen_up_length), in the lines' units."""
    return float(lc.pen_up_length()[0]) if len(lc) > 1 else 0.0


def simplify(lc: vp.LineCollection, tolerance: float = SIMPLIFY_TOLERANCE) -> vp.LineCollection:
    """Each stroke simplified within tolerance (Douglas-Peucker, as vpype's linesimplify)."""
    from shapely.geometry import LineString  # type: ignore[import-untyped]

    out = lc.clone()
    for line in lc:
        coords = np.asarray(LineString(np.c_[line.real, line.imag]).simplify(tolerance, preserve_topology=False).coords)
        out.append(coords[:, 0] + 1j * coords[:, 1] if len(coords) >= 2 else line)
    return out


def sort_lines(lc: vp.LineCollection) -> vp.LineCollection:
    """Strokes reordered (and reversed where it helps) to cut pen-up travel: vpype's linesort.

    Greedy: from the first stroke, always the stroke with the nearest end
    next. The original order is kept if that would not shorten the travel,
    so sorting never makes it longer."""
    if len(lc) < 2:
        return lc
    index = vp.LineIndex(lc[1:], reverse=True)
    out = lc.clone([lc[0]])
    while len(index) > 0:
        idx, reverse = index.find_nearest(out[-1][-1])
        line = index.pop(idx)
        if line is not None:
            out.append(np.flip(line) if reverse else line)
    return out if pen_up_travel(out) < pen_up_travel(lc) else lc


@dataclass(frozen=True)
class Tidy:
    """What tidying did: strokes before and after, pen-up travel (m) before and after sorting."""

    strokes_in: int
    strokes_out: int
    travel_before: float
    travel_after: float


def tidy(lc: vp.LineCollection) -> tuple[vp.LineCollection, Tidy]:
    """Merge touching strokes, simplify, then sort; with the pen-up travel before and after the sort."""
    n_in = len(lc)
    merged = lc.clone()
    merged.extend(lc)
    merged.merge(MERGE_TOLERANCE, flip=True)
    merged = simplify(merged)
    before = pen_up_travel(merged)
    out = sort_lines(merged)
    return out, Tidy(n_in, len(out), before, pen_up_travel(out))
