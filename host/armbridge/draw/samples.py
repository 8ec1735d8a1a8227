"""The paper's twelve samples (Table 3), built in: `armbridge draw --sample NAME`.

Each goes through the same code path as a user's input of its kind: the two
CSV samples are CSV text (docs/drawing.md shows them as examples of the
format), the five image samples are rasters of the filled shape traced by
`sources.image_lines`, the five text samples are Hershey text.
"""
from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np
import vpype as vp  # type: ignore[import-untyped]

from armbridge.draw import sources
from armbridge.errors import ArmbridgeError

IMAGE_PX = 200  # the image samples' raster is this many pixels square; the shape spans 80 percent

# Table 3 no. 1: a circle of radius 5 cm, one point every 10 degrees, one stroke.
CSV_CIRCLE = """\
# armbridge draw sample: Table 3 no. 1 (CSV, circle); x,y in cm
x,y
5.0000,0.0000
4.9240,0.8682
4.6985,1.7101
4.3301,2.5000
3.8302,3.2139
3.2139,3.8302
2.5000,4.3301
1.7101,4.6985
0.8682,4.9240
0.0000,5.0000
-0.8682,4.9240
-1.7101,4.6985
-2.5000,4.3301
-3.2139,3.8302
-3.8302,3.2139
-4.3301,2.5000
-4.6985,1.7101
-4.9240,0.8682
-5.0000,0.0000
-4.9240,-0.8682
-4.6985,-1.7101
-4.3301,-2.5000
-3.8302,-3.2139
-3.2139,-3.8302
-2.5000,-4.3301
-1.7101,-4.6985
-0.8682,-4.9240
0.0000,-5.0000
0.8682,-4.9240
1.7101,-4.6985
2.5000,-4.3301
3.2139,-3.8302
3.8302,-3.2139
4.3301,-2.5000
4.6985,-1.7101
4.9240,-0.8682
5.0000,0.0000
"""

# Table 3 no. 2: MANIT in block capitals, 6 cm tall; pen 0 = move there with the pen up.
CSV_MANIT = """\
# armbridge draw sample: Table 3 no. 2 (CSV, MANIT); x,y in cm
x,y,pen
0,0,0
0,6,1
2,3,1
4,6,1
4,0,1
5.5,0,0
7.5,6,1
9.5,0,1
6.1667,2,0
8.8333,2,1
11,0,0
11,6,1
15,0,1
15,6,1
16.5,0,0
16.5,6,1
18,6,0
22,6,1
20,6,0
20,0,1
"""


def _image(shape: str) -> np.ndarray:
    """A white raster with the shape filled black (what a scanned or drawn shape looks like)."""
    from skimage.draw import polygon

    img = np.ones((IMAGE_PX, IMAGE_PX))
    outline = sources.shape_outline(shape) * 0.4 * IMAGE_PX + IMAGE_PX / 2
    rr, cc = polygon(IMAGE_PX - outline[:, 1], outline[:, 0], img.shape)
    img[rr, cc] = 0.0
    return img


class Sample(NamedTuple):
    """One row of Table 3: its number, source kind, what it draws, and how it is built."""

    number: int
    source: str
    plot: str
    build: Callable[[], vp.LineCollection]


def _text(t: str) -> Callable[[], vp.LineCollection]:
    return lambda: sources.text_lines(t)


def _img(shape: str) -> Callable[[], vp.LineCollection]:
    return lambda: sources.image_lines(_image(shape), f"sample image-{shape}")


SAMPLES: dict[str, Sample] = {
    "csv-circle": Sample(1, "CSV", "Circle", lambda: sources.csv_lines(CSV_CIRCLE, "sample csv-circle")),
    "csv-manit": Sample(2, "CSV", "MANIT", lambda: sources.csv_lines(CSV_MANIT, "sample csv-manit")),
    "image-circle": Sample(3, "Image", "Circle", _img("circle")),
    "image-triangle": Sample(4, "Image", "Triangle", _img("triangle")),
    "image-square": Sample(5, "Image", "Square", _img("square")),
    "image-pentagon": Sample(6, "Image", "Pentagon", _img("pentagon")),
    "image-hexagon": Sample(7, "Image", "Hexagon", _img("hexagon")),
    "text-manit": Sample(8, "Text", "MANIT", _text("MANIT")),
    "text-robotics": Sample(9, "Text", "ROBOTICS", _text("ROBOTICS")),
    "text-3-link": Sample(10, "Text", "3 LINK", _text("3 LINK")),
    "text-bhopal": Sample(11, "Text", "BHOPAL", _text("BHOPAL")),
    "text-research": Sample(12, "Text", "RESEARCH", _text("RESEARCH")),
}


def sample_lines(name: str) -> vp.LineCollection:
    """The strokes of a built-in sample (see SAMPLES)."""
    s = SAMPLES.get(name.lower())
    if s is None:
        raise ArmbridgeError(f'unknown sample "{name}" (known: {", ".join(SAMPLES)})')
    return s.build()
