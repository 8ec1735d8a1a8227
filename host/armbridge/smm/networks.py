"""The two kinds of network of section V-D: the cluster classifier and the
per-cluster Fourier regressors, with their losses (eq. 15-17).

Both take a location in canonical coordinates (the joint-1 symmetry removed,
`SmmArm.canonical`). The input scaling to [-1, 1] over the training box (clamped) and
the regressor's output scaling are buffers inside the module, so the exported
ONNX graph takes raw canonical coordinates and returns raw coefficients.

Regressor targets are the real and imaginary parts of the K Fourier
coefficients of every branch of the cluster (eq. 8 after the low-pass filter),
flattened in the order (branch, joint, k, [re, im]); `coeffs_to_target` and
`target_to_coeffs` (in armbridge.smm.fourier: inference needs them without
torch) are the two directions of that layout.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from armbridge.errors import ArmbridgeError
from armbridge.smm.fourier import coeffs_to_target, target_to_coeffs  # noqa: F401 (the layout, re-exported)

LEAKY_SLOPE = 0.01  # torch's default LeakyReLU slope; the paper gives none


@dataclass(frozen=True)
class Architecture:
    """Hidden layer sizes of the classifier and of every regressor."""

    classifier: tuple[int, ...]
    regressor: tuple[int, ...]


# Section VI-A: classifiers 2x5, 3x50, 4x150; regressors 4x150, 5x150, 6x150.
PAPER_SIZES = {
    3: Architecture(classifier=(5, 5), regressor=(150,) * 4),
    4: Architecture(classifier=(50,) * 3, regressor=(150,) * 5),
    7: Architecture(classifier=(150,) * 4, regressor=(150,) * 6),
}


def default_architecture(n: int) -> Architecture:
    """The paper's sizes for an arm with n joints (3R, 4R, 7R)."""
    if n not in PAPER_SIZES:
        raise ArmbridgeError(f"no default network sizes for a {n}-joint arm (known: 3, 4, 7); give --cls-hidden and --reg-hidden")
    return PAPER_SIZES[n]


def mlp(n_in: int, hidden: Sequence[int], n_out: int) -> nn.Sequential:
    """Linear layers with LeakyReLU between them (section VI-A), linear output."""
    layers: list[nn.Module] = []
    width = n_in
    for h in hidden:
        layers += [nn.Linear(width, h), nn.LeakyReLU(LEAKY_SLOPE)]
        width = h
    layers.append(nn.Linear(width, n_out))
    return nn.Sequential(*layers)


def input_box(canon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) of the training locations per canonical coordinate, widened where constant."""
    lo, hi = canon.min(axis=0), canon.max(axis=0)
    flat = hi - lo < 1e-12
    return np.where(flat, lo - 1.0, lo), np.where(flat, hi + 1.0, hi)


class _Scaled(nn.Module):
    """An MLP on canonical coordinates mapped from the box [lo, hi] to [-1, 1].

    `periodic[i]` marks coordinate i as an angle that wraps around (the 7R's
    tool azimuth, grid.PERIODIC): the network sees (cos, sin) of it instead.
    On the raw angle, -pi and pi are the two ends of the input box, so the
    network has to learn twice over what is one place, and the branch count
    is not continuous across the seam. Measured on the 7R region (44,000
    traced locations, the paper's 4 x 150 classifier, `bench smm-data`):
    held-out branch-count mismatch 22.6 % on the raw angle, 20.4 % on
    (cos, sin) (docs/smm.md).
    """

    lo: torch.Tensor
    hi: torch.Tensor

    def __init__(self, lo: np.ndarray, hi: np.ndarray, hidden: Sequence[int], n_out: int,
                 periodic: Sequence[bool] | None = None) -> None:
        super().__init__()
        self.periodic = tuple(bool(p) for p in periodic) if periodic is not None else (False,) * len(lo)
        if len(self.periodic) != len(lo):
            raise ArmbridgeError(f"periodic has {len(self.periodic)} flags for {len(lo)} canonical coordinates")
        self.register_buffer("lo", torch.as_tensor(np.asarray(lo, dtype=np.float32)))
        self.register_buffer("hi", torch.as_tensor(np.asarray(hi, dtype=np.float32)))
        self.body = mlp(len(lo) + sum(self.periodic), hidden, n_out)

    def features(self, canon: torch.Tensor) -> torch.Tensor:
        """Clamped to the box: a location past the grid reads as the grid's border cell, which
        the data set's margin makes out of reach, instead of an extrapolation. Periodic
        coordinates become (cos, sin) (the class doc)."""
        x = torch.clamp(2.0 * (canon - self.lo) / (self.hi - self.lo) - 1.0, -1.0, 1.0)
        if not any(self.periodic):
            return x
        cols = []
        for i, wraps in enumerate(self.periodic):
            cols += [torch.cos(canon[..., i]), torch.sin(canon[..., i])] if wraps else [x[..., i]]
        return torch.stack(cols, dim=-1)


class SmmClassifier(_Scaled):
    """Canonical location -> logits over the C workspace clusters (section V-D)."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, hidden: Sequence[int], n_clusters: int,
                 periodic: Sequence[bool] | None = None) -> None:
        super().__init__(lo, hi, hidden, n_clusters, periodic)

    def forward(self, canon: torch.Tensor) -> torch.Tensor:
        return self.body(self.features(canon))


class SmmRegressor(_Scaled):
    """Canonical location -> flattened real/imaginary Fourier coefficients of one cluster.

    The body predicts (y - mean) / scale with one scalar scale for all outputs,
    so its loss is eq. (17) divided by scale^2: every coefficient keeps the
    weight the paper gives it (a per-output scale would inflate the tiny
    high-frequency terms).
    """

    mean: torch.Tensor
    scale: torch.Tensor

    def __init__(self, lo: np.ndarray, hi: np.ndarray, hidden: Sequence[int], mean: np.ndarray, scale: float,
                 periodic: Sequence[bool] | None = None) -> None:
        super().__init__(lo, hi, hidden, int(np.asarray(mean).size), periodic)
        self.register_buffer("mean", torch.as_tensor(np.asarray(mean, dtype=np.float32)))
        self.register_buffer("scale", torch.tensor(float(scale), dtype=torch.float32))

    def normalised(self, canon: torch.Tensor) -> torch.Tensor:
        """The body's output, in the units the loss is measured in."""
        return self.body(self.features(canon))

    def normalise(self, target: torch.Tensor) -> torch.Tensor:
        return (target - self.mean) / self.scale

    def forward(self, canon: torch.Tensor) -> torch.Tensor:
        return self.mean + self.scale * self.normalised(canon)


def output_scaling(target: np.ndarray) -> tuple[np.ndarray, float]:
    """Per-output mean and one RMS scale over all outputs of the centred targets."""
    mean = target.mean(axis=0)
    scale = float(np.sqrt(np.mean((target - mean) ** 2)))
    return mean, scale if scale > 1e-12 else 1.0


def classifier_loss(logits: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Cross entropy of the softmax (16) against one-hot labels, eq. (15)."""
    return nn.functional.cross_entropy(logits, labels)


def regressor_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Eq. (17): mean over the batch of the squared 2-norm of the error."""
    return ((pred - target) ** 2).sum(dim=-1).mean()
