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

Pure torch: numbers in, numbers out, no I/O. Training (the data's random
q_c, the schedule, checkpoints, the int8 fine-tune) is ik/masr_nn_train.py.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
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
