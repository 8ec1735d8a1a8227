"""The SMMs of a batch of task locations, whichever method computed them."""
from __future__ import annotations

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
