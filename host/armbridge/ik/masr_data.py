"""The IK-NN data set of MA poses (masr paper, section III-B).

An occupancy grid B covers the upper half workspace W+ (y >= 0) of the MA
position. Random configurations are sampled in batches; a pose whose position
falls into an empty cell marks it and joins the data set, one into an occupied
cell is dropped. Sampling stops when no vacancy enclosed by occupied cells is
larger than rho cells. The set is then mirrored into W- (y -> -y, phi -> -phi).

Density check: the empty cells are labelled into 4-connected components
(scipy.ndimage.label) on the grid stacked with its mirror image, so that the
y = 0 edge is interior (W+ and W- meet there) and only the outer edges of the
grid, which lie outside the workspace, count as outside. A component that
touches the outer edge is outside the workspace; every other one is an
enclosed vacancy. The check runs after every batch.

The random configurations come in batches of `batch`, batch k from
Generator([seed, k]) (so each batch can be drawn anywhere: shards, below).

Poses are stored as (x, y, phi) with phi the MA's absolute heading
theta_hat_{j_d} as MasrArm.fk gives it, wrapped to [-pi, pi).
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from armbridge.errors import ArmbridgeError

if TYPE_CHECKING:
    from armbridge.shards import Runner

JOB = "masr-dataset"  # the sharded job's name: its checkpoint folder below --checkpoint


@dataclass(frozen=True)
class GridSpec:
    """Occupancy grid over W+: nx cells across x in [-l, l], ny cells across y in [0, l]."""

    nx: int = 1800
    ny: int = 1600
    rho: int = 10
    batch: int = 100_000
    max_samples: int = 20_000_000
    seed: int = 0

    @staticmethod
    def parse(text: str) -> tuple[int, int]:
        """'1800x1600' -> (1800, 1600)."""
        try:
            a, b = text.lower().split("x")
            nx, ny = int(a), int(b)
        except ValueError:
            raise ArmbridgeError(f"grid must look like 1800x1600, got {text!r}") from None
        if nx < 4 or ny < 2:
            raise ArmbridgeError(f"grid must be at least 4x2 cells, got {text!r}")
        return nx, ny


@dataclass
class MasrDataset:
    poses: np.ndarray  # (N, 3) float32, W+ then its mirror
    samples: int  # random configurations drawn
    largest_vacancy: int  # cells, at stop
    occupied: int  # cells of B marked in W+
    spec: GridSpec
    converged: bool  # density reached before max_samples

    def info(self) -> dict[str, Any]:
        return {
            "size": int(self.poses.shape[0]),
            "samples": int(self.samples),
            "occupied_cells_w_plus": int(self.occupied),
            "largest_enclosed_vacancy_cells": int(self.largest_vacancy),
            "converged": bool(self.converged),
            "grid": f"{self.spec.nx}x{self.spec.ny}",
            "rho": self.spec.rho,
            "batch": self.spec.batch,
            "seed": self.spec.seed,
        }


def largest_enclosed_vacancy(occ: np.ndarray) -> int:
    """Largest 4-connected group of empty cells of occ (ny, nx) over W+ that is enclosed.

    The grid is stacked with its mirror (row 0 is y = 0) so that vacancies on
    the x axis are judged as a whole; groups touching the outer edge are outside.
    """
    from scipy import ndimage  # type: ignore[import-untyped]

    full = np.concatenate([occ[::-1], occ], axis=0)
    labels, count = ndimage.label(~full)
    if count == 0:
        return 0
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    # count each group's cells in W+ only (the stacked mirror holds the same again)
    sizes = np.bincount(labels[occ.shape[0]:].ravel(), minlength=count + 1)
    sizes[0] = 0
    sizes[border] = 0
    return int(sizes.max())


def sample_shard(params: Mapping[str, Any], shard: Any) -> dict[str, np.ndarray]:
    """Batch shard.id of the sampling: its configurations from Generator([seed, batch]), their
    poses, and of the poses in W+ the first in each grid cell: cell (flat index, ascending),
    first (index among the batch's W+ poses), pose (float32, the data set's precision).

    Independent of every other batch, so the batches are shards (armbridge.shards)
    that may run anywhere; `generate` merges them in order.
    """
    from armbridge.robots.masr import MasrArm

    arm = MasrArm.from_dict(params["arm"])
    nx, ny = params["nx"], params["ny"]
    lengths = np.asarray(arm.link_lengths, dtype=float)
    n = lengths.size
    total = float(lengths.sum())
    tb = np.broadcast_to(np.asarray(arm.theta_b, dtype=float), (n,))
    rng = np.random.default_rng(shard.seed)
    m = int(shard.params["size"])
    q = np.concatenate([rng.uniform(-tb, tb, (m, n)), rng.uniform(0.0, total, (m, 1))], axis=1)
    x = np.asarray(arm.fk(q), dtype=float)
    x = x[x[:, 1] >= 0]
    ix = np.clip(np.floor((x[:, 0] + total) / (2 * total) * nx).astype(np.int64), 0, nx - 1)
    iy = np.clip(np.floor(x[:, 1] / total * ny).astype(np.int64), 0, ny - 1)
    cell, first = np.unique(iy * nx + ix, return_index=True)
    return {"cell": cell, "first": first, "pose": x[first].astype(np.float32)}


def generate(arm: Any, spec: GridSpec = GridSpec(), progress: Callable[[int, int, int], None] | None = None,
             runner: Runner | None = None) -> MasrDataset:
    """Build the data set for `arm` (a MasrArm).

    Batch k (spec.batch configurations, the last one shorter to end at
    spec.max_samples) draws from Generator([spec.seed, k]); its sampling is a
    shard (sample_shard) run where `runner` says (None: here, one after the
    other). The shards are merged in batch order: a batch's pose joins the
    set when its cell is still empty, and the vacancy check after every
    batch stops the job at the same batch whatever ran where.
    """
    from armbridge.shards import Job, Runner, Shard

    occ = np.zeros((spec.ny, spec.nx), dtype=bool)
    flat = occ.ravel()
    kept: list[np.ndarray] = []
    samples = 0
    vacancy = spec.ny * spec.nx
    sizes = [min(spec.batch, spec.max_samples - s) for s in range(0, spec.max_samples, spec.batch)]
    job = Job(JOB, sample_shard, {"arm": arm.to_dict(), "nx": spec.nx, "ny": spec.ny})
    shards = [Shard(k, [spec.seed, k], {"size": m}) for k, m in enumerate(sizes)]

    def merge(shard: Shard, part: dict[str, np.ndarray]) -> bool:
        nonlocal samples, vacancy
        samples += int(shard.params["size"])
        cell, first, pose = part["cell"], part["first"], part["pose"]
        new = ~flat[cell]
        flat[cell[new]] = True
        kept.append(pose[new][np.argsort(first[new])])
        vacancy = largest_enclosed_vacancy(occ)
        if progress:
            progress(samples, int(occ.sum()), vacancy)
        return vacancy <= spec.rho

    (runner or Runner()).map(job, shards, stop=merge, label="IK-NN data")
    upper = np.concatenate(kept) if kept else np.zeros((0, 3), dtype=np.float32)
    lower = upper * np.array([1.0, -1.0, -1.0], dtype=np.float32)
    poses = np.concatenate([upper, lower]).astype(np.float32)
    return MasrDataset(poses, samples, vacancy, int(occ.sum()), spec, vacancy <= spec.rho)


def cache_key(arm: Any, spec: GridSpec) -> str:
    robot = {"name": str(arm.name), "link_lengths": np.asarray(arm.link_lengths, float).tolist(),
             "theta_b": np.broadcast_to(np.asarray(arm.theta_b, float), (np.size(arm.link_lengths),)).tolist()}
    blob = json.dumps({"robot": robot, "spec": asdict(spec), "v": 2}, sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def load_or_generate(arm: Any, spec: GridSpec, cache_dir: Path | None,
                     progress: Callable[[int, int, int], None] | None = None,
                     runner: Runner | None = None) -> tuple[MasrDataset, bool]:
    """The data set from cache_dir (a .npz keyed by robot and grid), or a fresh one (then cached).

    Once cached, the runner's shard checkpoints of the data set are deleted (the cache holds it all).
    (v 2 of the key: batch k from Generator([seed, k]); v 1 drew every batch from one stream.)
    """
    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / f"masr-dataset-{arm.name}-{cache_key(arm, spec)}.npz"
        if path.exists():
            z = np.load(path, allow_pickle=False)
            info = json.loads(str(z["info"]))
            ds = MasrDataset(z["poses"], info["samples"], info["largest_enclosed_vacancy_cells"],
                             info["occupied_cells_w_plus"], spec, info["converged"])
            return ds, True
    ds = generate(arm, spec, progress=progress, runner=runner)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, allow_pickle=False, poses=ds.poses, info=json.dumps(ds.info()))
        tmp.replace(path)
        if runner is not None:
            runner.discard(JOB)
    return ds, False
