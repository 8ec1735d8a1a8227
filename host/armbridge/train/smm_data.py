"""The data stage of `armbridge train smm-*`: the data set, checked, and its held-out rows.

The data set is loaded from --dataset or built over --grid
(smm/dataset.build_dataset, its SMMs traced in shards where the runner says)
and saved there (`load_or_build`); it must be for the robot trained
(`check_dataset`). Held-out locations (a share of each cluster, at least one
location of every cluster kept for training: `split`) are never trained on
and give the card's accuracy.

Apart from the training (train/smm_fit.py) and the pipeline (train/smm.py)
because it needs no torch: it is the nullspace SMMs, the grid and the shards.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.smm.arms import SmmArm
from armbridge.smm.dataset import SmmDataset
from armbridge.smm.grid import GridSpec
from armbridge.train.smm_fit import Log

if TYPE_CHECKING:
    from armbridge.shards import Runner


def split(label: np.ndarray, holdout: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) row indices: `holdout` of each cluster's locations held out, >= 1 kept for training.

    By the classifier's label (SmmDataset.label); rows labelled -1 are in neither.
    """
    rng = np.random.default_rng([seed, 7])
    train, test = [], []
    for c in np.unique(label[label >= 0]):
        rows = rng.permutation(np.flatnonzero(label == c))
        k = min(round(holdout * rows.size), rows.size - 1)
        test.append(rows[:k])
        train.append(rows[k:])
    if not train:
        raise ArmbridgeError("the data set has no labelled locations (every label is -1)")
    return np.sort(np.concatenate(train)), np.sort(np.concatenate(test))


def check_dataset(ds: SmmDataset, arm: SmmArm) -> None:
    """The data set is for this robot (SmmDataset checks its own fields' shapes)."""
    if ds.robot != arm.name:
        raise ArmbridgeError(f"data set is for robot {ds.robot!r}, training {arm.name!r}")
    if ds.coeffs.shape[2] != arm.n or ds.canon.shape[1] != arm.c_dim:
        raise ArmbridgeError(f"data set: coeffs {ds.coeffs.shape} and canon {ds.canon.shape} do not fit {arm.name!r} "
                             f"(n = {arm.n}, {arm.c_dim} canonical coordinates)")


def grid_for(arm: SmmArm, text: str) -> GridSpec:
    """dataset.GridSpec for --grid: '' (the data-set module's default), '200' or '250x400' cells."""
    from armbridge.smm.grid import default_grid

    if arm.c_dim > 2 and not arm.tool_roll:
        raise ArmbridgeError(f"robot {arm.name!r}: the CLI cannot build its grid ({arm.c_dim} canonical coordinates); "
                             "pass --dataset with an existing .npz")
    if not text:
        return default_grid(arm)
    try:
        shape = tuple(int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ArmbridgeError(f"--grid must be cell counts like 200 or 250x400, got {text!r}") from None
    return default_grid(arm, shape)


def load_or_build(arm: SmmArm, path: Path, grid: str, K: int, N: int, seed: int, progress: bool,
                  log: Log | None, per_cell: int = 4, sing_tol: float = 0.02,
                  runner: Runner | None = None, refine: int = 0) -> tuple[SmmDataset, dict[str, Any]]:
    """The data set at `path`, or a new one built over --grid and saved there; and its card entry.

    refine > 1: the grid is refined that many times per axis where its cells
    cannot be labelled (armbridge.smm.refine). The SMMs are traced in shards
    where `runner` says (armbridge.shards; None: here, serially), with one
    progress bar per sharded job; their checkpoints are deleted once the data
    set is saved.
    """
    from armbridge.shards import Runner
    from armbridge.smm import refine as rf
    from armbridge.smm.dataset import build_dataset
    from armbridge.smm.grid import REGION_REFINE_TILE

    if path.exists():
        if log:
            log(f"data set: {path}")
        return SmmDataset.load(path), {"built": "loaded from an existing file"}
    g = grid_for(arm, grid)
    t0 = time.perf_counter()
    runner = runner or Runner(progress=progress)
    build = build_dataset(arm, g, K=K, N=N, seed=seed, per_cell=per_cell, sing_tol=sing_tol, runner=runner)
    ds, parts = build.dataset, list[rf.Patch]()
    if refine:
        # The 7R: finer in tool direction only, in tiles of a few coarse cells (smm/refine.py's module doc).
        factor: rf.Factor = (1, 1, refine, refine) if arm.tool_roll else refine
        tile = REGION_REFINE_TILE if arm.tool_roll else None
        ds, parts = rf.refine(arm, build, factor, per_cell=per_cell, runner=runner, sing_tol=sing_tol, seed=seed,
                              tile=tile)
    seconds = time.perf_counter() - t0
    path.parent.mkdir(parents=True, exist_ok=True)
    ds.save(path)
    jobs = ["smm-grid", "smm-boundary"] + [f"smm-patch-{i}{end}" for i in range(len(parts)) for end in ("", "-boundary")]
    for job in jobs:  # the data set holds what their shards did
        runner.discard(job)
    if log:
        log(f"data set: {g.size} cells + {sum(p.grid.size for p in parts)} in {len(parts)} refined patches, "
            f"{len(ds.canon)} rows in {seconds:.1f} s -> {path}")
    info = {"built": "armbridge.smm.dataset.build_dataset", "grid_lo": list(g.lo), "grid_hi": list(g.hi),
            "grid_shape": list(g.shape), "boundary_points_per_cell": per_cell, "sing_tol": sing_tol,
            "seconds": round(seconds, 1), "seed": seed, "shards": runner.backend}
    if refine:
        info["refine"] = {"factor": list(factor) if not isinstance(factor, int) else factor, "tile": tile,
                          "how": "armbridge.smm.refine", "patches": rf.summary(parts)}
    return ds, info
