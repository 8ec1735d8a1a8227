"""Training of the MASR IK-NN (ik/masr_nn.py): the loop, its schedule and checkpoints.

`train` minimises eq. (10) (`MasrIKLoss`) over the data set's poses, every
epoch with a fresh random current configuration q_c for every pose (section
III-B), Adam with a linear warm-up and a cosine decay (`lr_at`). It is
deterministic for a seed (`set_determinism`: one thread, seeded torch,
deterministic kernels; the random streams are functions of (seed, epoch)), so
a run resumed from its checkpoint (written after every epoch) equals an
uninterrupted one. `finetune_int8` is the quantisation-aware fine-tune for the
int8 export.

Apart from ik/masr_nn.py (the network, its torch FK and its loss: what a
model is and what it minimises) because this is how one is made.
"""
from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from armbridge.errors import ArmbridgeError
from armbridge.ik.masr_nn import ArmParams, LossConfig, MasrIKLoss, MasrIKNet, fake_quant_rows


@dataclass
class TrainConfig:
    hidden: list[int] = field(default_factory=lambda: [120, 100, 50, 30])
    activation: str = "leaky_relu"
    reg: str = "action"
    lam: float = 1e-3
    pos_unit: float = 1.0
    ang_unit: float = 1.0
    link_softness: float = 0.0
    lr: float = 3e-3
    lr_final: float = 3e-5
    warmup_steps: int = 200
    epochs: int = 100
    batch: int = 4096
    seed: int = 0
    weight_decay: float = 0.0
    max_steps: int = 0  # 0: epochs * steps per epoch; >0 stops early (tests)

    def loss_config(self) -> LossConfig:
        return LossConfig(self.reg, self.lam, self.pos_unit, self.ang_unit, self.link_softness)


def lr_at(cfg: TrainConfig, step: int, total: int) -> float:
    """Linear warm-up then cosine decay from lr to lr_final (a function of the step: resumable)."""
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    t = min(1.0, (step - cfg.warmup_steps) / max(1, total - cfg.warmup_steps))
    return cfg.lr_final + 0.5 * (cfg.lr - cfg.lr_final) * (1 + math.cos(math.pi * t))


def random_configs(arm: Any, count: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform random configurations in C_f (eq. 5), shape (count, n+1)."""
    p = ArmParams.of(arm)
    tb = np.asarray(p.theta_b)
    th = rng.uniform(-tb, tb, (count, p.n))
    d = rng.uniform(0.0, p.total_length, (count, 1))
    return np.concatenate([th, d], axis=1)


def set_determinism(seed: int) -> dict[str, Any]:
    """One thread, seeded torch, deterministic kernels; returns what to restore afterwards."""
    saved = {"threads": torch.get_num_threads(), "det": torch.are_deterministic_algorithms_enabled(),
             "warn": torch.is_deterministic_algorithms_warn_only_enabled()}
    torch.set_num_threads(1)
    torch.manual_seed(seed)
    torch.use_deterministic_algorithms(True, warn_only=True)
    return saved


def restore_torch(saved: dict[str, Any]) -> None:
    torch.set_num_threads(saved["threads"])
    torch.use_deterministic_algorithms(saved["det"], warn_only=saved["warn"])


@dataclass
class TrainResult:
    model: MasrIKNet
    history: list[dict[str, float]]
    steps: int
    seconds: float


def _save_atomic(obj: Any, path: Path) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def train(
    arm: Any,
    poses: np.ndarray,
    cfg: TrainConfig,
    checkpoint: Path | None = None,
    resume: bool = False,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    stop_after_epoch: int | None = None,
) -> TrainResult:
    """Train the IK-NN on data-set poses (N, 3); deterministic for a given cfg.seed.

    Checkpoints (model, optimiser, epoch, history) go to `checkpoint` after
    every epoch; `resume=True` continues from it (the random streams are
    functions of (seed, epoch), so a resumed run equals an uninterrupted one).
    `stop_after_epoch` ends the run early after that epoch, as an interruption would.
    """
    saved = set_determinism(cfg.seed)
    try:
        return _train(arm, poses, cfg, checkpoint, resume, progress, log, stop_after_epoch)
    finally:
        restore_torch(saved)


def _train(arm: Any, poses: np.ndarray, cfg: TrainConfig, checkpoint: Path | None, resume: bool, progress: bool,
           log: Callable[[str], None] | None, stop_after_epoch: int | None) -> TrainResult:
    p = ArmParams.of(arm)
    model = MasrIKNet(p, cfg.hidden, cfg.activation)
    loss_fn = MasrIKLoss(p, cfg.loss_config())
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    x_all = torch.as_tensor(np.asarray(poses, dtype=np.float32))
    n_data = x_all.shape[0]
    if n_data == 0:
        raise ArmbridgeError("training needs a non-empty data set")
    steps_per_epoch = max(1, math.ceil(n_data / cfg.batch))
    total = cfg.epochs * steps_per_epoch
    if cfg.max_steps:
        total = min(total, cfg.max_steps)
    history: list[dict[str, float]] = []
    start_epoch, step = 0, 0
    if resume and checkpoint is not None and checkpoint.exists():
        ck = torch.load(checkpoint, weights_only=True)  # tensors, numbers, strings and dicts only: no pickled objects
        if ck["config"] != asdict(cfg):
            raise ArmbridgeError(f"checkpoint {checkpoint} was made with other settings; start without --resume")
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        start_epoch, step, history = ck["epoch"], ck["step"], ck["history"]
        if log:
            log(f"resumed from {checkpoint} at epoch {start_epoch}, step {step}")

    t0 = time.perf_counter()
    before = float(history[-1]["seconds"]) if history else 0.0  # seconds of earlier runs (resume)
    bar = None
    if progress:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        bar = Progress(
            TextColumn("[bold]IK-NN[/] epoch {task.fields[epoch]}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("loss {task.fields[loss]:.5f}"),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
        )
        bar.start()
        task = bar.add_task("train", total=total, completed=step, epoch=start_epoch, loss=float("nan"))
    try:
        for epoch in range(start_epoch, cfg.epochs):
            if step >= total:
                break
            rng = np.random.default_rng([cfg.seed, epoch])
            perm = torch.as_tensor(rng.permutation(n_data))
            q_c_all = torch.as_tensor(random_configs(p, n_data, rng).astype(np.float32))
            sums = {"loss": 0.0, "twist": 0.0, "reg": 0.0}
            batches = 0
            model.train()
            for b in range(steps_per_epoch):
                if step >= total:
                    break
                idx = perm[b * cfg.batch : (b + 1) * cfg.batch]
                x_d = x_all[idx]
                q_c = q_c_all[idx]
                for g in opt.param_groups:
                    g["lr"] = lr_at(cfg, step, total)
                q = model(torch.cat([x_d, q_c], dim=-1))
                loss, parts = loss_fn(x_d, q_c, q)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                step += 1
                batches += 1
                sums["loss"] += float(loss.detach())
                sums["twist"] += float(parts["twist"])
                sums["reg"] += float(parts["reg"])
                if bar is not None and (step % 20 == 0 or step == total):
                    bar.update(task, completed=step, epoch=epoch + 1, loss=sums["loss"] / batches)
            rec = {k: v / max(1, batches) for k, v in sums.items()}
            rec.update(epoch=epoch + 1, step=step, lr=lr_at(cfg, step - 1, total), seconds=before + time.perf_counter() - t0)
            history.append(rec)
            if log:
                log(json.dumps(rec))
            if checkpoint is not None:
                checkpoint.parent.mkdir(parents=True, exist_ok=True)
                _save_atomic(
                    {"model": model.state_dict(), "optimizer": opt.state_dict(), "epoch": epoch + 1, "step": step,
                     "history": history, "config": asdict(cfg)},
                    checkpoint,
                )
            if stop_after_epoch is not None and epoch + 1 >= stop_after_epoch:
                break
    finally:
        if bar is not None:
            bar.stop()
    model.eval()
    return TrainResult(model, history, step, time.perf_counter() - t0)


def finetune_int8(arm: Any, model: MasrIKNet, poses: np.ndarray, cfg: TrainConfig, epochs: int, lr: float,
                  progress: bool = False, log: Callable[[str], None] | None = None) -> TrainResult:
    """Quantisation-aware fine-tuning of a copy of `model` for the int8 export.

    The forward pass uses per-row int8 weights (fake_quant_rows, straight-through
    gradients); same loss, data and fresh q_c as training, the random stream
    Generator([seed, 1_000_000 + epoch]), Adam at `lr` with cosine decay to lr/100.
    """
    import copy

    saved = set_determinism(cfg.seed + 1)
    try:
        q_model = copy.deepcopy(model)
        q_model.fake_quant = True
        q_model.train()
        p = ArmParams.of(arm)
        loss_fn = MasrIKLoss(p, cfg.loss_config())
        opt = torch.optim.Adam(q_model.parameters(), lr=lr)
        x_all = torch.as_tensor(np.asarray(poses, dtype=np.float32))
        n_data = x_all.shape[0]
        steps_per_epoch = max(1, math.ceil(n_data / cfg.batch))
        total = epochs * steps_per_epoch
        qcfg = TrainConfig(**{**asdict(cfg), "lr": lr, "lr_final": lr / 100, "warmup_steps": 0})
        history: list[dict[str, float]] = []
        t0 = time.perf_counter()
        step = 0
        for epoch in range(epochs):
            rng = np.random.default_rng([cfg.seed, 1_000_000 + epoch])
            perm = torch.as_tensor(rng.permutation(n_data))
            q_c_all = torch.as_tensor(random_configs(p, n_data, rng).astype(np.float32))
            tot = 0.0
            for b in range(steps_per_epoch):
                idx = perm[b * cfg.batch : (b + 1) * cfg.batch]
                for g in opt.param_groups:
                    g["lr"] = lr_at(qcfg, step, total)
                x_d, q_c = x_all[idx], q_c_all[idx]
                loss, _ = loss_fn(x_d, q_c, q_model(torch.cat([x_d, q_c], dim=-1)))
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                step += 1
                tot += float(loss.detach())
            rec = {"epoch": epoch + 1, "loss": tot / steps_per_epoch, "seconds": time.perf_counter() - t0}
            history.append(rec)
            if log:
                log("int8 fine-tune " + json.dumps(rec))
        q_model.fake_quant = False
        with torch.no_grad():  # store the weights already on the int8 grid
            for lin in q_model.linear_layers():
                lin.weight.copy_(fake_quant_rows(lin.weight))
        q_model.eval()
        return TrainResult(q_model, history, step, time.perf_counter() - t0)
    finally:
        restore_torch(saved)
