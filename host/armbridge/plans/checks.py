"""Checks the plan sections share (plans/masr.py, plans/soft.py): pure, numbers in, one error line out."""
from __future__ import annotations

from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError


def polygon(p: Any, where: str, min_vertices: int = 2) -> np.ndarray:
    """An obstacle as its (v, 2) vertices in m; ArmbridgeError `where` names otherwise."""
    try:
        a = np.asarray(p, dtype=float)
    except (TypeError, ValueError):
        a = np.zeros((0,))
    if a.ndim != 2 or a.shape[1] != 2 or a.shape[0] < min_vertices or not np.all(np.isfinite(a)):
        raise ArmbridgeError(f"{where} must be a list of at least {min_vertices} [x, y] vertices")
    return a
