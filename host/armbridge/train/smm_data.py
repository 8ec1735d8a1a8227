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
from armbridge.smm.margin import MAX_CANDIDATES
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
                  runner: Runner | None = None, refine: int = 0, margin: int = 0
                  ) -> tuple[SmmDataset, dict[str, Any]]:
    """The data set at `path`, or a new one built over --grid and saved there; and its card entry.

    refine > 1: the grid is refined that many times per axis where its cells
    cannot be labelled (armbridge.smm.refine). margin > 0 (the 7R): that many
    classifier-only locations more, where a branch-count classifier trained on
    the grid is least sure (armbridge.smm.margin). The SMMs are traced in shards
    where `runner` says (armbridge.shards; None: here, serially), with one
    progress bar per sharded job; their checkpoints are deleted once the data
    set is saved.
    """
    from armbridge.shards import Runner
    from armbridge.smm import refine as rf
    from armbridge.smm.dataset import build_dataset
    from armbridge.smm.grid import REGION_REFINE_TILE

    if margin and not arm.tool_roll:
        raise ArmbridgeError(f"--margin samples the 7R's region (tool directions); robot {arm.name!r} has none")
    if margin * MARGIN_CANDIDATES > MAX_CANDIDATES:  # before the grid's hours, not after
        raise ArmbridgeError(f"--margin must be at most {MAX_CANDIDATES // MARGIN_CANDIDATES} (each location is picked "
                             f"from {MARGIN_CANDIDATES} candidates scored at once), got {margin}")
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
    margin_info: dict[str, Any] = {}
    if margin:
        ds, margin_info = add_margin(arm, ds, g, margin, seed, runner=runner, trace_batch=2048 * max(1, runner.workers),
                                     shard=2048, log=log, sing_tol=sing_tol)
    seconds = time.perf_counter() - t0
    path.parent.mkdir(parents=True, exist_ok=True)
    ds.save(path)
    jobs = ["smm-grid", "smm-boundary"] + [f"smm-patch-{i}{end}" for i in range(len(parts)) for end in ("", "-boundary")]
    jobs += margin_info.get("jobs", [])
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
    if margin:
        info["margin"] = {k: v for k, v in margin_info.items() if k != "jobs"}
    return ds, info


MARGIN_STEPS = 4000  # the quick classifier's optimiser steps: where it is unsure, not its best accuracy
MARGIN_BATCH = 1024
MARGIN_CANDIDATES = 20  # candidates scored per location traced


def add_margin(arm: SmmArm, ds: SmmDataset, g: GridSpec, n: int, seed: int = 0, *,
               hidden: tuple[int, ...] | None = None, steps: int = MARGIN_STEPS, batch: int = MARGIN_BATCH,
               candidates: int = MARGIN_CANDIDATES, deadline: float | None = None, classifier_device: Any = None,
               runner: Runner | None = None, trace_batch: int = 2048, shard: int | None = None,
               log: Log | None = None, **nullspace_options: Any) -> tuple[SmmDataset, dict[str, Any]]:
    """ds with up to n margin-sampled classifier-only locations (armbridge.smm.margin.grow), picked by
    a branch-count classifier (`hidden`, default the paper's) trained for about `steps` steps on ds's
    labelled rows; traced `trace_batch` a job in shards of `shard`, none started after `deadline`."""
    import math

    import torch

    from armbridge.smm import margin
    from armbridge.smm.grid import PERIODIC
    from armbridge.smm.networks import default_architecture
    from armbridge.train.smm_fit import SmmTrainConfig, fit_classifier

    t = time.perf_counter()
    canon, label = ds.classifier_data(np.arange(len(ds.canon)))
    if not len(canon):
        raise ArmbridgeError(f"--margin: the {g.shape} grid has no labelled cell to train its classifier on "
                             "(every cluster was too small); use a finer --grid")
    count = ds.cluster_branches[label]
    per_epoch = max(1, math.ceil(len(canon) / batch))
    cfg = SmmTrainConfig(hidden or default_architecture(arm.n).classifier, (1,), epochs=max(1, steps // per_epoch),
                         min_steps=0, batch=batch, seed=seed)
    if log:
        log(f"margin sampling: a branch-count classifier on {len(canon)} rows, then {n} of {candidates * n} "
            "candidates traced")
    dev = torch.device(classifier_device or "cpu")
    clf = fit_classifier(canon, count, int(count.max()) + 2, cfg, PERIODIC[4], dev).to(dev)
    trained_s = time.perf_counter() - t

    def logits(c: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return clf(torch.as_tensor(c, dtype=torch.float32, device=dev)).cpu().numpy()

    out, info = margin.grow(arm, ds, g, logits, n, candidates, deadline, trace_batch, seed + 1, runner, shard,
                            **nullspace_options)
    return out, {"classifier_steps": cfg.epochs * per_epoch, "classifier_seconds": round(trained_s, 1), **info,
                 "seconds": round(time.perf_counter() - t, 1)}
