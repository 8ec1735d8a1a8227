"""The SMMs of a batch of task locations, whichever method computed them."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SmmSet:
    """SMMs of L task locations, each branch sampled at N configurations.

    points[l, b] is branch b of location l for b < count[l]; slots past the
    count are NaN. Angles are radians wrapped to (-pi, pi]. count[l] == 0
    means the location is out of reach. singular[l] is True when a branch of
    l passes within tolerance of a singular configuration (such locations
    separate clusters in the cellular automaton).
    """

    points: np.ndarray  # (L, Bmax, N, n) float64
    count: np.ndarray  # (L,) int64
    singular: np.ndarray  # (L,) bool

    def __post_init__(self) -> None:
        if self.points.ndim != 4:
            raise ValueError(f"points must be (L, Bmax, N, n), got {self.points.shape}")
        L = self.points.shape[0]
        if self.count.shape != (L,) or self.singular.shape != (L,):
            raise ValueError("count and singular must have one entry per location")

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def branches(self, l: int) -> list[np.ndarray]:
        """The branches of location l, each (N, n)."""
        return [self.points[l, b] for b in range(int(self.count[l]))]


def concat(parts: Sequence[SmmSet], n_points: int, n: int) -> SmmSet:
    """One SmmSet from several (in order), padding branch slots with NaN to the largest count."""
    if len(parts) == 1:
        return parts[0]
    bmax = max([1] + [p.points.shape[1] for p in parts])
    pts = np.full((sum(len(p) for p in parts), bmax, n_points, n), np.nan)
    row = 0
    for p in parts:
        pts[row : row + len(p), : p.points.shape[1]] = p.points
        row += len(p)
    return SmmSet(points=pts, count=np.concatenate([p.count for p in parts] or [np.zeros(0, dtype=np.int64)]),
                  singular=np.concatenate([p.singular for p in parts] or [np.zeros(0, dtype=bool)]))
