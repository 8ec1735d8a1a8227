"""The learned-SMM pipeline: data set -> classifier and per-cluster regressors
-> ONNX -> measured accuracy on held-out locations -> card.

Used by `armbridge train smm-3r|smm-4r|smm-7r`. Training follows section VI-A
(LeakyReLU MLPs, AdamW, lr 1e-3 for the classifier and 3e-3 for the
regressors, losses (15)-(17)); the learning rate decays by a cosine to
lr * lr_decay over each network's steps (the paper does not say; a decay
lowers the final regression error, lr_decay = 1 keeps it constant).

Every network trains for `epochs` passes over its training locations, and at
least `min_steps` steps, so a cluster with few locations is not left
under-trained. Held-out locations (a share of each cluster, at least one
location of every cluster kept for training) are never trained on and give
the card's accuracy. Deterministic for a seed: each network's initial weights
come from torch.manual_seed(seed + 1000 * net), its batches from
numpy Generator([seed, net, epoch]); a checkpoint written at epoch boundaries
lets --resume continue to the same result.

Files in the output folder: classifier.onnx, regressor-<c>.onnx for every
cluster c with branches, card.json. One regressor file per cluster because
inference runs each regressor only on the locations classified into its
cluster; one graph holding them all would run every regressor on every
location (or need control flow in the graph).
"""
from __future__ import annotations

import hashlib
import json
import math
import platform
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from armbridge.errors import ArmbridgeError
from armbridge.smm import networks as nets
from armbridge.smm.arms import SmmArm, get_smm_arm
from armbridge.smm.dataset import GridSpec, SmmDataset
from armbridge.smm.learned import CARD_NAME, CARD_VERSION, KIND, LearnedSmm
from armbridge.smm.manifold import SmmSet

if TYPE_CHECKING:
    from armbridge.shards import Runner

Log = Callable[[str], None]
ROBOTS = {"smm-3r": "planar3r", "smm-4r": "spatial4r", "smm-7r": "spatial7r"}
CHECKPOINT_SECONDS = 60.0  # write the checkpoint at the first epoch end after this long


@dataclass
class SmmTrainConfig:
    """Settings of one training run (all recorded in the card)."""

    cls_hidden: tuple[int, ...]
    reg_hidden: tuple[int, ...]
    epochs: int = 200
    min_steps: int = 2000
    batch: int = 256
    cls_lr: float = 1e-3
    reg_lr: float = 3e-3
    lr_decay: float = 0.01
    weight_decay: float = 0.01  # AdamW's default
    holdout: float = 0.1
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("epochs", "batch"):
            if getattr(self, name) < 1:
                raise ArmbridgeError(f"--{name} must be >= 1, got {getattr(self, name)}")
        if self.min_steps < 0:
            raise ArmbridgeError(f"--min-steps must be >= 0, got {self.min_steps}")
        if not 0 < self.lr_decay <= 1:
            raise ArmbridgeError(f"--lr-decay must be in (0, 1], got {self.lr_decay}")
        if self.cls_lr <= 0 or self.reg_lr <= 0 or self.weight_decay < 0:
            raise ArmbridgeError("learning rates must be > 0 and the weight decay >= 0")
        if not 0 <= self.holdout < 1:
            raise ArmbridgeError(f"--holdout must be in [0, 1), got {self.holdout}")
        if not self.cls_hidden or not self.reg_hidden or min(self.cls_hidden + self.reg_hidden) < 1:
            raise ArmbridgeError("hidden layer sizes must be positive")


@dataclass
class Trained:
    """The trained networks, their loss histories, steps and seconds."""

    classifier: nets.SmmClassifier
    regressors: dict[int, nets.SmmRegressor]
    history: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    steps: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0


def parse_sizes(text: str, option: str) -> tuple[int, ...]:
    """'150,150,150' or '4x150' -> (150, 150, 150, 150)."""
    try:
        if "x" in text:
            count, width = text.lower().split("x")
            sizes = (int(width),) * int(count)
        else:
            sizes = tuple(int(s) for s in text.split(",") if s.strip())
    except ValueError:
        raise ArmbridgeError(f"{option} must be sizes like 150,150 or 4x150, got {text!r}") from None
    if not sizes or min(sizes) < 1:
        raise ArmbridgeError(f"{option} needs positive layer sizes, got {text!r}")
    return sizes


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


def cluster_targets(ds: SmmDataset, c: int, rows: np.ndarray) -> np.ndarray:
    """Regressor targets (M, B_c*n*K*2) of cluster c at the given rows (eq. 17's y)."""
    b = int(ds.cluster_branches[c])
    coeffs = ds.coeffs[rows, :b]
    if not np.isfinite(coeffs).all():
        raise ArmbridgeError(f"data set: cluster {c} has NaN coefficients within its {b} branches")
    return nets.coeffs_to_target(coeffs)


def lr_at(peak: float, decay: float, step: int, total: int) -> float:
    """Cosine from peak to peak * decay over `total` steps."""
    frac = min(1.0, step / max(1, total))
    return peak * (decay + (1 - decay) * 0.5 * (1 + math.cos(math.pi * frac)))


def steps_for(cfg: SmmTrainConfig, rows: int) -> tuple[int, int]:
    """(epochs, steps per epoch) of a network with `rows` training locations."""
    per_epoch = max(1, math.ceil(rows / cfg.batch))
    return max(cfg.epochs, math.ceil(cfg.min_steps / per_epoch)), per_epoch


@dataclass
class _Job:
    """One network to train: its key, module, inputs, targets, loss and lr."""

    key: str
    index: int
    model: torch.nn.Module
    inputs: torch.Tensor
    targets: torch.Tensor
    loss: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
    lr: float

    def predict(self, x: torch.Tensor) -> torch.Tensor:
        m = self.model
        return m.normalised(x) if isinstance(m, nets.SmmRegressor) else m(x)


def _jobs(ds: SmmDataset, rows: np.ndarray, cfg: SmmTrainConfig, device: torch.device) -> list[_Job]:
    """The classifier and a regressor per cluster with branches, initialised from the seed."""
    canon, labels = ds.classifier_data(rows)
    lo, hi = nets.input_box(np.asarray(ds.canon[ds.cluster >= 0]))
    torch.manual_seed(cfg.seed)
    clf = nets.SmmClassifier(lo, hi, cfg.cls_hidden, int(ds.cluster_branches.size)).to(device)
    jobs = [_Job("classifier", 0, clf, torch.as_tensor(canon, dtype=torch.float32, device=device),
                 torch.as_tensor(labels, device=device), nets.classifier_loss, cfg.cls_lr)]
    x_all = torch.as_tensor(np.asarray(ds.canon[rows], dtype=np.float64), dtype=torch.float32, device=device)
    for c in np.flatnonzero(ds.cluster_branches > 0):
        mine = ds.cluster[rows] == c  # regression targets exist in the cluster's own cells only
        if not mine.any():
            continue
        y = cluster_targets(ds, int(c), rows[mine])
        mean, scale = nets.output_scaling(y)
        torch.manual_seed(cfg.seed + 1000 * (int(c) + 1))
        reg = nets.SmmRegressor(lo, hi, cfg.reg_hidden, mean, scale).to(device)
        yt = reg.normalise(torch.as_tensor(y, dtype=torch.float32, device=device))
        jobs.append(_Job(f"regressor-{c}", int(c) + 1, reg, x_all[torch.as_tensor(mine, device=device)], yt,
                         nets.regressor_loss, cfg.reg_lr))
    return jobs


def _progress_bar(label: str, after: str | None = None) -> Any:
    """A started rich progress bar: label, bar, done/total, [after], elapsed, remaining."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    extra = [TextColumn(after)] if after else []
    bar = Progress(TextColumn(label), BarColumn(), MofNCompleteColumn(), *extra, TimeElapsedColumn(),
                   TimeRemainingColumn())
    bar.start()
    return bar


def _save(obj: Any, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(obj, tmp)
    tmp.replace(path)


def _fit(job: _Job, cfg: SmmTrainConfig, state: dict[str, Any], advance: Callable[[int, float], None],
         save: Callable[[], None]) -> None:
    """Train one network from `state` (epoch, step, optimiser), updating `state` in place."""
    epochs, per_epoch = steps_for(cfg, job.inputs.shape[0])
    total = epochs * per_epoch
    opt = torch.optim.AdamW(job.model.parameters(), lr=job.lr, weight_decay=cfg.weight_decay)
    if state.get("optimizer"):
        opt.load_state_dict(state["optimizer"])
    last_save = time.perf_counter()
    job.model.train()
    for epoch in range(state.get("epoch", 0), epochs):
        t_epoch = time.perf_counter()
        perm = torch.as_tensor(np.random.default_rng([cfg.seed, job.index, epoch]).permutation(job.inputs.shape[0]),
                               device=job.inputs.device)
        total_loss = 0.0
        for b in range(per_epoch):
            idx = perm[b * cfg.batch : (b + 1) * cfg.batch]
            for g in opt.param_groups:
                g["lr"] = lr_at(job.lr, cfg.lr_decay, state.get("step", 0), total)
            loss = job.loss(job.predict(job.inputs[idx]), job.targets[idx])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            state["step"] = state.get("step", 0) + 1
            total_loss += float(loss.detach())
            advance(1, total_loss / (b + 1))
        state["epoch"] = epoch + 1
        state["seconds"] = state.get("seconds", 0.0) + time.perf_counter() - t_epoch
        state.setdefault("history", []).append({"epoch": epoch + 1, "loss": total_loss / per_epoch})
        state["optimizer"] = opt.state_dict()
        if time.perf_counter() - last_save > CHECKPOINT_SECONDS:
            save()
            last_save = time.perf_counter()
    job.model.eval()
    state["done"] = True


def train(ds: SmmDataset, rows: np.ndarray, cfg: SmmTrainConfig, checkpoint: Path | None = None, resume: bool = False,
          progress: bool = True, log: Log | None = None, device: torch.device | None = None) -> Trained:
    """Train the classifier and the regressors on the data-set rows `rows`; deterministic for cfg.seed."""
    device = device or torch.device("cuda" if torch.cuda.is_available() else "cpu")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _train(ds, rows, cfg, checkpoint, resume, progress, log, device)
    finally:
        torch.set_num_threads(threads)


def _train(ds: SmmDataset, rows: np.ndarray, cfg: SmmTrainConfig, checkpoint: Path | None, resume: bool, progress: bool,
           log: Log | None, device: torch.device) -> Trained:
    jobs = _jobs(ds, rows, cfg, device)
    states: dict[str, dict[str, Any]] = {j.key: {} for j in jobs}
    data = hashlib.sha256()
    for a in (ds.canon[rows], ds.cluster[rows], ds.label[rows], ds.boundary_canon, ds.boundary_label):
        data.update(np.ascontiguousarray(a).tobytes())
    fingerprint = {"config": asdict(cfg), "data": data.hexdigest(), "networks": [j.key for j in jobs]}
    if resume and checkpoint is not None and checkpoint.exists():
        ck = torch.load(checkpoint, weights_only=True, map_location=device)
        if ck["fingerprint"] != fingerprint:
            raise ArmbridgeError(f"checkpoint {checkpoint} was made with other settings or data; start without --resume")
        states = ck["states"]
        for j in jobs:
            j.model.load_state_dict(ck["models"][j.key])
        if log:
            log(f"resumed from {checkpoint}: {sum(s.get('done', False) for s in states.values())} of {len(jobs)} networks done")

    def save() -> None:
        if checkpoint is not None:
            _save({"fingerprint": fingerprint, "states": states,
                   "models": {j.key: j.model.state_dict() for j in jobs}}, checkpoint)

    total = sum(math.prod(steps_for(cfg, j.inputs.shape[0])) for j in jobs)
    done = sum(states[j.key].get("step", 0) for j in jobs)
    bar, task = None, None
    if progress:
        bar = _progress_bar("[bold]SMM[/] {task.fields[net]}", "loss {task.fields[loss]:.4g}")
        task = bar.add_task("train", total=total, completed=done, net="", loss=float("nan"))
    try:
        for j in jobs:
            st = states[j.key]
            if st.get("done"):
                continue

            def advance(k: int, loss: float, name: str = j.key) -> None:
                if bar is not None and task is not None:
                    bar.update(task, advance=k, net=name, loss=loss)

            _fit(j, cfg, st, advance, save)
            save()
            if log:
                log(f"{j.key}: {st['step']} steps, last epoch loss {st['history'][-1]['loss']:.4g}")
    finally:
        if bar is not None:
            bar.stop()
    for j in jobs:
        j.model.eval().cpu()
    return Trained(classifier=jobs[0].model,  # type: ignore[arg-type]
                   regressors={j.index - 1: j.model for j in jobs[1:]},  # type: ignore[misc]
                   history={j.key: states[j.key]["history"] for j in jobs},
                   steps={j.key: states[j.key]["step"] for j in jobs},
                   seconds=sum(states[j.key]["seconds"] for j in jobs))


# ------------------------------------------------------------------ export


def export_onnx(model: torch.nn.Module, c_dim: int, path: Path) -> Path:
    """Dynamo export, float32, dynamic batch, weights inside the file (input "canon")."""
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(model.eval(), (torch.zeros(2, c_dim),), str(path), dynamo=True, external_data=False,
                      input_names=["canon"], output_names=["y"], dynamic_shapes=({0: "batch"},), verbose=False)
    side = Path(str(path) + ".data")
    if side.exists():
        raise ArmbridgeError(f"ONNX export wrote a side file {side}; expected the weights inside the model")
    return path


def export_all(trained: Trained, c_dim: int, out: Path) -> dict[str, Any]:
    """classifier.onnx and regressor-<c>.onnx in `out`; the card's "files" entry."""
    from armbridge.ik.export import file_entry

    files: dict[str, Any] = {"classifier": file_entry(export_onnx(trained.classifier, c_dim, out / "classifier.onnx"), out)}
    files["regressors"] = {str(c): file_entry(export_onnx(m, c_dim, out / f"regressor-{c}.onnx"), out)
                           for c, m in sorted(trained.regressors.items())}
    return files


def onnx_matches_torch(trained: Trained, out: Path, files: dict[str, Any], canon: np.ndarray) -> float:
    """Largest |onnx - torch| over all networks on `canon`, relative to each output's scale."""
    from armbridge.ik.export import onnx_run

    x = np.ascontiguousarray(canon, dtype=np.float32)
    worst = 0.0
    models = [(trained.classifier, files["classifier"])] + [(m, files["regressors"][str(c)])
                                                            for c, m in trained.regressors.items()]
    for model, entry in models:
        with torch.no_grad():
            ref = model(torch.as_tensor(x)).numpy()
        got = onnx_run(out / entry["path"], x)
        worst = max(worst, float(np.abs(got - ref).max() / max(1.0, np.abs(ref).max())))
    return worst


# ------------------------------------------------------------------ accuracy


def measure(smm: LearnedSmm, ds: SmmDataset, rows: np.ndarray, n_points: int, correct_iters: int) -> dict[str, Any]:
    """Table III metrics of a LearnedSmm on data-set rows: classifier accuracy, branch-count
    mismatch, and FK error % (eq. 19) before and after `correct_iters` eq. (18) steps.

    The FK error is taken over the rows that are reachable (their label has
    branches), as Table III samples reachable locations: branches predicted at
    an unreachable location have no FK error to speak of, they count as
    branch-count mismatches.
    """
    arm = smm.arm
    canon = np.asarray(ds.canon[rows], dtype=np.float64)
    true_label = np.asarray(ds.label[rows])
    pred = smm.classify(canon)
    reachable = ds.cluster_branches[true_label] > 0
    x = arm.uncanonical(canon[reachable])
    acc: dict[str, Any] = {
        "locations": int(rows.size),
        "classifier_accuracy_pct": float(np.mean(pred == true_label) * 100),
        "branch_count_mismatch_pct": float(np.mean(ds.cluster_branches[pred] != ds.cluster_branches[true_label]) * 100),
        "fk_locations": int(reachable.sum()),
    }
    for label, iters in (("before", 0), ("after", correct_iters)):
        err = fk_errors(arm, smm.compute(x, n_points=n_points, correct_iters=iters), x) * 100
        acc[f"fk_error_pct_{label}"] = {"correct_iters": iters, "points": int(err.size), **(
            {k: float(f(err)) for k, f in (("mean", np.mean), ("median", np.median), ("std", np.std), ("max", np.max))}
            if err.size else {})}
    return acc


def fk_errors(arm: SmmArm, s: SmmSet, x: np.ndarray) -> np.ndarray:
    """Eq. (19) FK error (fraction) of every point of every branch of an SmmSet at targets x."""
    valid = np.arange(s.points.shape[1])[None, :] < s.count[:, None]
    q = s.points[valid].reshape(-1, arm.n)
    target = np.repeat(x[np.nonzero(valid)[0]], s.points.shape[2], axis=0)
    return np.asarray(arm.fk_error(q, target))


# ------------------------------------------------------------------ data set


def grid_for(arm: SmmArm, text: str) -> GridSpec:
    """dataset.GridSpec for --grid: '' (the data-set module's default), '200' or '250x400' cells."""
    from armbridge.smm.dataset import default_grid

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
        ds, parts = rf.refine(arm, build, refine, per_cell=per_cell, runner=runner, sing_tol=sing_tol, seed=seed)
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
        info["refine"] = {"factor": refine, "how": "armbridge.smm.refine", "patches": rf.summary(parts)}
    return ds, info


# ------------------------------------------------------------------ pipeline


@dataclass
class PipelineConfig:
    """Where the data and the outputs go, and how accuracy is measured."""

    robot: str
    train: SmmTrainConfig
    dataset: Path
    out: Path
    work_dir: Path
    eval_points: int = 128
    correct_iters: int = 3
    command: str = ""
    dataset_info: dict[str, Any] = field(default_factory=dict)


def run(cfg: PipelineConfig, ds: SmmDataset, resume: bool = False, progress: bool = True, log: Log | None = None,
        device: torch.device | None = None) -> dict[str, Any]:
    """Train, export, measure and write OUT/card.json; returns the card."""
    import onnx
    import onnxruntime  # type: ignore[import-untyped]

    from armbridge.ik.export import sha256

    arm = get_smm_arm(cfg.robot)
    check_dataset(ds, arm)
    train_rows, test_rows = split(np.asarray(ds.label), cfg.train.holdout, cfg.train.seed)
    device = device or torch.device("cuda" if torch.cuda.is_available() else "cpu")
    trained = train(ds, train_rows, cfg.train, cfg.work_dir / "checkpoint.pt", resume, progress, log, device)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    files = export_all(trained, arm.c_dim, out)
    probe = test_rows if test_rows.size else train_rows
    onnx_err = onnx_matches_torch(trained, out, files, np.asarray(ds.canon[probe[:2000]]))
    clf = trained.classifier
    card: dict[str, Any] = {
        "card_version": CARD_VERSION,
        "name": out.name,
        "kind": KIND,
        "description": ("learned SMMs (Clark and Xie, section V-D): classifier location -> cluster, "
                        "per-cluster regressor location -> Fourier coefficients of every branch, eq. (10) decode"),
        "robot": arm.name,
        "robot_description": arm.to_dict(),
        "canonical": {"dims": arm.c_dim, "what": "DHChain.canonical: joint-1 symmetry removed; "
                                                 "SMM at x = SMM at c with theta_1 += phi"},
        "fourier": {"K": int(ds.K), "N": int(ds.N), "frequencies": "armbridge.smm.fourier.frequencies(K)",
                    "decode": "armbridge.smm.fourier.decode (eq. 10)",
                    "regressor_output": "flattened (branch, joint, k, [re, im]), eq. (8) unnormalised"},
        "clusters": {"branches": [int(b) for b in ds.cluster_branches],
                     "train_locations": [int(np.sum(ds.cluster[train_rows] == c)) for c in range(ds.cluster_branches.size)],
                     "out_of_reach": [int(c) for c in np.flatnonzero(ds.cluster_branches == 0)]},
        "scaling": {"input_lo": clf.lo.tolist(), "input_hi": clf.hi.tolist(),
                    "features": "2 * (canon - input_lo) / (input_hi - input_lo) - 1, inside the graphs",
                    "regressor_output": "mean + scale * z per cluster (mean per output, one RMS scale), inside the graphs",
                    "regressor_scale": {str(c): float(m.scale) for c, m in trained.regressors.items()}},
        "architecture": {
            "activation": f"leaky_relu({nets.LEAKY_SLOPE})",
            "classifier": {"inputs": arm.c_dim, "hidden": list(cfg.train.cls_hidden), "outputs": int(ds.cluster_branches.size),
                           "parameters": _params(clf)},
            "regressor": {"inputs": arm.c_dim, "hidden": list(cfg.train.reg_hidden),
                          "outputs": {str(c): int(m.mean.numel()) for c, m in trained.regressors.items()},
                          "parameters": {str(c): _params(m) for c, m in trained.regressors.items()}},
        },
        "training": {
            **asdict(cfg.train),
            "optimizer": "AdamW, cosine lr decay from lr to lr * lr_decay per network",
            "losses": "classifier: cross entropy (15)-(16); regressors: eq. (17) on (y - mean) / scale",
            "steps": trained.steps,
            "final_loss": {k: h[-1]["loss"] for k, h in trained.history.items() if h},
            "seconds": round(trained.seconds, 1),
            "device": str(device),
            "threads": 1,
            "command": cfg.command,
            "versions": {"python": platform.python_version(), "torch": torch.__version__, "numpy": np.__version__,
                         "onnx": onnx.__version__, "onnxruntime": onnxruntime.__version__},
            "machine": f"{platform.machine()} {platform.processor() or 'CPU'}",
        },
        "dataset": {**cfg.dataset_info, "path": str(cfg.dataset), "sha256": sha256(cfg.dataset) if cfg.dataset.exists() else None,
                    "locations": int(ds.canon.shape[0]), "clustered": int(np.sum(ds.cluster >= 0)),
                    "labelled": int(np.sum(ds.label >= 0)), "boundary_points": int(ds.boundary_label.size),
                    "boundary_labelled": int(np.sum(ds.boundary_label >= 0)),
                    "train": int(train_rows.size), "held_out": int(test_rows.size)},
        "files": files,
    }
    (out / CARD_NAME).write_text(_json(card))  # the accuracy is measured on the files as shipped, through this card
    smm = LearnedSmm.load(out, robot=arm.name)
    card["accuracy"] = {"onnx_vs_torch_max_rel": onnx_err, "n_points": cfg.eval_points,
                        "held_out": measure(smm, ds, test_rows, cfg.eval_points, cfg.correct_iters) if test_rows.size else None}
    (out / CARD_NAME).write_text(_json(card))
    if log:
        log(f"wrote {out / CARD_NAME}")
    return card


def _params(model: torch.nn.Module) -> int:
    return int(sum(p.numel() for p in model.parameters()))


def _json(card: dict[str, Any]) -> str:
    return json.dumps(card, indent=2) + "\n"
