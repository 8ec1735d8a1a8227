"""Margin sampling: trace next where the classifier is least sure of the branch count.

Why: on the 7R the branch count changes on a finer scale than the region's
grid, so almost every cell has a neighbour of another count (`refine.disagree`
flagged 9,574 of the 3 x 3 x 24 x 48 cells, 92 %, in a scratch count; the
device script reports it for its grid), and refining where neighbours disagree is
refining nearly everywhere. A classifier trained on what is traced so far
says where it is unsure; tracing there puts the tracer's time where the
count changes, as active learning's margin sampling does. Measured by
`armbridge bench smm-data` (docs/smm.md, "How much data the 7R needs"): on
held-out uniform locations, 11,000 uniform plus 11,000 margin-sampled came
to 24.7 % branch-count mismatch against 25.6 % for 22,000 uniform; a gain,
but a small one beside what more data buys.

1. `least_certain`: of many untraced candidates, the ones whose two likeliest
   classes are closest. The classifier predicts the branch count itself
   (train.smm_fit.fit_classifier), since two clusters of one count are no
   uncertainty about the count.
2. `pick` scores candidates uniform over the region and picks the least
   sure; `grow` traces them in batches until a deadline and `add_points`
   joins them to the data set.
3. `add_points`: the picked points, their counts traced, join the data set
   as classifier-only points (the data set's boundary points): each takes
   the cluster of the nearest labelled row with its own count, within
   `reach` coarse cells (azimuth wrapping around), else -1 (left out of
   training, as an unlabelled boundary point is).
"""
from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.smm.arms import SmmArm
from armbridge.smm.dataset import LABEL_REACH, SmmDataset
from armbridge.smm.grid import PERIODIC, GridSpec, region_locations

if TYPE_CHECKING:
    from armbridge.shards import Runner

MAX_CANDIDATES = 4_000_000  # scored at once: 128 MB of locations and their float64 probabilities besides


def least_certain(logits: np.ndarray, k: int) -> np.ndarray:
    """Indices of the k rows of (M, C) class logits whose two likeliest classes are closest."""
    z = np.asarray(logits, dtype=np.float64)
    if z.ndim != 2 or z.shape[1] < 2:
        raise ArmbridgeError(f"logits must be (rows, classes >= 2), got shape {z.shape}")
    if not 0 <= k <= len(z):
        raise ArmbridgeError(f"can pick 0 to {len(z)} rows, asked for {k}")
    p = np.exp(z - z.max(axis=1, keepdims=True))
    p /= p.sum(axis=1, keepdims=True)
    top = np.sort(p, axis=1)[:, -2:]
    return np.argsort(top[:, 1] - top[:, 0], kind="stable")[:k]


def nearest_labels(ds: SmmDataset, grid: GridSpec, canon: np.ndarray, count: np.ndarray, reach: float,
                   periodic: Sequence[bool]) -> np.ndarray:
    """Cluster labels of points by their traced counts: the nearest labelled row's (grid rows and
    boundary points) of the same count, within `reach` cells of `grid`, else -1."""
    from scipy.spatial import cKDTree  # type: ignore[import-untyped]

    lo, hi, shape = np.asarray(grid.lo), np.asarray(grid.hi), np.asarray(grid.shape, dtype=float)
    size = (hi - lo) / shape
    # cell units; a periodic axis is a torus of shape[i] cells (cKDTree's boxsize), the others unbounded
    box = np.where(np.asarray(periodic, bool), shape, 1e9)

    def units(c: np.ndarray) -> np.ndarray:
        u = (np.asarray(c, dtype=np.float64) - lo) / size
        m = np.mod(u, shape)
        m = np.where(m >= shape, m - shape, m)  # mod of a tiny negative rounds up to shape itself
        return np.where(np.asarray(periodic, bool), m, u + 5e8)

    rows_c = np.concatenate([ds.canon, ds.boundary_canon])
    rows_l = np.concatenate([ds.label, ds.boundary_label])
    known = rows_l >= 0
    rows_c, rows_l = rows_c[known], rows_l[known]
    rows_n = ds.cluster_branches[rows_l]
    out = np.full(len(canon), -1, dtype=np.int64)
    at = units(canon)
    for b in np.unique(count):
        mine, have = np.flatnonzero(count == b), rows_n == b
        if not have.any():
            continue
        dist, j = cKDTree(units(rows_c[have]), boxsize=box).query(at[mine], distance_upper_bound=reach)
        hit = np.isfinite(dist)
        out[mine[hit]] = rows_l[have][j[hit]]
    return out


def add_points(ds: SmmDataset, grid: GridSpec, canon: np.ndarray, count: np.ndarray, reach: float,
               periodic: Sequence[bool]) -> SmmDataset:
    """ds with traced points joined as classifier-only (boundary) points, labelled by nearest_labels."""
    canon = np.asarray(canon, dtype=np.float64)
    if canon.ndim != 2 or canon.shape[1] != ds.canon.shape[1] or len(count) != len(canon):
        raise ArmbridgeError(f"points {canon.shape} and counts {np.shape(count)} do not fit the data set's "
                             f"{ds.canon.shape[1]} canonical coordinates")
    label = nearest_labels(ds, grid, canon, np.asarray(count), reach, periodic)
    return replace(ds, boundary_canon=np.concatenate([ds.boundary_canon, canon]),
                   boundary_label=np.concatenate([ds.boundary_label, label]))


def pick(grid: GridSpec, logits: Callable[[np.ndarray], np.ndarray], n: int, candidates: int, seed: int = 1
         ) -> np.ndarray:
    """The n of `candidates` x n untraced locations uniform over a region grid (grid.region_locations)
    where logits(canon) -> (M, classes) is least sure (least_certain), scored 65,536 at a time."""
    if n < 0 or candidates < 1:
        raise ArmbridgeError(f"n >= 0 and candidates >= 1, got {n} and {candidates}")
    if candidates * n > MAX_CANDIDATES:
        raise ArmbridgeError(f"margin sampling of {n} locations scores {candidates * n} candidates; at most "
                             f"{MAX_CANDIDATES} at once (n <= {MAX_CANDIDATES // candidates})")
    cand = region_locations(grid, candidates * n, seed=seed)
    if not n:
        return cand
    scores = np.concatenate([logits(c) for c in np.array_split(cand, max(1, len(cand) // 65536))])
    return cand[least_certain(scores, n)]


def grow(arm: SmmArm, ds: SmmDataset, grid: GridSpec, logits: Callable[[np.ndarray], np.ndarray], n: int,
         candidates: int, deadline: float | None, batch: int, seed: int = 1, runner: Runner | None = None,
         shard: int | None = None, **nullspace_options: Any) -> tuple[SmmDataset, dict[str, Any]]:
    """ds with up to n margin-sampled points of a 7R region grid (add_points, LABEL_REACH cells).

    logits(canon) -> (M, classes): the caller's branch-count classifier (trained on ds, e.g. by
    train.smm_fit.fit_classifier). The n that `pick` picks are
    traced (smm.trace.trace_smms, counts only: jobs "smm-margin-<i>" of `batch` locations in
    shards of `shard`, where `runner` says), no batch started after `deadline`
    (time.monotonic()); what was traced joins. Returns (the data set, what was done).
    """
    from armbridge.smm.trace import trace_smms

    if batch < 1:
        raise ArmbridgeError(f"batch must be >= 1, got {batch}")
    picked = pick(grid, logits, n, candidates, seed)
    done_c, done_n, jobs = [picked[:0]], [np.zeros(0, np.int64)], []
    for i, start in enumerate(range(0, len(picked), batch)):
        if deadline is not None and time.monotonic() > deadline:
            break
        c = picked[start : start + batch]
        jobs.append(f"smm-margin-{i}")
        s = trace_smms(arm, np.asarray(arm.uncanonical(c)), 16, shard or batch, runner=runner, job=jobs[-1], seed=seed,
                       **nullspace_options)
        done_c.append(c)
        done_n.append(s.count)
    c, count = np.concatenate(done_c), np.concatenate(done_n)
    out = add_points(ds, grid, c, count, LABEL_REACH, PERIODIC[len(grid.shape)])
    labelled = int((out.boundary_label[len(ds.boundary_label):] >= 0).sum())
    return out, {"candidates": candidates * n, "planned": int(n), "traced": int(len(c)), "labelled": labelled,
                 "count_histogram": {str(int(b)): int(np.sum(count == b)) for b in np.unique(count)}, "jobs": jobs}
