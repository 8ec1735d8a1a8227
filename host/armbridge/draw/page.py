"""The page a drawing goes on: `armbridge draw --page A4|A5|letter|WxH --margin MM --rotate DEG`.

A page is a sheet lying in the arm's plane, its sides along the arm's x and y,
its centre where the drawing's centre goes (`--at`, default the safe disc's
centre). The drawing, turned by `--rotate` degrees (counter-clockwise), is
fitted into the page less its margin on every side *and* into the arm's safe
disc less its safety margin (`layout.place`): whichever is tighter sets its
size, and the command says which. Sizes come from vpype's own table
(`vpype.PAGE_SIZES`, `vpype.convert_page_size`), portrait unless `--landscape`;
`WxH` (W along x) is in mm unless it names a unit (`210x297mm`, `15x10cm`,
`8.5x11in`), turned only by `--landscape` when it is portrait.

The page also fixes the frame of the SVG export (`draw.export`): page
coordinates, origin at its top-left corner, y down, in mm, as a plotter's
software expects.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import vpype as vp  # type: ignore[import-untyped]

from armbridge.errors import ArmbridgeError

PAGES = ("A4", "A5", "letter")  # the names --help shows; vpype knows a few more (a6..a0, legal, tabloid)
ROTATE_RANGE = (-360.0, 360.0)  # degrees accepted by --rotate
PX_PER_M = 1000.0 / 25.4 * 96.0  # vpype's unit is the CSS pixel, 96 a inch
_WXH = re.compile(r"^\s*(\d+(?:\.\d*)?)\s*x\s*(\d+(?:\.\d*)?)\s*([a-z]*)\s*$", re.IGNORECASE)


@dataclass(frozen=True)
class Page:
    """A sheet: its name, size (m, as it lies: width along x) and margin (m)."""

    name: str
    width: float
    height: float
    margin: float = 0.0

    @property
    def printable(self) -> tuple[float, float]:
        """Width and height of the page less its margin on every side, m."""
        return self.width - 2 * self.margin, self.height - 2 * self.margin

    def corner(self, center) -> np.ndarray:
        """The page's top-left corner in the arm's frame (m) when its centre is at `center`."""
        return np.asarray(center, float) + [-self.width / 2, self.height / 2]

    def to_page(self, xy, center) -> np.ndarray:
        """Arm-frame points (n, 2), m -> page coordinates in mm (origin top-left, y down)."""
        c = self.corner(center)
        xy = np.asarray(xy, float).reshape(-1, 2)
        return np.c_[xy[:, 0] - c[0], c[1] - xy[:, 1]] * 1000.0

    def to_dict(self) -> dict:
        return {"name": self.name, "width_mm": round(self.width * 1000, 3),
                "height_mm": round(self.height * 1000, 3), "margin_mm": round(self.margin * 1000, 3)}


def parse_page(spec: str, *, landscape: bool = False, margin_mm: float = 0.0) -> Page:
    """The --page value (a name vpype knows, or WxH) with --landscape and --margin, checked:
    one clear line naming what is accepted when it is not."""
    text = str(spec).strip()
    m = _WXH.match(text)
    try:
        if m is not None:
            unit = m.group(3) or "mm"
            w_px, h_px = vp.convert_page_size(f"{m.group(1)}x{m.group(2)}{unit}")
        else:
            w_px, h_px = vp.convert_page_size(text.lower())
    except (ValueError, KeyError):
        raise ArmbridgeError(f"--page {spec!r}: expected {', '.join(PAGES)} (or {', '.join(_others())}) or WxH "
                             "in mm, e.g. 150x100 or 15x10cm") from None
    w, h = float(w_px) / PX_PER_M, float(h_px) / PX_PER_M
    if not (w > 0 and h > 0):
        raise ArmbridgeError(f"--page {spec!r}: both sides must be above 0")
    if (landscape and w < h) or (m is None and not landscape and w > h):  # WxH as given, unless --landscape
        w, h = h, w
    margin = check_margin(margin_mm, w, h)
    return Page(text if m is not None else text.upper() if text.lower()[0] == "a" else text.lower(), w, h, margin)


def _others() -> list[str]:
    return [k for k in vp.PAGE_SIZES if k not in ("tight", "a4", "a5", "letter")]


def check_margin(margin_mm: float, width: float, height: float) -> float:
    """--margin (mm) -> m, checked against the page: 0 <= margin < half its shorter side."""
    limit = min(width, height) / 2 * 1000
    if not (0 <= margin_mm < limit):
        raise ArmbridgeError(f"--margin {margin_mm:g} mm: expected 0 <= MM < {limit:g} (half the page's "
                             "shorter side)")
    return margin_mm / 1000.0


def check_rotate(degrees: float) -> float:
    """--rotate (degrees, counter-clockwise), checked: within ROTATE_RANGE."""
    lo, hi = ROTATE_RANGE
    if not (lo <= degrees <= hi):
        raise ArmbridgeError(f"--rotate {degrees:g}: expected degrees in [{lo:g}, {hi:g}]")
    return float(degrees)


def rotated(lc: vp.LineCollection, degrees: float) -> vp.LineCollection:
    """A copy of lc turned counter-clockwise by degrees about the origin (vpype's rotate; y is up
    here, so vpype's clockwise-on-screen angle is counter-clockwise in the arm's frame)."""
    out = vp.LineCollection(lc)
    if degrees:
        out.rotate(np.radians(degrees))
    return out
