"""Training the learned SMM's networks: the classifier and one regressor per cluster.

Used by the pipeline of `armbridge train smm-3r|smm-4r|smm-7r` (train/smm.py).
Training follows section VI-A (LeakyReLU MLPs, AdamW, lr 1e-3 for the
classifier and 3e-3 for the regressors, losses (15)-(17)); the learning rate
decays by a cosine to lr * lr_decay over each network's steps (the paper does
not say; a decay lowers the final regression error, lr_decay = 1 keeps it
constant).

Every network trains for `epochs` passes over its training locations, and at
least `min_steps` steps, so a cluster with few locations is not left
under-trained. Deterministic for a seed: each network's initial weights come
from torch.manual_seed(seed + 1000 * net), its batches from numpy
Generator([seed, net, epoch]); a checkpoint written at epoch boundaries lets
--resume continue to the same result.

Apart from the pipeline (the data set, the export, the accuracy and the card)
because this is the one part that runs torch's optimiser: the settings, the
schedule and the resumable loop.
"""
from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from armbridge.errors import ArmbridgeError
from armbridge.smm import networks as nets
from armbridge.smm.dataset import SmmDataset
from armbridge.smm.grid import PERIODIC

Log = Callable[[str], None]
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
    periodic = PERIODIC.get(lo.size)  # the 7R's azimuth wraps around (networks._Scaled)
    torch.manual_seed(cfg.seed)
    clf = nets.SmmClassifier(lo, hi, cfg.cls_hidden, int(ds.cluster_branches.size), periodic).to(device)
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
        reg = nets.SmmRegressor(lo, hi, cfg.reg_hidden, mean, scale, periodic).to(device)
        yt = reg.normalise(torch.as_tensor(y, dtype=torch.float32, device=device))
        jobs.append(_Job(f"regressor-{c}", int(c) + 1, reg, x_all[torch.as_tensor(mine, device=device)], yt,
                         nets.regressor_loss, cfg.reg_lr))
    return jobs


def fit_classifier(canon: np.ndarray, labels: np.ndarray, n_classes: int, cfg: SmmTrainConfig,
                   periodic: tuple[bool, ...] | None = None, device: torch.device | None = None) -> nets.SmmClassifier:
    """One classifier (cfg.cls_hidden, cfg.cls_lr) trained on (canon, labels) by the pipeline's own loop
    (the schedule, the batches, the seed): the branch-count classifier of margin sampling (train smm-7r
    --margin, the device script) and of bench smm-data, which measures the data, not the loop."""
    device = device or torch.device("cpu")
    lo, hi = nets.input_box(np.asarray(canon, dtype=np.float64))
    torch.manual_seed(cfg.seed)
    clf = nets.SmmClassifier(lo, hi, cfg.cls_hidden, int(n_classes), periodic).to(device)
    job = _Job("classifier", 0, clf, torch.as_tensor(np.asarray(canon), dtype=torch.float32, device=device),
               torch.as_tensor(np.asarray(labels, dtype=np.int64), device=device), nets.classifier_loss, cfg.cls_lr)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        _fit(job, cfg, {}, lambda k, loss: None, lambda: None)
    finally:
        torch.set_num_threads(threads)
    return clf.eval().cpu()


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
