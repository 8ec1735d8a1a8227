"""Tip paths for drawing: pure geometry, numpy in and out."""
from __future__ import annotations

import numpy as np

from armbridge.errors import ArmbridgeError


def polyline(corners: np.ndarray, step: float, closed: bool = True) -> np.ndarray:
    """Points every `step` metres along the corners (the corners themselves included)."""
    corners = np.asarray(corners, dtype=float)
    if closed:
        corners = np.vstack([corners, corners[:1]])
    points = [corners[:1]]
    for a, b in zip(corners[:-1], corners[1:]):
        count = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        t = np.arange(1, count + 1)[:, None] / count
        points.append(a + t * (b - a))
    return np.vstack(points)


def square(center: tuple[float, float], side: float, step: float) -> np.ndarray:
    """A square traced counter-clockwise from its lower-left corner."""
    if side <= 0 or step <= 0:
        raise ArmbridgeError(f"square: side ({side}) and step ({step}) must be positive")
    cx, cy, h = center[0], center[1], side / 2
    return polyline(np.array([[cx - h, cy - h], [cx + h, cy - h], [cx + h, cy + h], [cx - h, cy + h]]), step)


def segment_durations(points: np.ndarray, speed: float, min_duration: float = 0.01) -> np.ndarray:
    """Time for each segment at a constant tip speed (m/s); entry 0 is the first segment."""
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.maximum(lengths / speed, min_duration)
