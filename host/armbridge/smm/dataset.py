"""Training data for learned SMMs: grid -> SMMs -> clusters -> classes -> Fourier.

Pipeline of Clark and Xie, section V: a grid over canonical coordinates (the
joint-1 symmetry removed, `SmmArm.canonical`), ground-truth SMMs of each cell
centre by nullspace projection (with phi = 0), the cluster automaton (V-B),
the homotopy automaton (V-C), and the unique, low-passed Fourier spectrum of
every branch (IV, eq. 4-8) in its homotopy slot.

Default grids (`default_grid`, every size settable):
- 'xy' arms (planar 3R): 200 radial cells (the paper's 200) over [0, r_max];
- 'xyz' arms (spatial 4R): 250 x 400 cells over (rho, z) (the paper's
  100,000) in the x-z half plane.
r_max, z_min, z_max are the extent of 20,000 random configurations grown by
`margin` (5 %) of the span, so the border cells are out of reach: those have
branch count 0 and form their own cluster(s) with cluster_branches 0, which
teaches the classifier "out of reach". Tool-roll pose arms (7R): one
region, `region_grid`. Other pose arms need an explicit GridSpec.

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

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.smm import automaton, fourier
from armbridge.smm.arms import SmmArm
from armbridge.smm.manifold import SmmSet, concat

if TYPE_CHECKING:
    from armbridge.shards import Runner, Shard

Progress = Callable[[int, int], None]
DEFAULT_SHAPES = {1: (200,), 2: (250, 400)}
REGION_SHAPE = (3, 3, 24, 48)  # region_grid: (rho, z, polar, azimuth) cells of the 7R
# Cells a label may reach across (automaton.nearest_cluster): a singular band is a few cells wide,
# and 10 finds the cluster beyond it (3 left 1.4 % of the 4R's grid-cell labels at -1, 10 left 0.7 %).
LABEL_REACH = 10.0
FIELDS = ("robot", "canon", "cluster", "label", "coeffs", "cluster_branches", "boundary_canon", "boundary_label",
          "K", "N")


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


def compute_smms(
    arm: SmmArm,
    canon: np.ndarray,
    n_points: int = 128,
    batch: int = 2048,  # locations per nullspace call: larger batches amortise the per-step overhead
    progress: Progress | None = None,
    runner: Runner | None = None,
    job: str = "smm",
    **nullspace_options: Any,
) -> SmmSet:
    """Nullspace SMMs at canonical locations (no shift): trace_smms at arm.uncanonical(canon)."""
    x = np.asarray(arm.uncanonical(np.asarray(canon, dtype=np.float64)))
    return trace_smms(arm, x, n_points, batch, progress, runner, job, **nullspace_options)


def trace_smms(
    arm: SmmArm,
    x: np.ndarray,
    n_points: int = 128,
    batch: int = 2048,
    progress: Progress | None = None,
    runner: Runner | None = None,
    job: str = "smm",
    seconds: list[float] | None = None,
    **nullspace_options: Any,
) -> SmmSet:
    """Nullspace SMMs at task locations x, `batch` locations per call, one shard each.

    The shards (armbridge.shards) run where `runner` says (None: here, one
    after the other); each traces its locations with the same IK seed
    `seed` (a nullspace option), as the serial path always has, so the
    result does not depend on where or in which order the shards ran.
    progress(done, total) follows the shards in order; `seconds` gets each
    shard's nullspace time (a measurement, not part of the result).
    """
    from armbridge.shards import Job, Runner, Shard

    x = np.asarray(x, dtype=np.float64)
    options = dict(nullspace_options)
    seed = options.pop("seed", 0)
    if "device" in options and options["device"] is not None:
        options["device"] = str(options["device"])
    work = Job(job, smm_shard, {"arm": arm.to_dict(), "n_points": int(n_points), "options": options},
               gpu=options.get("device") is None)
    shards = [Shard(i, seed, {"start": s}, {"x": x[s : s + batch]}) for i, s in enumerate(range(0, len(x), batch))]
    done = 0

    def advance(shard: Shard, arrays: dict[str, np.ndarray]) -> None:
        nonlocal done
        done += len(arrays["count"])
        if seconds is not None:
            seconds.append(float(arrays["seconds"]))
        if progress is not None:
            progress(done, len(x))

    parts = (runner or Runner()).map(work, shards, on_result=advance, label=f"SMM {job}")
    return concat([SmmSet(p["points"], p["count"], p["singular"]) for p in parts], n_points, arm.n)


def smm_shard(params: Mapping[str, Any], shard: Shard) -> dict[str, np.ndarray]:
    """One shard of trace_smms: nullspace.compute on its locations, on one torch thread (the
    tracer's ops are small: a second thread only adds hand-offs, nullspace's docstring)."""
    import torch

    from armbridge.robots.dh import DHChain
    from armbridge.smm import nullspace

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    arm = DHChain.from_dict(params["arm"])
    try:
        t0 = time.perf_counter()
        s = nullspace.compute(arm, shard.inputs["x"], n_points=params["n_points"], seed=shard.seed, **params["options"])
        took = time.perf_counter() - t0
    finally:
        torch.set_num_threads(threads)
    return {"points": s.points, "count": s.count, "singular": s.singular, "seconds": np.asarray(took)}


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


def random_locations(arm: SmmArm, count: int, seed: int = 0) -> np.ndarray:
    """Reachable task locations: the tips of uniformly random configurations."""
    q = np.random.default_rng(seed).uniform(-np.pi, np.pi, (count, arm.n))
    return np.asarray(arm.task(q))


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

