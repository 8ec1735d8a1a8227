"""IK-NN for the MASR (masr paper, section III-A, Fig. 4b): model, torch FK, loss, training.

The network g(x_d, q_c) -> q takes the goal MA pose x_d = (x, y, phi) and the
current configuration q_c = (theta_1..theta_n, d) and returns a configuration
within the joint limits by construction (theta = theta_b * tanh, d = l * sigmoid).
It is trained without labels, through a differentiable FK (the paper's
autoencoder idea: encoder = IK-NN, decoder = FK), by minimising eq. (10):

    L = || log(x_d^-1 f(g(x_d, q_c))) || + lambda * L_reg(q_c, g(x_d, q_c))

with L_reg eq. (11) (joint motion) or eq. (12) (action time). Every epoch draws
a fresh random q_c for every pose of the data set (section III-B).

FK and the MA's link. d = r_{j_d} + d_link picks the link j_d the MA stands on
(eqs. 2-4). The MA *position* is continuous in d (at a joint both links give
the same point), but phi = theta_hat_{j_d} jumps when d crosses a joint, so
d/dphi is zero almost everywhere and undefined at the joints. We use the hard
selection: j_d is an integer index computed without gradient (searchsorted),
and gradients flow through d_link = d - r_{j_d} (position) and through the
angles theta_1..theta_{j_d} (position and phi). The loss is then
differentiable almost everywhere, and exact: what is trained is the FK the
robot and the tests use. The network still learns which link to put the MA
on, because the position error pulls d along the arm and the regulariser
weighs which joints move; a soft blend of phi over links (`link_softness` > 0,
phi = sum_j w_j(d) theta_hat_j with sigmoid weights of width `link_softness` m)
is available for experiments, and is not what the shipped model used unless
its card says so.

Pure torch: numbers in, numbers out; no I/O except `train`, which writes
checkpoints and shows a progress bar.
"""
from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch
from torch import nn

from armbridge.errors import ArmbridgeError
from armbridge.geometry import wrap_angle

# Goal-reach bounds of eq. (9), section V-A.
E_P = 0.008  # m
E_PHI = math.radians(4.0)  # rad


@dataclass(frozen=True)
class ArmParams:
    """The numbers of a MASR arm that the torch code needs (from a MasrArm)."""

    name: str
    link_lengths: tuple[float, ...]
    theta_b: tuple[float, ...]
    ma_speed: float
    joint_speed: float

    @property
    def n(self) -> int:
        return len(self.link_lengths)

    @property
    def total_length(self) -> float:
        return float(sum(self.link_lengths))

    @property
    def r(self) -> np.ndarray:
        """r_j = sum_{i<j} l_i, j = 1..n (r_1 = 0)."""
        return np.concatenate([[0.0], np.cumsum(self.link_lengths)[:-1]])

    @classmethod
    def of(cls, arm: Any) -> "ArmParams":
        if isinstance(arm, ArmParams):
            return arm
        n = len(np.atleast_1d(arm.link_lengths))
        tb = np.broadcast_to(np.asarray(arm.theta_b, dtype=float), (n,))
        return cls(
            name=str(arm.name),
            link_lengths=tuple(float(v) for v in np.asarray(arm.link_lengths, dtype=float)),
            theta_b=tuple(float(v) for v in tb),
            ma_speed=float(arm.ma_speed),
            joint_speed=float(arm.joint_speed),
        )


# ---------------------------------------------------------------- kinematics


class TorchMasrFK(nn.Module):
    """MA pose (x, y, phi) of configurations q (..., n+1), eqs. (2)-(4), in torch."""

    lengths: torch.Tensor
    r: torch.Tensor

    def __init__(self, arm: Any, link_softness: float = 0.0) -> None:
        super().__init__()
        p = ArmParams.of(arm)
        self.n = p.n
        self.link_softness = float(link_softness)
        self.register_buffer("lengths", torch.tensor(p.link_lengths, dtype=torch.float32))
        self.register_buffer("r", torch.tensor(p.r, dtype=torch.float32))

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        return masr_fk_torch(q, self.lengths.to(q.dtype), self.r.to(q.dtype), self.link_softness)


def masr_fk_torch(q: torch.Tensor, lengths: torch.Tensor, r: torch.Tensor, link_softness: float = 0.0) -> torch.Tensor:
    """FK of the MASR: q (..., n+1) -> (..., 3) = (x, y, phi), differentiable a.e.

    Hard link selection: j_d = max{j : r_j <= d} (d = l lands on link n);
    gradients flow through d_link and the angles (see the module docstring).
    """
    n = lengths.shape[0]
    theta, d = q[..., :n], q[..., n]
    cum = torch.cumsum(theta, dim=-1)  # theta_hat_j
    c, s = torch.cos(cum), torch.sin(cum)
    zero = torch.zeros_like(c[..., :1])
    jx = torch.cat([zero, torch.cumsum(lengths * c, dim=-1)[..., :-1]], dim=-1)  # joint j position
    jy = torch.cat([zero, torch.cumsum(lengths * s, dim=-1)[..., :-1]], dim=-1)
    with torch.no_grad():
        idx = torch.searchsorted(r.contiguous(), d.detach().contiguous().unsqueeze(-1), right=True) - 1
        idx = idx.clamp(0, n - 1)
    d_link = d.unsqueeze(-1) - r[idx]
    x = jx.gather(-1, idx) + d_link * c.gather(-1, idx)
    y = jy.gather(-1, idx) + d_link * s.gather(-1, idx)
    if link_softness > 0:
        # phi as a blend of theta_hat_j over links with sigmoid edges at the joints
        edges = torch.sigmoid((d.unsqueeze(-1) - r[1:]) / link_softness)  # past joint j+1
        ones = torch.ones_like(edges[..., :1])
        up = torch.cat([ones, edges], dim=-1)  # on or past link j
        w = up - torch.cat([edges, torch.zeros_like(ones)], dim=-1)
        phi = (w * cum).sum(-1, keepdim=True)
    else:
        phi = cum.gather(-1, idx)
    return torch.cat([x, y, phi], dim=-1)


def se2_log(x_d: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Twist V_b = log(x_d^-1 x) in R^3 = (v_x, v_y, omega), poses as (..., 3) (x, y, phi).

    x_d^-1 x = (R(-phi_d)(p - p_d), phi - phi_d); omega is the wrapped angle and
    v = V(omega)^-1 t with V^-1 = [[a, b], [-b, a]], a = (w/2) cot(w/2), b = w/2
    (Lynch & Park, SE(2) case of the matrix logarithm).
    """
    dp = x[..., :2] - x_d[..., :2]
    cd, sd = torch.cos(x_d[..., 2]), torch.sin(x_d[..., 2])
    tx = cd * dp[..., 0] + sd * dp[..., 1]
    ty = -sd * dp[..., 0] + cd * dp[..., 1]
    w = wrap_angle(x[..., 2] - x_d[..., 2])  # a gradient of 1 everywhere
    small = w.abs() < 1e-3
    ws = torch.where(small, torch.ones_like(w), w)  # safe operand for the exact branch
    half = ws / 2
    a_exact = half * torch.cos(half) / torch.sin(half)
    a = torch.where(small, 1 - w * w / 12, a_exact)
    b = w / 2
    vx = a * tx + b * ty
    vy = -b * tx + a * ty
    return torch.stack([vx, vy, w], dim=-1)


def twist_norm(v: torch.Tensor, pos_unit: float = 1.0, ang_unit: float = 1.0, eps: float = 1e-12) -> torch.Tensor:
    """|| (v_x / pos_unit, v_y / pos_unit, omega / ang_unit) || (smooth at 0 through eps)."""
    scale = v.new_tensor([1 / pos_unit, 1 / pos_unit, 1 / ang_unit])
    return torch.sqrt(((v * scale) ** 2).sum(-1) + eps)


def reg_joint_torch(q_c: torch.Tensor, q: torch.Tensor, n: int) -> torch.Tensor:
    """Eq. (11): sum_i |theta_c,i - theta_i| (rad)."""
    return (q_c[..., :n] - q[..., :n]).abs().sum(-1)


def reg_action_torch(q_c: torch.Tensor, q: torch.Tensor, r: torch.Tensor, joint_speed: float, ma_speed: float) -> torch.Tensor:
    """Eq. (12): sum_i (|theta_c,i - theta_i| / theta_dot) * (|d_c - r_i| / d_dot) (s^2)."""
    n = r.shape[0]
    dtheta = (q_c[..., :n] - q[..., :n]).abs() / joint_speed
    reach = (q_c[..., n : n + 1] - r).abs() / ma_speed
    return (dtheta * reach).sum(-1)


# ---------------------------------------------------------------- model


@dataclass
class Scaling:
    """Input/output scaling baked into the network (recorded in the model card)."""

    total_length: float
    theta_b: list[float]

    def describe(self) -> dict[str, Any]:
        return {
            "input": ["x_goal (m)", "y_goal (m)", "phi_goal (rad)", *[f"theta_c{i + 1} (rad)" for i in range(len(self.theta_b))], "d_c (m)"],
            "features": "[x/l, y/l, cos(phi), sin(phi), theta_c/theta_b, 2*d_c/l - 1], l = total length",
            "output": [*[f"theta{i + 1} (rad)" for i in range(len(self.theta_b))], "d (m)"],
            "output_map": "theta = theta_b * tanh(z_theta), d = l * sigmoid(z_d)",
            "total_length": self.total_length,
            "theta_b": self.theta_b,
        }


def fake_quant_rows(w: torch.Tensor) -> torch.Tensor:
    """w rounded to symmetric per-row int8 (scale = max|row| / 127), straight-through gradient."""
    scale = w.detach().abs().amax(dim=1, keepdim=True).clamp_min(1e-12) / 127.0
    q = torch.clamp(torch.round(w / scale), -127, 127) * scale
    return w + (q - w).detach()


class MasrIKNet(nn.Module):
    """g(x_d, q_c): raw inputs (B, 3 + n + 1) -> configuration (B, n + 1) within limits."""

    theta_b: torch.Tensor
    length: torch.Tensor

    def __init__(self, arm: Any, hidden: Sequence[int] = (120, 100, 50, 30), activation: str = "leaky_relu") -> None:
        super().__init__()
        p = ArmParams.of(arm)
        self.n = p.n
        self.hidden = list(hidden)
        self.activation = activation
        self.register_buffer("theta_b", torch.tensor(p.theta_b, dtype=torch.float32))
        self.register_buffer("length", torch.tensor(p.total_length, dtype=torch.float32))
        acts: dict[str, Callable[[], nn.Module]] = {
            "leaky_relu": lambda: nn.LeakyReLU(0.01),
            "relu": nn.ReLU,
            "tanh": nn.Tanh,
            "silu": nn.SiLU,
        }
        if activation not in acts:
            raise ArmbridgeError(f"activation must be one of {sorted(acts)}, got {activation!r}")
        layers: list[nn.Module] = []
        width = 4 + p.n + 1
        for h in hidden:
            layers += [nn.Linear(width, h), acts[activation]()]
            width = h
        layers.append(nn.Linear(width, p.n + 1))
        self.mlp = nn.Sequential(*layers)
        self.scaling = Scaling(p.total_length, list(p.theta_b))
        self.fake_quant = False  # quantisation-aware fine-tuning: int8 per-row weights in the forward pass

    def features(self, inp: torch.Tensor) -> torch.Tensor:
        n = self.n
        xy = inp[..., 0:2] / self.length
        phi = inp[..., 2:3]
        th = inp[..., 3 : 3 + n] / self.theta_b
        d = inp[..., 3 + n : 4 + n] * (2 / self.length) - 1
        return torch.cat([xy, torch.cos(phi), torch.sin(phi), th, d], dim=-1)

    def forward(self, inp: torch.Tensor) -> torch.Tensor:
        h = self.features(inp)
        if self.fake_quant:
            for m in self.mlp:
                h = nn.functional.linear(h, fake_quant_rows(m.weight), m.bias) if isinstance(m, nn.Linear) else m(h)
            z = h
        else:
            z = self.mlp(h)
        theta = self.theta_b * torch.tanh(z[..., : self.n])
        d = self.length * torch.sigmoid(z[..., self.n :])
        return torch.cat([theta, d], dim=-1)

    def linear_layers(self) -> list[nn.Linear]:
        return [m for m in self.mlp if isinstance(m, nn.Linear)]


# ---------------------------------------------------------------- loss


@dataclass
class LossConfig:
    reg: str = "action"  # "action" (eq. 12) or "joint" (eq. 11)
    lam: float = 1e-3
    pos_unit: float = 1.0  # m per twist unit (1 = the paper's plain twist)
    ang_unit: float = 1.0  # rad per twist unit
    link_softness: float = 0.0


class MasrIKLoss(nn.Module):
    """Eq. (10): mean twist norm + lambda * mean regulariser; also returns the parts."""

    def __init__(self, arm: Any, cfg: LossConfig) -> None:
        super().__init__()
        p = ArmParams.of(arm)
        if cfg.reg not in ("action", "joint"):
            raise ArmbridgeError(f"reg must be 'action' (eq. 12) or 'joint' (eq. 11), got {cfg.reg!r}")
        self.cfg = cfg
        self.p = p
        self.fk = TorchMasrFK(p, cfg.link_softness)

    def forward(self, x_d: torch.Tensor, q_c: torch.Tensor, q: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        x = self.fk(q)
        tw = twist_norm(se2_log(x_d, x), self.cfg.pos_unit, self.cfg.ang_unit)
        if self.cfg.reg == "action":
            reg = reg_action_torch(q_c, q, self.fk.r, self.p.joint_speed, self.p.ma_speed)
        else:
            reg = reg_joint_torch(q_c, q, self.p.n)
        loss = tw.mean() + self.cfg.lam * reg.mean()
        return loss, {"twist": tw.mean().detach(), "reg": reg.mean().detach()}


# ---------------------------------------------------------------- training


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
