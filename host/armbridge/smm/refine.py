"""Local grid refinement of an SMM data set where its cells cannot be labelled.

Why: the section V pipeline learns a branch count only where a cluster of
cells with that count exists. On the spatial 4R the locations with three
branches lie in slivers 0.01-0.04 wide in rho (near rho = 3.6 for |z| < 0.6,
and near rho = 0.47, |z| = 1.1-1.3), against a 250 x 400 cell of 0.025 x
0.023; at sing_tol 0.02 every such cell is flagged singular, no cluster has
three branches, and every three-branch location comes out as two. A
uniformly finer grid costs the square of the factor everywhere; refining only
where the coarse grid fails costs a few per cent of it (adaptive mesh
refinement, one level).

1. Seeds (`unlabelled`): the grid cells, and the cells holding boundary
   points, whose label is -1: no cluster of their own nullspace branch count
   lies within automaton.nearest_cluster's reach, so the classifier has
   nothing to learn there.
2. Patches (`patches`): the seed cells grown by `pad` cells, split into
   connected pieces (8-neighbourhood in 2-D), each piece's bounding box
   (boxes that overlap are joined) gridded `factor` times finer per axis.
3. Each patch is a data set of its own, by the same pipeline (the caller's
   `assemble` and `add_boundary`), traced with sing_tol / sqrt(factor): the
   flagged band is about one cell wide when sing_tol ~ 0.5 sqrt(h / 2L)
   (armbridge.smm.nullspace), so the finer cell needs a finer flag, or the
   slivers would again be all singular.
4. `merge`: the coarse rows and boundary points inside a patch give way to
   the patch's, the patches' cluster ids follow the coarse ones, and clusters
   left without a row are dropped (ids renumbered in order; a label naming
   one becomes -1), so that every cluster with branches has regression rows
   and a regressor file.

The 7R (four canonical coordinates: rho, z, polar, azimuth; grid.region_grid)
takes the same steps with two changes (`seeds_for`, `patches`' tile and
per-axis factor), not a copy of them:
- Seeds: also every cell whose branch count differs from a face neighbour's
  (`disagree`; azimuth wraps around, grid.PERIODIC): on the 7R the count
  changes on a finer scale than a 7.5 degree cell of tool direction
  (docs/smm.md, "The 7R: one region"), and most such cells are labelled
  (nearest_cluster finds a cluster of their count nearby), so -1 labels alone
  would miss them.
- Patches: in 4-D the grown seeds touch one another nearly everywhere and
  one bounding box would be the whole grid; so each box is cut into tiles of
  at most `tile` coarse cells per axis and only the tiles holding a seed are
  refined, with a factor per axis (e.g. 1 x 1 x 3 x 3: finer in tool
  direction only). Patches are traced in order of how many seeds they hold,
  and with a `deadline` the ones not started by then are left out (the
  one-run GPU build watches its clock: scripts/smm7r_device.py).

The classifier is one network over all rows, so a patch only adds rows: a
cluster that runs across a patch's edge becomes two clusters with the same
count, which costs nothing in the branch count and keeps each regressor's
homotopy slots consistent (they are paired within one grid only).
"""
from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Union

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.smm.arms import SmmArm
from armbridge.smm.dataset import Build, SmmDataset
from armbridge.smm.grid import PERIODIC, GridSpec
from armbridge.smm.manifold import SmmSet

if TYPE_CHECKING:
    from armbridge.shards import Runner

Factor = Union[int, Sequence[int]]  # one refinement factor, or one per grid axis


@dataclass(frozen=True)
class Patch:
    """One refined box: its grid, the sing_tol it was traced with, and its own data set."""

    grid: GridSpec
    sing_tol: float
    dataset: SmmDataset


def cell_of(grid: GridSpec, canon: np.ndarray) -> np.ndarray:
    """Flat index of the grid cell holding each canonical location (P, d) (clamped to the grid)."""
    lo, hi, shape = np.asarray(grid.lo), np.asarray(grid.hi), np.asarray(grid.shape)
    at = np.floor((np.asarray(canon, dtype=np.float64) - lo) / (hi - lo) * shape).astype(np.int64)
    at = np.clip(at, 0, shape - 1)
    return np.ravel_multi_index(tuple(at.T), grid.shape) if at.size else np.zeros(0, dtype=np.int64)


def unlabelled(ds: SmmDataset, grid: GridSpec) -> np.ndarray:
    """Boolean mask over the grid's cells: the seeds of step 1 (ds's rows are the grid's cells in order)."""
    if ds.canon.shape[0] != grid.size:
        raise ArmbridgeError(f"data set has {ds.canon.shape[0]} rows for a grid of {grid.size} cells")
    mask = (ds.label < 0).copy()
    mask[cell_of(grid, ds.boundary_canon[ds.boundary_label < 0])] = True
    return mask.reshape(grid.shape)


def disagree(count: np.ndarray, periodic: Sequence[bool] | None = None) -> np.ndarray:
    """Boolean mask of the cells whose branch count differs from one of their 2d face neighbours'.

    count has the grid's shape; periodic[i]: axis i wraps around (the 7R's
    azimuth), so its first and last cells are neighbours.
    """
    c = np.asarray(count)
    wrap = tuple(periodic) if periodic is not None else (False,) * c.ndim
    if len(wrap) != c.ndim:
        raise ArmbridgeError(f"periodic needs one flag per grid axis ({c.ndim}), got {len(wrap)}")
    out = np.zeros(c.shape, dtype=bool)
    for axis in range(c.ndim):
        if c.shape[axis] < 2:
            continue
        nxt = np.roll(c, -1, axis)
        diff = c != nxt  # cell i against i + 1 (the last against the first: dropped unless periodic)
        if not wrap[axis]:
            diff[(slice(None),) * axis + (-1,)] = False
        out |= diff | np.roll(diff, 1, axis)
    return out


def seeds_for(arm: SmmArm, coarse: Build) -> np.ndarray:
    """Step 1 for this arm: unlabelled cells; on a 4-D (tool-roll, 7R) grid also the cells where
    neighbours disagree on the branch count (module doc)."""
    mask = unlabelled(coarse.dataset, coarse.grid)
    if len(coarse.grid.shape) == 4 and arm.tool_roll:
        mask |= disagree(coarse.smms.count.reshape(coarse.grid.shape), PERIODIC[4])
    return mask


def factors(grid: GridSpec, factor: Factor) -> tuple[int, ...]:
    """One refinement factor per grid axis, each an integer >= 1 and at least one >= 2."""
    if isinstance(factor, (int, np.integer)):
        if factor < 2:
            raise ArmbridgeError(f"refinement factor must be an integer >= 2, got {factor!r}")
        return (int(factor),) * len(grid.shape)
    try:
        out = tuple(factor)
    except TypeError:
        raise ArmbridgeError(f"refinement factor must be an integer >= 2, got {factor!r}") from None
    if len(out) != len(grid.shape) or not all(isinstance(f, (int, np.integer)) and f >= 1 for f in out) \
            or max(out) < 2:
        raise ArmbridgeError(f"refinement factor must be an integer >= 2 or {len(grid.shape)} integers >= 1 "
                             f"with one >= 2, got {factor!r}")
    return tuple(int(f) for f in out)


def _tiles(box: tuple[slice, ...], mask: np.ndarray, tile: int) -> list[tuple[slice, ...]]:
    """The tiles (at most `tile` cells per axis) of a box that hold a cell of mask."""
    ranges = [range(s.start, s.stop, tile) for s in box]
    out = []
    for corner in np.stack(np.meshgrid(*ranges, indexing="ij"), -1).reshape(-1, len(box)):
        t = tuple(slice(int(a), min(int(a) + tile, s.stop)) for a, s in zip(corner, box))
        if mask[t].any():
            out.append(t)
    return out


def _overlap(a: tuple[slice, ...], b: tuple[slice, ...]) -> bool:
    return all(x.start < y.stop and y.start < x.stop for x, y in zip(a, b))


def _join(a: tuple[slice, ...], b: tuple[slice, ...]) -> tuple[slice, ...]:
    return tuple(slice(min(x.start, y.start), max(x.stop, y.stop)) for x, y in zip(a, b))


def patches(grid: GridSpec, seeds: np.ndarray, factor: Factor, pad: int = 2, tile: int | None = None
            ) -> list[GridSpec]:
    """Step 2: the refined grids over the seed cells (mask of grid.shape), in order of their first cell.

    tile: cut every box into tiles of at most that many coarse cells per axis
    and keep the tiles that hold a seed (the 7R; module doc).
    """
    from scipy import ndimage  # type: ignore[import-untyped]

    per_axis = np.asarray(factors(grid, factor))
    if tile is not None and (not isinstance(tile, (int, np.integer)) or tile < 1):
        raise ArmbridgeError(f"refinement tile must be an integer >= 1 cells, got {tile!r}")
    if not isinstance(pad, (int, np.integer)) or pad < 0:
        raise ArmbridgeError(f"refinement pad must be an integer >= 0 cells, got {pad!r}")
    mask = np.asarray(seeds, dtype=bool)
    if mask.shape != grid.shape:
        raise ArmbridgeError(f"seed mask {mask.shape} does not match the grid's {grid.shape}")
    if not mask.any():
        return []
    full = np.ones((3,) * mask.ndim, bool)
    grown = ndimage.binary_dilation(mask, full, iterations=pad) if pad else mask
    boxes = [b for b in ndimage.find_objects(ndimage.label(grown, full)[0]) if b is not None]
    joined = True
    while joined:  # bounding boxes of separate pieces may still overlap
        joined = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                if _overlap(boxes[i], boxes[j]):
                    boxes[i] = _join(boxes[i], boxes.pop(j))
                    joined = True
                    break
            if joined:
                break
    if tile is not None:
        boxes = [t for b in boxes for t in _tiles(b, mask, int(tile))]
    lo, size = np.asarray(grid.lo), (np.asarray(grid.hi) - np.asarray(grid.lo)) / np.asarray(grid.shape)
    out = []
    for box in sorted(boxes, key=lambda b: tuple(s.start for s in b)):
        start = np.array([s.start for s in box])
        stop = np.array([s.stop for s in box])
        out.append(GridSpec(tuple(float(v) for v in lo + start * size), tuple(float(v) for v in lo + stop * size),
                            tuple(int(v) for v in (stop - start) * per_axis)))
    return out


def patch_sing_tol(sing_tol: float, factor: Factor) -> float:
    """Step 3's flag: sing_tol ~ sqrt(cell size), so a cell `factor` times smaller takes sing_tol / sqrt(factor)
    (per-axis factors: the largest, the finest axis)."""
    f = factor if isinstance(factor, (int, np.integer)) else max(factor)
    return float(sing_tol) / math.sqrt(f)


def inside(grids: list[GridSpec], canon: np.ndarray) -> np.ndarray:
    """(P,) whether each canonical location lies in one of the grids' boxes (lo <= c < hi)."""
    c = np.asarray(canon, dtype=np.float64)
    out = np.zeros(c.shape[0], dtype=bool)
    for g in grids:
        out |= np.all((c >= np.asarray(g.lo)) & (c < np.asarray(g.hi)), axis=1)
    return out


def _shift(ids: np.ndarray, by: int) -> np.ndarray:
    return np.where(ids >= 0, ids + by, -1)


def merge(coarse: SmmDataset, parts: list[Patch]) -> SmmDataset:
    """Step 4: one data set of the coarse rows outside every patch and the patches' rows."""
    if not parts:
        return coarse
    grids = [p.grid for p in parts]
    keep, bkeep = ~inside(grids, coarse.canon), ~inside(grids, coarse.boundary_canon)
    for p in parts:
        d = p.dataset
        if (d.robot, d.K, d.N, d.coeffs.shape[2]) != (coarse.robot, coarse.K, coarse.N, coarse.coeffs.shape[2]):
            raise ArmbridgeError(f"patch {p.grid}: data set for {d.robot!r} (K {d.K}, N {d.N}) does not match "
                                 f"the coarse one ({coarse.robot!r}, K {coarse.K}, N {coarse.N})")
    sets = [(coarse, keep, bkeep)] + [(p.dataset, np.ones(len(p.dataset.canon), bool),
                                       np.ones(len(p.dataset.boundary_canon), bool)) for p in parts]
    bmax = max(d.coeffs.shape[1] for d, _, _ in sets)
    cols: dict[str, list[np.ndarray]] = {k: [] for k in ("canon", "cluster", "label", "coeffs", "branches",
                                                         "bcanon", "blabel")}
    offset = 0
    for d, rows, brows in sets:
        c = d.coeffs[rows]
        pad = np.full(c.shape[:1] + (bmax - c.shape[1],) + c.shape[2:], np.nan, dtype=c.dtype)
        cols["canon"].append(d.canon[rows])
        cols["cluster"].append(_shift(d.cluster[rows], offset))
        cols["label"].append(_shift(d.label[rows], offset))
        cols["coeffs"].append(np.concatenate([c, pad], axis=1))
        cols["branches"].append(d.cluster_branches)
        cols["bcanon"].append(d.boundary_canon[brows])
        cols["blabel"].append(_shift(d.boundary_label[brows], offset))
        offset += d.cluster_branches.size
    cluster, label, blabel = (np.concatenate(cols[k]) for k in ("cluster", "label", "blabel"))
    branches = np.concatenate(cols["branches"])
    # kept: clusters with rows, and out-of-reach clusters (no regressor) some label still names
    has_rows = np.isin(np.arange(offset), cluster)
    named = np.isin(np.arange(offset), np.concatenate([label, blabel]))
    used = np.flatnonzero(has_rows | (named & (branches == 0)))
    new = np.full(offset, -1, dtype=np.int64)
    new[used] = np.arange(used.size)

    def renumber(ids: np.ndarray) -> np.ndarray:
        return np.where(ids >= 0, new[np.maximum(ids, 0)], -1)

    return SmmDataset(
        robot=coarse.robot,
        canon=np.concatenate(cols["canon"]),
        cluster=renumber(cluster),
        label=renumber(label),
        coeffs=np.concatenate(cols["coeffs"]),
        cluster_branches=branches[used],
        boundary_canon=np.concatenate(cols["bcanon"]),
        boundary_label=renumber(blabel),
        K=coarse.K,
        N=coarse.N,
    )


def refine(
    arm: SmmArm,
    coarse: Build,
    factor: Factor = 5,
    pad: int = 2,
    per_cell: int = 4,
    batch: int = 2048,
    runner: Runner | None = None,
    sing_tol: float = 0.02,
    seed: int = 0,
    exact_phase: bool = True,
    min_cells: int = 4,
    tile: int | None = None,
    deadline: float | None = None,
    **nullspace_options: Any,
) -> tuple[SmmDataset, list[Patch]]:
    """Steps 1-4 on a built coarse data set: (the merged data set, its patches).

    Each patch's SMMs are the sharded jobs "smm-patch-<i>" and
    "smm-patch-<i>-boundary" (armbridge.shards), traced with the coarse
    build's IK seed `seed` and patch_sing_tol(sing_tol, factor). Seeds:
    seeds_for (the 7R adds count disagreement). tile: patches' tiles. Patches
    run in order of their seed count, most first, as many together as fit in
    `batch` locations (one tracer call: the GPU's batch); deadline
    (time.monotonic()): no group starts after it, so the patches left out
    are those that matter least.
    """
    from armbridge.smm.dataset import add_boundary, assemble
    from armbridge.smm.trace import compute_smms

    ds = coarse.dataset
    tol = patch_sing_tol(sing_tol, factor)
    seeds = seeds_for(arm, coarse)
    grids = patches(coarse.grid, seeds, factor, pad, tile)
    held = [int(seeds[cells_of(coarse.grid, g)].sum()) for g in grids]
    order = sorted(range(len(grids)), key=lambda j: -held[j])
    parts = []
    while order:
        if deadline is not None and time.monotonic() > deadline:
            break
        # Patches traced together up to `batch` locations: one tracer call (a GPU's batch) for many small ones.
        group = [order.pop(0)]
        while order and sum(grids[j].size for j in group) + grids[order[0]].size <= batch:
            group.append(order.pop(0))
        centres = [grids[j].centres() for j in group]
        smms = compute_smms(arm, np.concatenate(centres), ds.N, batch, None, runner, f"smm-patch-{group[0]}",
                            seed=seed, sing_tol=tol, **nullspace_options)
        start = 0
        for j, c in zip(group, centres):
            g, rows = grids[j], slice(start, start + len(c))
            start += len(c)
            b = assemble(arm, g, SmmSet(smms.points[rows], smms.count[rows], smms.singular[rows]), ds.K,
                         exact_phase, min_cells)
            b = add_boundary(arm, b, per_cell, batch, None, seed=seed, runner=runner, job=f"smm-patch-{j}-boundary",
                             sing_tol=tol, **nullspace_options)
            parts.append(Patch(g, tol, b.dataset))
    return merge(ds, parts), parts


def cells_of(coarse: GridSpec, patch: GridSpec) -> tuple[slice, ...]:
    """The coarse grid's cells (index slices) a patch of it covers."""
    lo, hi = np.asarray(coarse.lo), np.asarray(coarse.hi)
    size = (hi - lo) / np.asarray(coarse.shape)
    a = np.rint((np.asarray(patch.lo) - lo) / size).astype(int)
    b = np.rint((np.asarray(patch.hi) - lo) / size).astype(int)
    return tuple(slice(int(x), int(y)) for x, y in zip(a, b))


def summary(parts: list[Patch]) -> list[dict[str, Any]]:
    """The card's record of the patches: box, cells, sing_tol, and the branch counts of their clusters."""
    out = []
    for p in parts:
        b = p.dataset.cluster_branches
        out.append({"lo": list(p.grid.lo), "hi": list(p.grid.hi), "shape": list(p.grid.shape), "sing_tol": p.sing_tol,
                    "clusters_by_branches": {str(int(k)): int(np.sum(b == k)) for k in np.unique(b)},
                    "boundary_points": int(p.dataset.boundary_label.size)})
    return out
