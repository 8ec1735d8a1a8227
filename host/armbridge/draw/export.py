"""What was drawn, as a plotter user keeps it: an SVG of the pen-down strokes at the page's scale.

`drawn_strokes(rrd)` reads a run's recording back: the pen trace the run logs
under `drawing/trace` (executor/run.py -> telemetry/recording.py: forward
kinematics of every measured joint sample whose active segment draws, i.e.
pen down only), the last, complete one. `planned_strokes(plan)` are the plan's
own pen-down strokes (FK of its waypoints), for a drawing that was not run.

`svg_text(strokes, page, center)` writes them with vpype (`vpype.write_svg`)
in page coordinates: origin at the page's top-left corner, y down, 1 mm on
the arm's plane = 1 mm in the file (its width and height carry the unit).
Without a page (`--page`), the page is the strokes' bounding box plus
BORDER on every side.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import vpype as vp  # type: ignore[import-untyped]

from armbridge.draw.page import PX_PER_M, Page
from armbridge.errors import ArmbridgeError

BORDER = 0.005  # m: the margin around the strokes of a drawing without --page
TRACE_ENTITY = "/drawing/trace"


def planned_strokes(plan) -> list[np.ndarray]:
    """The plan's pen-down strokes (FK of its waypoints, m, arm frame)."""
    from armbridge.plans.drawing import pen_strips

    if plan.pen is None:
        raise ArmbridgeError("the plan has no pen flags: nothing is drawn with the pen down")
    return [s for s in pen_strips(np.asarray(plan.ee_path())[:, :2], plan.pen) if len(s) >= 2]


def drawn_strokes(rrd: Path | str) -> list[np.ndarray]:
    """The executed pen-down trace of a run's recording (m, arm frame): runs of measured samples
    taken while the pen was down, each through FK. Empty when the run drew nothing."""
    from rerun.chunk import RrdReader  # type: ignore[import-untyped]

    last: list | None = None
    best_t = -np.inf
    try:
        chunks = list(RrdReader(str(rrd)).stream())
    except Exception as exc:  # noqa: BLE001 - rerun raises its own types for a missing or bad file
        raise ArmbridgeError(f"{rrd}: cannot read the run's recording ({exc})") from None
    for chunk in chunks:
        if chunk.entity_path != TRACE_ENTITY:
            continue
        rb = chunk.to_record_batch()
        col = [c for c in rb.schema.names if c.endswith("LineStrips2D:strips")]
        times = rb.column("board_time").to_pylist() if "board_time" in rb.schema.names else None
        for i, value in enumerate(rb.column(col[0]).to_pylist()):
            t = _seconds(times[i]) if times is not None else float(i)
            if value is not None and t >= best_t:
                best_t, last = t, value
    return [np.asarray(s, float).reshape(-1, 2) for s in (last or []) if len(s) >= 2]


def _seconds(t) -> float:
    if hasattr(t, "total_seconds"):
        return float(t.total_seconds())
    return float(t) / 1e9 if isinstance(t, int) else float(t)


def frame(strokes: list[np.ndarray], page: Page | None, center) -> tuple[Page, tuple[float, float]]:
    """The page the SVG is drawn on and its centre (arm frame, m): the drawing's page, or the
    strokes' bounding box grown by BORDER."""
    if page is not None:
        return page, (float(center[0]), float(center[1]))
    pts = np.vstack(strokes) if strokes else np.zeros((1, 2)) + np.asarray(center, float)
    lo, hi = pts.min(axis=0) - BORDER, pts.max(axis=0) + BORDER
    mid = (lo + hi) / 2
    return Page("tight", float(hi[0] - lo[0]), float(hi[1] - lo[1])), (float(mid[0]), float(mid[1]))


def svg_text(strokes: list[np.ndarray], page: Page | None, center, *, label: str = "drawn",
             source: str = "") -> str:
    """An SVG (vpype's writer) of strokes (m, arm frame) on the page centred at `center`."""
    page, mid = frame(strokes, page, center)
    lines = vp.LineCollection()
    for s in strokes:
        p = page.to_page(s, mid) / 1000.0 * PX_PER_M  # mm on the page -> vpype's px
        lines.append(p[:, 0] + 1j * p[:, 1])
    doc = vp.Document(page_size=(page.width * PX_PER_M, page.height * PX_PER_M))
    doc.add(lines, 1)
    doc.layers[1].set_property("vp_name", label)
    out = io.StringIO()
    vp.write_svg(out, doc, source_string=source, set_date=False)
    return out.getvalue()


def write_svg(path: Path | str, strokes: list[np.ndarray], page: Page | None, center, **kw) -> Path:
    """svg_text to a file (its folder made); an unwritable path is one clear line."""
    path = Path(path)
    text = svg_text(strokes, page, center, **kw)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ArmbridgeError(f"{path}: cannot write the SVG ({exc.strerror})") from None
    return path
