"""Placement and line clean-up, on vpype's LineCollection.

`place` scales and moves a drawing into the safe disk (`ik.region.safe_region`)
at the size and position the user asked for, or as large as fits inside the
disk less a margin (`margin_for`: what the executed pen strays from the
commanded one, measured); a drawing that cannot fit the disk is an error
naming by how much it overflows. `tidy` then runs
vpype's own commands on the placed lines (`vpype_cli.execute`): `linemerge`
(strokes whose ends meet joined), `linesimplify`, `filter --min-length` and
`linesort` (its greedy nearest-end search, kept only where it helps, then
with `--two-opt` its 2-opt passes: 10-40 % less pen-up travel on text).
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
TWO_OPT_PASSES = 250  # vpype linesort's default passes of 2-opt
SORTS = ("2opt", "greedy", "none")  # `armbridge draw --sort`

@dataclass(frozen=True)
class Placement:
    """Where a drawing went: its scale (m per source unit), its centre and its size (m)."""

    scale: float
    at: tuple[float, float]
    size: float  # the longer side of its bounding box, m
    largest: float  # the largest size that fits at `at` keeping the margin (what --fit gives), m
    margin: float = 0.0  # m: what --fit kept inside the disk's edge
    limited_by: str = "reach"  # what set the --fit size: "reach" (the safe disk) or "page" (its printable area)


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
          at=None, margin: float = 0.0, box: tuple[float, float] | None = None) -> tuple[vp.LineCollection, Placement]:
    """The drawing scaled and moved into the disk (center, radius), and where it went.

    The bounding box's centre goes to `at` (default: the disk's centre). With
    `size` (m) the box's longer side is that long; without it the drawing is
    as large as fits `margin` (m) inside the disk's edge. Raises ArmbridgeError
    when it does not fit the disk, naming the overflow and the largest size that
    would; with a margin, also the largest that keeps it (a drawing between the
    two is accepted: the CBF filter presses its edge onto the margin). `box` (width, height, m):
    a page's printable area centred on `at`, which the drawing must also fit (draw.page)."""
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
    s_disc = s_fit = fit_scale(d, a, radius - margin - FIT_SLACK)  # FIT_SLACK: the IK round trip stays inside
    limited_by = "reach"
    if box is not None:
        span = hi - lo
        s_box = min(float(box[i]) / span[i] if span[i] > 0 else np.inf for i in (0, 1))
        if size is not None and size / extent > s_box * (1 + 1e-12):
            raise ArmbridgeError(f"the drawing at --size {size:g} m does not fit the page's printable area "
                                 f"({_mm(box[0])} x {_mm(box[1])}); the largest that does is {s_box * extent:.4f} m")
        if s_box < s_fit:
            s_fit, limited_by = s_box, "page"
    s = s_fit if size is None else size / extent
    placed = np.linalg.norm(a + s * d, axis=1)
    over = float(placed.max()) - radius
    if over > FIT_SLACK:
        keeps = f" ({s_disc * extent:.4f} m keeps the {_mm(margin)} margin, as --fit does)" if margin > 0 else ""
        raise ArmbridgeError(f"the drawing at --size {size:g} m overflows {where} by {_mm(over)}; "
                             f"the largest size that fits at ({target[0]:.4f}, {target[1]:.4f}) m "
                             f"is {fit_scale(d, a, radius) * extent:.4f} m{keeps}")
    out = lc.clone()
    out.extend(lc)
    out.translate(-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2)
    out.scale(s)
    out.translate(float(target[0]), float(target[1]))
    return out, Placement(scale=s, at=(float(target[0]), float(target[1])), size=s * extent,
                          largest=s_fit * extent, margin=margin, limited_by=limited_by if size is None else "size")


def pen_up_travel(lc: vp.LineCollection) -> float:
    """Total pen-up distance between consecutive strokes (vpype's pen_up_length), in the lines' units."""
    return float(lc.pen_up_length()[0]) if len(lc) > 1 else 0.0


def _pipeline(lc: vp.LineCollection, commands: str) -> vp.LineCollection:
    """lc through a vpype pipeline (`vpype_cli.execute`: the commands' own code, on a copy).
    Lengths in the commands are plain numbers: the lines' own unit (m here)."""
    import vpype_cli  # type: ignore[import-untyped]

    doc = vp.Document()
    doc.add(vp.LineCollection(lc), 1)
    out = vpype_cli.execute(commands, doc)
    return out.layers[1] if 1 in out.layers else vp.LineCollection()


def simplify(lc: vp.LineCollection, tolerance: float = SIMPLIFY_TOLERANCE) -> vp.LineCollection:
    """Each stroke simplified within tolerance (vpype's linesimplify)."""
    return _pipeline(lc, f"linesimplify -t {tolerance!r}") if len(lc) else lc


def merge(lc: vp.LineCollection, tolerance: float = MERGE_TOLERANCE) -> vp.LineCollection:
    """Strokes whose ends lie within tolerance joined, either way round (vpype's linemerge)."""
    return _pipeline(lc, f"linemerge -t {tolerance!r}") if len(lc) else lc


def drop_short(lc: vp.LineCollection, min_length: float) -> vp.LineCollection:
    """Strokes shorter than min_length dropped (vpype's filter --min-length); 0 keeps all."""
    return _pipeline(lc, f"filter -m {min_length!r}") if len(lc) and min_length > 0 else lc


def sort_lines(lc: vp.LineCollection, two_opt: bool = False, passes: int = TWO_OPT_PASSES) -> vp.LineCollection:
    """Strokes reordered (and reversed where it helps) to cut pen-up travel: vpype's linesort.

    Greedy (the nearest end next, vpype keeps the original order where that
    is shorter), then with `two_opt` vpype's 2-opt passes on the result (a
    pass swaps the segments of the tour that shorten it; deterministic)."""
    if len(lc) < 2:
        return lc
    return _pipeline(lc, "linesort" + (f" --two-opt --passes {int(passes)}" if two_opt else ""))


@dataclass(frozen=True)
class Tidy:
    """What tidying did: strokes before and after, pen-up travel (m) before sorting, after the
    greedy sort and after the chosen sort (`sort`: none, greedy or 2opt)."""

    strokes_in: int
    strokes_out: int
    travel_before: float
    travel_after: float
    travel_greedy: float = float("nan")
    sort: str = "2opt"
    dropped: int = 0  # strokes the length filter dropped


def check_sort(sort: str) -> str:
    """The --sort value, checked: one of SORTS (case-insensitive), else one clear line."""
    s = str(sort).strip().lower().replace("-", "")
    if s not in SORTS:
        raise ArmbridgeError(f"--sort {sort!r}: expected one of {', '.join(SORTS)}")
    return s


def tidy(lc: vp.LineCollection, *, sort: str = "2opt", merge_tolerance: float = MERGE_TOLERANCE,
         min_length: float = 0.0, passes: int = TWO_OPT_PASSES) -> tuple[vp.LineCollection, Tidy]:
    """Merge touching strokes, simplify, drop the shorter than min_length, then sort (vpype's
    linemerge, linesimplify, filter, linesort [--two-opt]); with the pen-up travel before the
    sort, after the greedy sort and after the chosen one."""
    sort = check_sort(sort)
    n_in = len(lc)
    merged = simplify(merge(lc, merge_tolerance))
    kept = drop_short(merged, min_length)
    if len(kept) == 0:
        raise ArmbridgeError(f"nothing to draw: every stroke is shorter than the {min_length * 1000:g} mm "
                             "--min-stroke length")
    before = pen_up_travel(kept)
    greedy = sort_lines(kept) if sort != "none" else kept
    out = sort_lines(greedy, two_opt=True, passes=passes) if sort == "2opt" else greedy
    return out, Tidy(n_in, len(out), before, pen_up_travel(out), pen_up_travel(greedy), sort,
                     len(merged) - len(kept))
