"""Cellular automata over the workspace grid (Clark and Xie, section V-B/V-C).

The grid is any d-dimensional array of cells (1-D radial for the planar 3R,
2-D (rho, z) for the 4R). Cells are adjacent along one axis (von Neumann
neighbourhood: 2 d neighbours), so a one-cell-wide singular line separates.

First automaton (V-B): each cell starts with a unique state (its flat index)
and repeatedly takes the minimum state among itself and its neighbours, a
neighbour being an adjacent cell with the same branch count where neither
cell is singular. Converged states are the workspace clusters.

Second automaton (V-C): starting from each cluster's seed cell (the one whose
initial state was the cluster's minimum), unpaired cells pair their branches
with a paired neighbour's by the deformation matrix (eq. 11-13) and the
Hungarian algorithm (eq. 14), until every cell is paired. Branch slot b then
means one homotopy class throughout the cluster.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment  # type: ignore[import-untyped]

from armbridge.errors import ArmbridgeError
from armbridge.robots import wrap_angle

# Memory for one block of deformation matrices (P, B, B, N, N float64).
_BLOCK_BYTES = 256 * 2**20


@dataclass(frozen=True)
class Clusters:
    """Result of the first automaton over a grid of `shape`.

    label: (L,) cluster id 0..C-1 in order of the seed cells, -1 for singular cells.
    seed: (C,) flat index of each cluster's seed cell (its minimum initial state).
    branches: (C,) the branch count shared by the cells of each cluster.
    steps: automaton steps until convergence.
    """

    shape: tuple[int, ...]
    label: np.ndarray
    seed: np.ndarray
    branches: np.ndarray
    steps: int


def _links(count: np.ndarray, singular: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """Per axis, a mask of cells linked to their +1 neighbour along it."""
    links = []
    for axis in range(count.ndim):
        lo = [slice(None)] * count.ndim
        hi = [slice(None)] * count.ndim
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        ok = (count[tuple(lo)] == count[tuple(hi)]) & ~singular[tuple(lo)] & ~singular[tuple(hi)]
        links.append((axis, ok))
    return links


def _neighbour_min(state: np.ndarray, links: list[tuple[int, np.ndarray]]) -> np.ndarray:
    """One automaton step: min over self and linked neighbours, all cells at once."""
    new = state.copy()
    big = np.iinfo(state.dtype).max
    for axis, ok in links:
        lo = [slice(None)] * state.ndim
        hi = [slice(None)] * state.ndim
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        lo_t, hi_t = tuple(lo), tuple(hi)
        np.minimum(new[lo_t], np.where(ok, state[hi_t], big), out=new[lo_t])
        np.minimum(new[hi_t], np.where(ok, state[lo_t], big), out=new[hi_t])
    return new


def _grid(count: np.ndarray, singular: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = np.asarray(count)
    s = np.asarray(singular)
    if c.ndim < 1 or c.shape != s.shape or c.size == 0:
        raise ArmbridgeError(f"count and singular must be grids of one shape, got {c.shape} and {s.shape}")
    if not np.issubdtype(c.dtype, np.integer) or np.any(c < 0):
        raise ArmbridgeError("count must hold non-negative integer branch counts")
    return c.astype(np.int64), s.astype(bool)


def cluster(count: np.ndarray, singular: np.ndarray, max_steps: int | None = None) -> Clusters:
    """Section V-B: cluster a grid of cells by branch count, singular cells separating.

    count, singular: arrays of the grid's shape. Cells out of reach (count 0)
    form clusters of their own like any other count.
    """
    c, s = _grid(count, singular)
    links = _links(c, s)
    state = np.arange(c.size, dtype=np.int64).reshape(c.shape)
    limit = c.size if max_steps is None else max_steps  # c.size steps always suffice
    steps = 0
    while True:
        new = _neighbour_min(state, links)
        if np.array_equal(new, state):
            break
        if steps == limit:
            raise ArmbridgeError(f"the cluster automaton did not converge in max_steps={limit} steps")
        state, steps = new, steps + 1
    flat = state.ravel()
    seeds = np.unique(flat[~s.ravel()])  # sorted: cluster ids follow their seeds
    label = np.where(s.ravel(), -1, np.searchsorted(seeds, flat))
    return Clusters(c.shape, label.astype(np.int64), seeds, c.ravel()[seeds], steps)


def drop_small(clusters: Clusters, min_cells: int) -> Clusters:
    """Mark the cells of clusters with fewer than min_cells cells -1, like singular cells.

    On a fine 4R grid, thin bands between close singular curves break into
    one- or two-cell clusters where flagged cells interrupt them (about 20 of
    38 clusters on 120 x 200 cells); no regressor can be trained on those.
    The remaining clusters keep their order, seeds and branch counts.
    """
    if not isinstance(min_cells, (int, np.integer)) or min_cells < 1:
        raise ArmbridgeError(f"min_cells must be an integer >= 1, got {min_cells!r}")
    sizes = np.bincount(clusters.label[clusters.label >= 0], minlength=len(clusters.seed))
    keep = sizes >= min_cells
    new_id = np.where(keep, np.cumsum(keep) - 1, -1)
    label = np.where(clusters.label >= 0, new_id[np.maximum(clusters.label, 0)], -1)
    return Clusters(clusters.shape, label, clusters.seed[keep], clusters.branches[keep], clusters.steps)


def circle_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Eq. (13): Euclidean norm of the joint differences on the circle group."""
    return np.sqrt(np.sum(wrap_angle(a - b) ** 2, axis=-1))


def deformation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Eq. (11)-(12): deformation matrices between two sets of branches.

    a (..., Ba, N, n), b (..., Bb, N, n) -> D (..., Ba, Bb): D[i, j] is the
    mean over the samples of branch a_i of the distance (eq. 13) to the
    nearest sample of branch b_j. NaN branches give NaN entries.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    d2 = np.zeros(a.shape[:-1][:-2] + (a.shape[-3], b.shape[-3], a.shape[-2], b.shape[-2]))
    for k in range(a.shape[-1]):  # joint by joint keeps the (.., N, N) block the largest array
        diff = a[..., :, None, :, None, k] - b[..., None, :, None, :, k]
        d2 += wrap_angle(diff) ** 2
    return np.sqrt(d2.min(axis=-1)).mean(axis=-1)


def pair(D: np.ndarray) -> tuple[np.ndarray, float]:
    """Eq. (14): the column permutation minimising tr(D P) (Hungarian algorithm).

    Returns perm with branch perm[i] of the second location paired with
    branch i of the first, and the total deformation of the pairing.
    """
    D = np.asarray(D, dtype=np.float64)
    if D.ndim != 2 or D.shape[0] != D.shape[1] or not np.isfinite(D).all():
        raise ArmbridgeError(f"deformation matrix must be square and finite, got shape {D.shape}")
    rows, cols = linear_sum_assignment(D)
    return cols[np.argsort(rows)], float(D[rows, cols].sum())


@dataclass(frozen=True)
class Homotopy:
    """Result of the second automaton.

    order: (L, Bmax) for each cell, the original branch index in each slot
      (slot b = homotopy class b of the cell's cluster), -1 past the count
      and for singular cells.
    parent: (L,) the flat index of the cell it was paired with, itself for
      seeds, -1 for singular cells.
    cost: (L,) mean deformation per branch of that pairing (0 for seeds).
    steps: automaton steps until every cell was paired.
    """

    order: np.ndarray
    parent: np.ndarray
    cost: np.ndarray
    steps: int


def homotopy(clusters: Clusters, points: np.ndarray, count: np.ndarray) -> Homotopy:
    """Section V-C: order every cell's branches by homotopy class of its cluster.

    points (L, Bmax, N, n) NaN-padded branches of the L cells in flat grid
    order, count (L,). A cell's state is 1 once paired; seeds start at 1.
    Each step pairs every unpaired cell that has a paired neighbour of its
    cluster (the first such along axis order, - then + direction) with that
    neighbour's ordered branches.
    """
    L = int(np.prod(clusters.shape))
    pts = np.asarray(points, dtype=np.float64)
    cnt = np.asarray(count, dtype=np.int64).reshape(-1)
    if pts.ndim != 4 or pts.shape[0] != L or cnt.shape != (L,):
        raise ArmbridgeError(f"points must be ({L}, Bmax, N, n) and count ({L},), got {pts.shape}, {cnt.shape}")
    label = clusters.label
    # (a grid whose clusters were all dropped as too small has no branches to index: no cell is clustered)
    if clusters.branches.size and np.any((label >= 0) & (cnt != clusters.branches[np.maximum(label, 0)])):
        raise ArmbridgeError("every clustered cell's branch count must equal its cluster's")
    Bmax = pts.shape[1]
    slots = np.arange(Bmax)
    order = np.where((slots < cnt[:, None]) & (label >= 0)[:, None], slots, -1)
    parent = np.full(L, -1, dtype=np.int64)
    parent[clusters.seed] = clusters.seed
    cost = np.zeros(L)
    done = label < 0
    done[clusters.seed] = True
    # the order in which neighbours are offered: axis by axis, - then +
    label_grid = label.reshape(clusters.shape)
    index_grid = np.arange(L).reshape(clusters.shape)
    offsets = [(axis, step) for axis in range(label_grid.ndim) for step in (-1, 1)]
    steps = 0
    while not done.all():
        frontier_parent = np.full(L, -1, dtype=np.int64)
        for axis, step in offsets:
            nb = _shifted(index_grid, axis, step).ravel()
            ok = (nb >= 0) & ~done & (frontier_parent < 0)
            ok[ok] = done[nb[ok]] & (label[nb[ok]] == label[ok]) & (label[ok] >= 0)
            frontier_parent[ok] = nb[ok]
        cells = np.flatnonzero(frontier_parent >= 0)
        if cells.size == 0:
            raise ArmbridgeError("homotopy automaton stalled: a cluster has cells unreachable from its seed")
        _pair_cells(cells, frontier_parent[cells], pts, cnt, order, cost)
        parent[cells] = frontier_parent[cells]
        done[cells] = True
        steps += 1
    return Homotopy(order, parent, cost, steps)


def _shifted(index_grid: np.ndarray, axis: int, step: int) -> np.ndarray:
    """Flat index of each cell's neighbour at `step` along `axis`, -1 off the grid."""
    out = np.full_like(index_grid, -1)
    src = [slice(None)] * index_grid.ndim
    dst = [slice(None)] * index_grid.ndim
    if step < 0:
        dst[axis], src[axis] = slice(1, None), slice(0, -1)
    else:
        dst[axis], src[axis] = slice(0, -1), slice(1, None)
    out[tuple(dst)] = index_grid[tuple(src)]
    return out


def _pair_cells(
    cells: np.ndarray, parents: np.ndarray, pts: np.ndarray, cnt: np.ndarray, order: np.ndarray, cost: np.ndarray
) -> None:
    """Pair `cells` with their paired `parents` in blocks, writing order and cost in place."""
    for B in np.unique(cnt[cells]):
        if B <= 1:
            continue  # 0 or 1 branch: nothing to order
        sel = cells[cnt[cells] == B]
        par = parents[cnt[cells] == B]
        N = pts.shape[2]
        block = max(1, _BLOCK_BYTES // (8 * 2 * B * B * N * N))
        for s in range(0, sel.size, block):
            c, p = sel[s : s + block], par[s : s + block]
            ordered = np.take_along_axis(pts[p, :B], order[p, :B, None, None], axis=1)
            D = deformation(ordered, pts[c, :B])
            for i, cell in enumerate(c):
                perm, total = pair(D[i])
                order[cell, :B] = perm
                cost[cell] = total / B


def cell_indices(shape: tuple[int, ...]) -> np.ndarray:
    """(L, d) index of every cell of a grid of `shape`, in flat (C) order."""
    return np.indices(shape).reshape(len(shape), -1).T


def nearest_cluster(clusters: Clusters, cells: np.ndarray, count: np.ndarray, reach: float) -> np.ndarray:
    """Classifier labels for points of the grid by their nullspace branch counts.

    cells (P, d): positions in cell units (cell i's centre at i, so a grid
    cell is its own index and a point inside one is fractional); count (P,).
    Each point takes the nearest cell of a cluster with its own branch count,
    within `reach` cells (Euclidean), and -1 if there is none. A clustered
    cell so keeps its cluster. Why: singular cells separate clusters but are
    left out of them, and in a 4R's singular band the count flips between 1,
    2 and 3 within a cell (9.5 % of random 4R locations fall in the band).
    Labelled with the neighbouring cluster of the same count, those cells
    teach the classifier where the count changes instead of leaving it to
    guess across the band.
    """
    from scipy.spatial import cKDTree  # type: ignore[import-untyped]

    pts, cnt = np.asarray(cells, dtype=np.float64), np.asarray(count)
    if pts.ndim != 2 or pts.shape[1] != len(clusters.shape) or cnt.shape != pts.shape[:1]:
        raise ArmbridgeError(f"cells {pts.shape} and count {cnt.shape} must be (P, {len(clusters.shape)}) and (P,)")
    if not reach >= 0:
        raise ArmbridgeError(f"reach must be >= 0 cells, got {reach!r}")
    grid = cell_indices(clusters.shape)
    out = np.full(cnt.shape, -1, dtype=np.int64)
    if not clusters.branches.size:  # no cluster (all dropped as too small): nothing to label with
        return out
    cell_count = np.where(clusters.label >= 0, clusters.branches[np.maximum(clusters.label, 0)], -1)
    for b in np.unique(cnt):
        src = np.flatnonzero(cell_count == b)
        if src.size == 0:
            continue
        sel = np.flatnonzero(cnt == b)
        dist, i = cKDTree(grid[src]).query(pts[sel], distance_upper_bound=reach)
        ok = np.isfinite(dist)
        out[sel[ok]] = clusters.label[src[i[ok]]]
    return out
