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

Poses are stored as (x, y, phi) with phi the MA's absolute heading
theta_hat_{j_d} as MasrArm.fk gives it, wrapped to [-pi, pi).
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from armbridge.errors import ArmbridgeError


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


def generate(arm: Any, spec: GridSpec = GridSpec(), fk: Callable[[np.ndarray], np.ndarray] | None = None,
             progress: Callable[[int, int, int], None] | None = None) -> MasrDataset:
    """Build the data set for `arm` (a MasrArm: link_lengths, theta_b, fk)."""
    fk = fk or arm.fk
    lengths = np.asarray(arm.link_lengths, dtype=float)
    n = lengths.size
    total = float(lengths.sum())
    tb = np.broadcast_to(np.asarray(arm.theta_b, dtype=float), (n,))
    rng = np.random.default_rng(spec.seed)
    occ = np.zeros((spec.ny, spec.nx), dtype=bool)
    kept: list[np.ndarray] = []
    samples = 0
    vacancy = spec.ny * spec.nx
    while samples < spec.max_samples:
        m = min(spec.batch, spec.max_samples - samples)
        q = np.concatenate([rng.uniform(-tb, tb, (m, n)), rng.uniform(0.0, total, (m, 1))], axis=1)
        samples += m
        x = np.asarray(fk(q), dtype=float)
        up = x[:, 1] >= 0
        x = x[up]
        ix = np.floor((x[:, 0] + total) / (2 * total) * spec.nx).astype(np.int64)
        iy = np.floor(x[:, 1] / total * spec.ny).astype(np.int64)
        ix = np.clip(ix, 0, spec.nx - 1)
        iy = np.clip(iy, 0, spec.ny - 1)
        cell = iy * spec.nx + ix
        # first sample of this batch in each cell, and only cells still empty
        uniq, first = np.unique(cell, return_index=True)
        new = ~occ.ravel()[uniq]
        take = first[new]
        occ.ravel()[uniq[new]] = True
        kept.append(x[np.sort(take)])
        vacancy = largest_enclosed_vacancy(occ)
        if progress:
            progress(samples, int(occ.sum()), vacancy)
        if vacancy <= spec.rho:
            break
    upper = np.concatenate(kept) if kept else np.zeros((0, 3))
    lower = upper * np.array([1.0, -1.0, -1.0])
    poses = np.concatenate([upper, lower]).astype(np.float32)
    return MasrDataset(poses, samples, vacancy, int(occ.sum()), spec, vacancy <= spec.rho)


def cache_key(arm: Any, spec: GridSpec) -> str:
    robot = {"name": str(arm.name), "link_lengths": np.asarray(arm.link_lengths, float).tolist(),
             "theta_b": np.broadcast_to(np.asarray(arm.theta_b, float), (np.size(arm.link_lengths),)).tolist()}
    blob = json.dumps({"robot": robot, "spec": asdict(spec), "v": 1}, sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def load_or_generate(arm: Any, spec: GridSpec, cache_dir: Path | None,
                     progress: Callable[[int, int, int], None] | None = None) -> tuple[MasrDataset, bool]:
    """The data set from cache_dir (a .npz keyed by robot and grid), or a fresh one (then cached)."""
    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / f"masr-dataset-{arm.name}-{cache_key(arm, spec)}.npz"
        if path.exists():
            z = np.load(path)
            info = json.loads(str(z["info"]))
            ds = MasrDataset(z["poses"], info["samples"], info["largest_enclosed_vacancy_cells"],
                             info["occupied_cells_w_plus"], spec, info["converged"])
            return ds, True
    ds = generate(arm, spec, progress=progress)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, poses=ds.poses, info=json.dumps(ds.info()))
        tmp.replace(path)
    return ds, False
