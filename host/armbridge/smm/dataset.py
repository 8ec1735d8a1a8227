"""Training data for learned SMMs: grid -> SMMs -> clusters -> classes -> Fourier.

Pipeline of Clark and Xie, section V: a grid over canonical coordinates (the
joint-1 symmetry removed, `SmmArm.canonical`), ground-truth SMMs of each cell
centre by nullspace projection (with phi = 0), the cluster automaton (V-B),
the homotopy automaton (V-C), and the unique, low-passed Fourier spectrum of
every branch (IV, eq. 4-8) in its homotopy slot.

The grids (GridSpec, `default_grid`, `region_grid`) are smm/grid.py's, the
ground-truth SMMs traced in shards (`compute_smms`) smm/trace.py's; this
module holds the data set itself (`SmmDataset`, its .npz file) and the steps
that turn the SMMs into it (`assemble`, `add_boundary`, `build_dataset`).

The classifier learns from more than the clusters: every cell, singular ones
included, is labelled by `automaton.nearest_cluster` from its own branch
count, and `per_cell` extra random points inside every boundary cell (one
within a cell of a cell outside the clusters or of a count change:
`boundary_cells`) are traced for their branch count and labelled the same
way. On the 4R the count flips within a cell across the singular band, and
the nearest grid cell's count differs from a random location's 2.1 % of the
time (Table III's 2.16 %); the boundary points sample it finer.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.smm import automaton, fourier
from armbridge.smm.arms import SmmArm
from armbridge.smm.grid import GridSpec, default_grid, random_locations
from armbridge.smm.manifold import SmmSet
from armbridge.smm.trace import Progress, compute_smms

if TYPE_CHECKING:
    from armbridge.shards import Runner

# Cells a label may reach across (automaton.nearest_cluster): a singular band is a few cells wide,
# and 10 finds the cluster beyond it (3 left 1.4 % of the 4R's grid-cell labels at -1, 10 left 0.7 %).
LABEL_REACH = 10.0
FIELDS = ("robot", "canon", "cluster", "label", "coeffs", "cluster_branches", "boundary_canon", "boundary_label",
          "K", "N")


@dataclass(frozen=True)
class SmmDataset:
    """The data set of the contract, saved as one .npz.

    canon (L, c_dim) cell centres; cluster (L,) id, -1 = singular boundary
    (no regression targets); label (L,) the classifier's target (the
    cluster, or automaton.nearest_cluster for cells outside them; -1 = none);
    coeffs (L, Bmax, n, K) complex128, slot b = homotopy class b of the
    cell's cluster, NaN past its count and for singular cells;
    cluster_branches (C,) (0 = out of reach); boundary_canon (E, c_dim) and
    boundary_label (E,): classifier-only points inside boundary cells; K kept
    components of N samples.
    """

    robot: str
    canon: np.ndarray
    cluster: np.ndarray
    label: np.ndarray
    coeffs: np.ndarray
    cluster_branches: np.ndarray
    boundary_canon: np.ndarray
    boundary_label: np.ndarray
    K: int
    N: int

    def __post_init__(self) -> None:
        L = self.canon.shape[0]
        if (self.canon.ndim != 2 or self.cluster.shape != (L,) or self.label.shape != (L,) or self.coeffs.ndim != 4
                or self.coeffs.shape[0] != L):
            raise ArmbridgeError(
                f"SmmDataset: canon {self.canon.shape}, cluster {self.cluster.shape}, label {self.label.shape} and "
                f"coeffs {self.coeffs.shape} must be (L, c_dim), (L,), (L,), (L, Bmax, n, K)"
            )
        E = self.boundary_canon.shape[0]
        if self.boundary_canon.shape != (E, self.canon.shape[1]) or self.boundary_label.shape != (E,):
            raise ArmbridgeError(f"SmmDataset: boundary_canon {self.boundary_canon.shape} and boundary_label "
                                 f"{self.boundary_label.shape} must be (E, {self.canon.shape[1]}) and (E,)")
        if self.coeffs.shape[-1] != self.K or not 1 <= self.K <= self.N:
            raise ArmbridgeError(
                f"SmmDataset: coeffs have {self.coeffs.shape[-1]} components, K = {self.K}, N = {self.N}"
            )
        for name in ("cluster", "label", "boundary_label"):
            ids = getattr(self, name)
            if ids.max(initial=-1) >= self.cluster_branches.size:
                raise ArmbridgeError(f"SmmDataset: {name} ids reach {ids.max()} of {self.cluster_branches.size}")

    def classifier_data(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(canon, label) the classifier trains on: the grid rows `rows` and every boundary point, labelled ones only."""
        canon = np.concatenate([self.canon[rows], self.boundary_canon])
        label = np.concatenate([self.label[rows], self.boundary_label])
        return canon[label >= 0], label[label >= 0]

    def save(self, path: str | Path) -> None:
        """Write the fields of FIELDS to a compressed .npz (no pickles): NaN slots shrink to little."""
        arrays: dict[str, Any] = {f: np.asarray(getattr(self, f)) for f in FIELDS}
        np.savez_compressed(Path(path), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> SmmDataset:
        p = Path(path)
        try:
            with np.load(p, allow_pickle=False) as z:
                missing = [f for f in FIELDS if f not in z.files]
                if missing:
                    raise ArmbridgeError(f"{p}: not an SMM data set, missing {', '.join(missing)}")
                return cls(
                    robot=str(z["robot"]),
                    canon=z["canon"].astype(np.float64),
                    cluster=z["cluster"].astype(np.int64),
                    label=z["label"].astype(np.int64),
                    coeffs=z["coeffs"].astype(np.complex128),
                    cluster_branches=z["cluster_branches"].astype(np.int64),
                    boundary_canon=z["boundary_canon"].astype(np.float64),
                    boundary_label=z["boundary_label"].astype(np.int64),
                    K=int(z["K"]),
                    N=int(z["N"]),
                )
        except (OSError, ValueError) as e:
            raise ArmbridgeError(f"{p}: cannot read SMM data set ({e})") from e


@dataclass(frozen=True)
class Build:
    """What build_dataset made, with the intermediate results for checks and plots."""

    dataset: SmmDataset
    grid: GridSpec
    smms: SmmSet
    clusters: automaton.Clusters
    homotopy: automaton.Homotopy
    reference: np.ndarray  # (2, C, Bmax) phase-rule (joint, freq) per cluster and slot
    margin: np.ndarray  # (C, Bmax) its smallest |Theta| / N in the cluster (NaN: no branch)


def harmonics(smms: SmmSet, label: np.ndarray, order: np.ndarray) -> np.ndarray:
    """(L, Bmax, n, 2) fourier.first_harmonics of every branch in homotopy order, NaN where none."""
    L, bmax, _, n = smms.points.shape
    out = np.full((L, bmax, n, 2), np.nan)
    cells, slots = np.nonzero((order >= 0) & (label >= 0)[:, None])
    for s in range(0, cells.size, 8192):
        c, b = cells[s : s + 8192], slots[s : s + 8192]
        out[c, b] = fourier.first_harmonics(smms.points[c, order[c, b]])
    return out


def reference_components(mags: np.ndarray, label: np.ndarray, n_clusters: int) -> tuple[np.ndarray, np.ndarray]:
    """Phase reference per (cluster, slot): the (joint, freq) whose first harmonic stays largest.

    The paper's reference, joint 1 at f = +1 (eq. 4), vanishes on branches
    along which joint 1 turns backwards (the tracer's +null vector direction
    makes one of the two 4R branches near the base axis do so), and then its
    phase, hence the start, is noise. Over the cells of one cluster the
    branches of one slot deform continuously, so a component whose magnitude
    stays away from 0 there gives a start that moves continuously, and
    continuous regression targets. Returns reference (2, C, Bmax) int64,
    (joint, freq) per slot, and margin (C, Bmax), the chosen component's
    smallest |Theta| / N over the cluster (NaN for empty slots).
    """
    ok = label >= 0
    C, bmax, n = n_clusters, mags.shape[1], mags.shape[2]
    low = np.full((C, bmax, n, 2), np.inf)
    np.fmin.at(low, label[ok], np.nan_to_num(mags[ok], nan=np.inf))
    flat = low.reshape(C, bmax, 2 * n)
    best = np.argmax(np.where(np.isfinite(flat), flat, -1.0), axis=-1)
    margin = np.take_along_axis(flat, best[..., None], axis=-1)[..., 0]
    return np.stack([best // 2, np.where(best % 2 == 0, 1, -1)]), np.where(np.isfinite(margin), margin, np.nan)


def coefficients(
    smms: SmmSet,
    label: np.ndarray,
    order: np.ndarray,
    K: int,
    reference: np.ndarray | None = None,
    exact_phase: bool = True,
) -> np.ndarray:
    """(L, Bmax, n, K) low-passed unique spectra in homotopy order, NaN where no branch.

    reference (2, C, Bmax): (joint, freq) of the phase rule per cluster and
    slot (reference_components); None is the paper's joint 1, f = +1.
    """
    L, bmax, _, n = smms.points.shape
    out = np.full((L, bmax, n, K), np.nan + 0j)
    cells, slots = np.nonzero((order >= 0) & (label >= 0)[:, None])
    for s in range(0, cells.size, 4096):  # full spectra are N/K times the output: encode in blocks
        c, b = cells[s : s + 4096], slots[s : s + 4096]
        joint, freq = (0, 1) if reference is None else reference[:, label[c], b]
        spectra = fourier.encode(smms.points[c, order[c, b]], exact_phase, joint, freq)
        out[c, b] = fourier.lowpass(spectra, K)
    return out


def build_dataset(
    arm: SmmArm,
    grid: GridSpec | None = None,
    K: int = 40,
    N: int = 128,
    batch: int = 2048,  # locations per nullspace call: larger batches amortise the per-step overhead
    progress: Progress | None = None,
    exact_phase: bool = True,
    min_cells: int = 4,
    per_cell: int = 4,
    runner: Runner | None = None,
    **nullspace_options: Any,
) -> Build:
    """Section V pipeline for `arm` over `grid` (default_grid if None).

    nullspace_options go to armbridge.smm.nullspace.compute (seeds, step,
    device, seed). progress(done, total) is called after every batch of SMMs,
    first of the grid, then of the boundary points. The rest is `assemble`
    and `add_boundary` (per_cell points in each boundary cell; 0 adds none).
    The SMMs are two sharded jobs, "smm-grid" and "smm-boundary", run by
    `runner` (compute_smms); the rest is cheap and runs here.
    """
    g = grid or default_grid(arm)
    _check(arm, g, K, N)
    smms = compute_smms(arm, g.centres(), N, batch, progress, runner, "smm-grid", **nullspace_options)
    build = assemble(arm, g, smms, K, exact_phase, min_cells)
    return add_boundary(arm, build, per_cell, batch, progress, runner=runner, **nullspace_options)


def boundary_cells(clusters: automaton.Clusters, count: np.ndarray) -> np.ndarray:
    """Flat indices of the cells within one cell (3^d block) of a cell outside every cluster or of a count change.

    Both sides of a boundary, so the points sample it evenly: with only the
    cells next to the change, the 3R's fold at r = 1 got 6 points of count 2
    for 2 of count 1, and the 2 x 5 classifier moved its boundary past r = 1.
    """
    from scipy import ndimage  # type: ignore[import-untyped]

    c = np.asarray(count).reshape(clusters.shape)
    edge = ndimage.maximum_filter(c, size=3, mode="nearest") != ndimage.minimum_filter(c, size=3, mode="nearest")
    edge |= clusters.label.reshape(clusters.shape) < 0
    return np.flatnonzero(ndimage.binary_dilation(edge, np.ones((3,) * c.ndim, bool)).ravel())


def add_boundary(
    arm: SmmArm,
    build: Build,
    per_cell: int = 4,
    batch: int = 2048,
    progress: Progress | None = None,
    seed: int = 0,
    runner: Runner | None = None,
    job: str = "smm-boundary",
    **nullspace_options: Any,
) -> Build:
    """`build` with per_cell uniform random points in every boundary cell as classifier-only samples.

    Each point's branch count comes from the nullspace method (its branches
    are not kept) and its label from automaton.nearest_cluster. `job`: the
    name of the sharded job that traces them.
    """
    if not isinstance(per_cell, (int, np.integer)) or per_cell < 0:
        raise ArmbridgeError(f"per_cell (boundary points per cell) must be an integer >= 0, got {per_cell!r}")
    g = build.grid
    cells = boundary_cells(build.clusters, build.smms.count)
    size = (np.asarray(g.hi) - np.asarray(g.lo)) / np.asarray(g.shape)
    offset = np.random.default_rng([seed, 1]).uniform(-0.5, 0.5, (cells.size * per_cell, len(g.shape)))
    at = np.repeat(automaton.cell_indices(g.shape)[cells], per_cell, axis=0) + offset
    canon = np.asarray(g.lo) + (at + 0.5) * size
    count = compute_smms(arm, canon, 16, batch, progress, runner, job, seed=seed, **nullspace_options).count
    label = automaton.nearest_cluster(build.clusters, at, count, LABEL_REACH)
    return replace(build, dataset=replace(build.dataset, boundary_canon=canon, boundary_label=label))


def assemble(
    arm: SmmArm, grid: GridSpec, smms: SmmSet, K: int = 40, exact_phase: bool = True, min_cells: int = 4
) -> Build:
    """Clusters, homotopy order and Fourier coefficients from the grid's SMMs (computed once, reusable).

    exact_phase (fourier.encode's exact): True by default because the
    paper's integer shift leaves up to one sample of start jitter between
    tracings of one loop (measured up to 0.13 rad per point, 4.6 % of the
    coefficients on random 3R/4R locations), against <= 3e-4 rad with the
    fractional shift; that jitter would be noise in the regression targets.
    The phase reference is chosen per cluster and slot (reference_components).
    Clusters of fewer than min_cells cells become -1 (automaton.drop_small).
    """
    N = smms.points.shape[2]
    _check(arm, grid, K, N)
    if len(smms) != grid.size:
        raise ArmbridgeError(f"SMMs of {len(smms)} locations for a grid of {grid.size} cells")
    cl = automaton.drop_small(automaton.cluster(smms.count.reshape(grid.shape), smms.singular.reshape(grid.shape)),
                              min_cells)
    hom = automaton.homotopy(cl, smms.points, smms.count)
    reference, margin = reference_components(harmonics(smms, cl.label, hom.order), cl.label, len(cl.seed))
    coeffs = coefficients(smms, cl.label, hom.order, int(K), reference, exact_phase)
    ds = SmmDataset(
        robot=arm.name,
        canon=grid.centres(),
        cluster=cl.label,
        label=automaton.nearest_cluster(cl, automaton.cell_indices(grid.shape), smms.count, LABEL_REACH),
        coeffs=coeffs[:, : max(int(cl.branches.max(initial=0)), 1)],  # Bmax of the kept clusters
        cluster_branches=cl.branches,
        boundary_canon=np.zeros((0, len(grid.shape))),
        boundary_label=np.zeros(0, dtype=np.int64),
        K=int(K),
        N=int(N),
    )
    return Build(ds, grid, smms, cl, hom, reference, margin)


def _check(arm: SmmArm, grid: GridSpec, K: int, N: int) -> None:
    if len(grid.shape) != arm.c_dim:
        raise ArmbridgeError(
            f"grid has {len(grid.shape)} dimensions, robot {arm.name!r} has {arm.c_dim} canonical ones"
        )
    if not isinstance(K, (int, np.integer)) or not 1 <= K <= N:
        raise ArmbridgeError(f"K (Fourier components kept) must be an integer in 1..N={N}, got {K!r}")


def fig3(
    arm: SmmArm,
    Ks: Sequence[int] = (10, 20, 40, 90),
    locations: int = 100,
    N: int = 128,
    seed: int = 0,
    **nullspace_options: Any,
) -> np.ndarray:
    """Fig. 3: mean absolute joint error (rad) of K-term spectra over the SMMs of random locations."""
    from armbridge.smm import nullspace

    smms = nullspace.compute(arm, random_locations(arm, locations, seed), n_points=N, **nullspace_options)
    mask = np.arange(smms.points.shape[1]) < smms.count[:, None]
    if not mask.any():
        raise ArmbridgeError(f"no SMM branches found at {locations} random locations of {arm.name!r}")
    return fourier.lowpass_error(smms.points[mask], Ks)

