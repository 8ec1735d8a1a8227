"""Where SMMs are taken: grids over canonical coordinates, and random locations.

A `GridSpec` is a regular grid of cells over canonical coordinates (the
joint-1 symmetry removed, `SmmArm.canonical`); a learned SMM's data set
(smm/dataset.py) takes the ground-truth SMMs of its cell centres.

Default grids (`default_grid`, every size settable):
- 'xy' arms (planar 3R): 200 radial cells (the paper's 200) over [0, r_max];
- 'xyz' arms (spatial 4R): 250 x 400 cells over (rho, z) (the paper's
  100,000) in the x-z half plane.
r_max, z_min, z_max are the extent of 20,000 random configurations grown by
`margin` (5 %) of the span, so the border cells are out of reach: those have
branch count 0 and form their own cluster(s) with cluster_branches 0, which
teaches the classifier "out of reach". Tool-roll pose arms (7R): one
region, `region_grid`. Other pose arms need an explicit GridSpec.

Random locations (`random_locations`: tips of random configurations;
`region_locations`: uniform over a region grid and the tool directions) are
what the benches and the tests measure on.

Apart from the data set because the grids and locations are also the
benches' and the refinement's, with no data set in sight.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.smm.arms import SmmArm


DEFAULT_SHAPES = {1: (200,), 2: (250, 400)}
REGION_SHAPE = (3, 3, 24, 48)  # region_grid: (rho, z, polar, azimuth) cells of the 7R
# Which axes wrap around, by grid dimension: the 7R's azimuth (its first and last cells are neighbours).
PERIODIC = {1: (False,), 2: (False, False), 4: (False, False, False, True)}
REGION_REFINE_TILE = 4  # coarse cells per axis of a 7R refinement patch (smm/refine.py)


@dataclass(frozen=True)
class GridSpec:
    """A regular grid of cells over canonical coordinates: per dimension lo, hi and cell count.

    Cell centres are lo + (i + 1/2) (hi - lo) / count; cells are numbered in
    C order (the last dimension fastest), which is also the automaton's order.
    """

    lo: tuple[float, ...]
    hi: tuple[float, ...]
    shape: tuple[int, ...]

    def __post_init__(self) -> None:
        d = len(self.shape)
        if d == 0 or len(self.lo) != d or len(self.hi) != d:
            raise ArmbridgeError(f"grid: lo, hi and shape need one entry per dimension, got {self}")
        for i, (a, b, s) in enumerate(zip(self.lo, self.hi, self.shape)):
            if not (np.isfinite(a) and np.isfinite(b) and a < b):
                raise ArmbridgeError(f"grid dimension {i}: need finite lo < hi, got [{a}, {b}]")
            if not isinstance(s, (int, np.integer)) or s < 1:
                raise ArmbridgeError(f"grid dimension {i}: cell count must be an integer >= 1, got {s!r}")

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def centres(self) -> np.ndarray:
        """(L, d) cell centres in flat (C) order."""
        axes = [lo + (np.arange(s) + 0.5) * (hi - lo) / s for lo, hi, s in zip(self.lo, self.hi, self.shape)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(self.shape))


def default_grid(arm: SmmArm, shape: Sequence[int] | None = None, margin: float = 0.05, seed: int = 0) -> GridSpec:
    """The grid of the module docstring for a planar ('xy'), positioning ('xyz') or tool-roll pose arm."""
    if arm.c_dim == 4:
        return region_grid(arm, shape, seed=seed)
    if arm.c_dim not in DEFAULT_SHAPES:
        raise ArmbridgeError(f"robot {arm.name!r} has {arm.c_dim} canonical coordinates; pass an explicit GridSpec")
    if not 0 <= margin < 1:
        raise ArmbridgeError(f"grid margin must be a fraction in [0, 1), got {margin!r}")
    cells = tuple(int(s) for s in (shape or DEFAULT_SHAPES[arm.c_dim]))
    if len(cells) != arm.c_dim:
        raise ArmbridgeError(f"grid shape for {arm.name!r} needs {arm.c_dim} cell counts, got {shape!r}")
    q = np.random.default_rng(seed).uniform(-np.pi, np.pi, (20000, arm.n))
    c, _ = arm.canonical(arm.task(q))
    lo, hi = c.min(axis=0), c.max(axis=0)
    grow = margin * (hi - lo)
    lo, hi = lo - grow, hi + grow
    lo[0] = 0.0  # rho >= 0: the half plane of section V-B
    return GridSpec(tuple(float(v) for v in lo), tuple(float(v) for v in hi), cells)


def region_grid(arm: SmmArm, shape: Sequence[int] | None = None, half: float = 0.1, seed: int = 0) -> GridSpec:
    """A tool-roll pose arm's (7R) grid: a (rho, z) square of side 2 half around the median
    position of 20,000 random configurations, times every tool direction (polar [0, pi],
    azimuth [-pi, pi]); REGION_SHAPE cells by default.

    The paper grids about 10 % of the 7R's positions (80 x 160) times 12,000
    orientations, 1.5e8 SMMs; at about 90 ms per 7R location on one CPU
    thread that is beyond this machine, so the default is one small region.
    """
    if not arm.tool_roll:
        raise ArmbridgeError(f"robot {arm.name!r} is not a tool-roll pose arm; region_grid is for those (the 7R)")
    if not half > 0:
        raise ArmbridgeError(f"region half-size must be > 0 m, got {half!r}")
    cells = tuple(int(s) for s in (shape or REGION_SHAPE))
    if len(cells) != 4:
        raise ArmbridgeError(f"grid shape for {arm.name!r} needs 4 cell counts (rho, z, polar, azimuth), got {shape!r}")
    q = np.random.default_rng(seed).uniform(-np.pi, np.pi, (20000, arm.n))
    c, _ = arm.canonical(arm.task(q))
    rho, z = np.median(c[:, 0]), np.median(c[:, 1])
    return GridSpec((float(rho - half), float(z - half), 0.0, -np.pi), (float(rho + half), float(z + half), np.pi, np.pi),
                    cells)


def region_locations(grid: GridSpec, count: int, seed: int = 0) -> np.ndarray:
    """Canonical locations uniform over a region_grid's positions and over tool directions (the sphere)."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(grid.lo), np.asarray(grid.hi)
    pos = lo[:2] + rng.uniform(0, 1, (count, 2)) * (hi[:2] - lo[:2])
    return np.column_stack([pos, np.arccos(rng.uniform(-1, 1, count)), rng.uniform(-np.pi, np.pi, count)])


def random_locations(arm: SmmArm, count: int, seed: int = 0) -> np.ndarray:
    """Reachable task locations: the tips of uniformly random configurations."""
    q = np.random.default_rng(seed).uniform(-np.pi, np.pi, (count, arm.n))
    return np.asarray(arm.task(q))
