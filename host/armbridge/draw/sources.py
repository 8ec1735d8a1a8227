"""What to draw, turned into strokes: text, SVG, CSV points, images, shapes.

Every source gives a `vpype.LineCollection` in its own units with y up (the
arm's frame; SVG, images and vpype's fonts have y down, so they are flipped
here). Each line is one pen-down stroke; the pen is up between lines.
Placement (`layout.place`) scales and moves the result into the arm's safe
region, so units here only fix the aspect ratio.

The parsers are pure (text or arrays in, lines out); reading files happens in
the `*_file` functions, which name the file in every error.
"""
from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import vpype as vp  # type: ignore[import-untyped]

from armbridge.errors import ArmbridgeError

DEFAULT_FONT = "futural"  # Hershey Simplex: single-stroke, what pen plotters draw text with
LINE_SPACING = 1.4  # text lines apart, in font heights
SHAPES = ("circle", "triangle", "square", "pentagon", "hexagon", "star")
CIRCLE_POINTS = 120  # a circle drawn as this many chords: 0.03 % radial error
STAR_INNER = 0.382  # inner/outer radius of the five-point star (a regular pentagram's)
IMAGE_TOLERANCE = 0.5  # px: contour simplification (skimage approximate_polygon)
IMAGE_SIGMA = 1.0  # px: smoothing before tracing
IMAGE_MIN_PERIMETER = 8.0  # px: smaller contours are speckle, not drawing
SVG_QUANTIZATION = 0.1  # px: curves in an SVG become segments this fine (vpype.read_svg)


def to_strokes(lc: vp.LineCollection) -> list[np.ndarray]:
    """The lines of a LineCollection as (k, 2) float arrays."""
    return [np.c_[line.real, line.imag].astype(float) for line in lc]


def from_strokes(strokes) -> vp.LineCollection:
    """A LineCollection of (k, 2) arrays (strokes of fewer than two points are dropped)."""
    return vp.LineCollection([s[:, 0] + 1j * s[:, 1] for s in map(np.asarray, strokes) if len(s) >= 2])


def _flip_y(lc: vp.LineCollection) -> vp.LineCollection:
    lc.scale(1.0, -1.0)
    return lc


# ---------------------------------------------------------------------------
# text


def text_lines(text: str, font: str = DEFAULT_FONT) -> vp.LineCollection:
    """Text in a Hershey font, one font height tall; "\\n" starts a new line.

    A character the font has no strokes for is an error (vpype would skip it
    silently and the drawing would lose a letter)."""
    if not text.strip():
        raise ArmbridgeError("the text to draw is empty")
    if font not in vp.FONT_NAMES:
        raise ArmbridgeError(f'unknown font "{font}" (known: {", ".join(vp.FONT_NAMES)})')
    for ch in sorted(set(text) - {" ", "\n"}):
        if vp.text_line(ch, font, size=1.0).is_empty():
            raise ArmbridgeError(f"font {font} has no glyph for {ch!r} (U+{ord(ch):04X}); "
                                 "the Hershey fonts cover printable ASCII")
    lc = vp.LineCollection()
    for row, line in enumerate(text.split("\n")):
        part = vp.text_line(line, font, size=1.0)
        part.translate(0, row * LINE_SPACING)
        lc.extend(part)
    return _flip_y(lc)


# ---------------------------------------------------------------------------
# SVG


def svg_lines(svg: str, name: str = "<svg>") -> vp.LineCollection:
    """The paths of an SVG document (curves as segments, every shape as lines)."""
    try:
        lc, _, _ = vp.read_svg(io.StringIO(svg), SVG_QUANTIZATION, crop=False)
    except Exception as exc:  # noqa: BLE001 - svgelements/xml raise many types: all are "unreadable"
        raise ArmbridgeError(f"{name}: cannot read the SVG ({type(exc).__name__}: {exc})") from None
    if lc.is_empty():
        raise ArmbridgeError(f"{name}: the SVG has no paths or shapes to draw")
    return _flip_y(lc)


def svg_file(path: Path | str) -> vp.LineCollection:
    """`svg_lines` of a file."""
    return svg_lines(_read_text(path, "SVG"), str(path))


def _read_text(path: Path | str, what: str) -> str:
    try:
        return Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ArmbridgeError(f"{path}: cannot read the {what} file ({exc.strerror or exc})"
                             if isinstance(exc, OSError) else f"{path}: the {what} file is not UTF-8 text") from None


# ---------------------------------------------------------------------------
# CSV


def csv_lines(text: str, name: str = "<csv>") -> vp.LineCollection:
    """Points `x,y` one a line; a blank line ends a stroke. See docs/drawing.md.

    An optional header row names the columns (`x`, `y` and optionally `pen`).
    With a `pen` column, a row with pen 0 is a pen-up move to that point: it
    starts a new stroke; pen 1 draws to the point. `#` starts a comment."""
    cols: tuple[str, ...] = ("x", "y")
    strokes: list[list[tuple[float, float]]] = [[]]
    seen_data = False
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            if strokes[-1]:
                strokes.append([])
            continue
        cells = [c.strip() for c in line.split(",")]
        if not seen_data and all(c.lower() in ("x", "y", "pen") for c in cells):
            cols = tuple(c.lower() for c in cells)
            if sorted(cols) not in (["x", "y"], ["pen", "x", "y"]):
                raise ArmbridgeError(f"{name}: line {lineno}: the header names {', '.join(cols)}; "
                                     "it needs x and y, and may add pen")
            continue
        seen_data = True
        if len(cells) != len(cols):
            raise ArmbridgeError(f"{name}: line {lineno}: {len(cells)} values, expected {len(cols)} "
                                 f"({', '.join(cols)})")
        row = {}
        for j, (col, cell) in enumerate(zip(cols, cells), start=1):
            try:
                v = float(cell)
            except ValueError:
                v = math.nan
            if not math.isfinite(v) or (col == "pen" and v not in (0.0, 1.0)):
                want = "0 (up) or 1 (down)" if col == "pen" else "a finite number"
                raise ArmbridgeError(f"{name}: line {lineno}, column {j} ({col}): {cell!r} is not {want}")
            row[col] = v
        if row.get("pen", 1.0) == 0.0 and strokes[-1]:
            strokes.append([])
        strokes[-1].append((row["x"], row["y"]))
    lc = from_strokes([np.array(s) for s in strokes if s])
    if lc.is_empty():
        raise ArmbridgeError(f"{name}: no stroke of two or more points to draw")
    return lc


def csv_file(path: Path | str) -> vp.LineCollection:
    """`csv_lines` of a file."""
    return csv_lines(_read_text(path, "CSV"), str(path))


# ---------------------------------------------------------------------------
# images


def image_lines(image: np.ndarray, name: str = "<image>") -> vp.LineCollection:
    """The outlines of the dark shapes in an image (grey or colour, any dtype).

    The image is smoothed a little (a Gaussian of IMAGE_SIGMA px: a binary
    image's pixel staircase would otherwise become hundreds of tiny steps),
    `measure.find_contours` traces each boundary at Otsu's threshold (ink
    from paper) at sub-pixel precision, and `approximate_polygon` keeps it
    within IMAGE_TOLERANCE px with far fewer points. One pixel is one unit.
    An image with an alpha channel (RGBA, grey + alpha) is laid on white paper
    first; where that leaves one flat colour (a white shape on a transparent
    ground) its alpha channel is traced instead: opaque is ink."""
    from skimage import filters, measure

    img = _grey(np.asarray(image))
    if img.ndim != 2 or min(img.shape) < 3:
        raise ArmbridgeError(f"{name}: not an image of at least 3x3 pixels (shape {img.shape})")
    img = img.astype(float)
    if np.ptp(img) == 0:
        raise ArmbridgeError(f"{name}: the image is one flat colour: nothing to trace")
    img = (img - img.min()) / np.ptp(img)
    img = filters.gaussian(np.pad(img, 2, constant_values=1.0), sigma=IMAGE_SIGMA)  # pad: closed outlines
    strokes = []
    for c in measure.find_contours(img, filters.threshold_otsu(img)):
        c = measure.approximate_polygon(c, IMAGE_TOLERANCE)
        if np.sum(np.hypot(*np.diff(c, axis=0).T)) >= IMAGE_MIN_PERIMETER:
            strokes.append(np.c_[c[:, 1] - 2, -(c[:, 0] - 2)])  # (row, col) -> (x, y up)
    if not strokes:
        raise ArmbridgeError(f"{name}: no outline found in the image")
    return from_strokes(strokes)


def _grey(img: np.ndarray) -> np.ndarray:
    """An image as grey levels in [0, 1] (dark = ink); alpha composited over white, or the alpha
    itself (1 - alpha) where the composite is flat and the alpha is not."""
    from skimage import color

    if img.ndim == 3 and img.shape[-1] == 1:
        return img[..., 0]
    if img.ndim != 3 or img.shape[-1] not in (2, 3, 4):
        return img
    full = float(np.iinfo(img.dtype).max) if np.issubdtype(img.dtype, np.integer) else 1.0
    x = img.astype(float) / full
    grey = color.rgb2gray(x[..., :3]) if x.shape[-1] >= 3 else x[..., 0]
    if x.shape[-1] in (2, 4):
        alpha = np.clip(x[..., -1], 0.0, 1.0)
        over_white = alpha * grey + (1.0 - alpha)
        grey = 1.0 - alpha if np.ptp(over_white) == 0 and np.ptp(alpha) > 0 else over_white
    return grey


def image_file(path: Path | str) -> vp.LineCollection:
    """`image_lines` of an image file (anything scikit-image reads: PNG, JPEG, BMP, TIFF...)."""
    from skimage import io as skio

    try:
        img = skio.imread(str(path))
    except Exception as exc:  # noqa: BLE001 - imageio raises many types: all mean "unreadable"
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else "not an image scikit-image can read"
        raise ArmbridgeError(f"{path}: cannot read the image ({why})") from None
    return image_lines(img, str(path))


# ---------------------------------------------------------------------------
# shapes


def shape_outline(name: str) -> np.ndarray:
    """A closed outline (k, 2) of unit circumradius, centred on the origin; a polygon stands on a
    flat side, the star on two points."""
    key = name.lower()
    sides = {"triangle": 3, "square": 4, "pentagon": 5, "hexagon": 6}
    if key == "circle":
        n, radii, start = CIRCLE_POINTS, np.ones(CIRCLE_POINTS), 0.0
    elif key in sides:
        n = sides[key]
        n, radii, start = n, np.ones(n), -np.pi / 2 + np.pi / n  # the bottom side horizontal
    elif key == "star":
        n, radii, start = 10, np.tile([1.0, STAR_INNER], 5), np.pi / 2
    else:
        raise ArmbridgeError(f'unknown shape "{name}" (known: {", ".join(SHAPES)})')
    a = start + 2 * np.pi * np.arange(n) / n
    pts = np.c_[radii * np.cos(a), radii * np.sin(a)]
    return np.vstack([pts, pts[:1]])


def shape_lines(name: str) -> vp.LineCollection:
    """A shape (see SHAPES) as one closed stroke."""
    return from_strokes([shape_outline(name)])


def characters(text: str) -> int:
    """The characters of a text that are drawn (not spaces or new lines)."""
    return sum(1 for c in text if not c.isspace())
