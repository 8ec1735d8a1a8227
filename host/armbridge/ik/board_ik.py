"""The ESP32's Cartesian IK (firmware/esp32/ik3r.py + mlp.py), in numpy float64, batched.

What the board does for `X id dur x y theta` (issue 10 section 3), step for step,
so its answers can be checked against this one (tests/test_board_ik.py) and the
bench can measure it (`armbridge bench board-ik`):

1. The safe region: the target (x, y) must lie in the disc IK_REGION_UM (the host's
   `ik.region.safe_region`, h_0 >= 0 of eq. 6); outside, no answer (REACH).
2. The ANN of Table 2 from the flat int8 file (`ik.flat_int8`'s format): MinMax
   features from the config's links and limits exactly as `ik.arm3r_ann.scaler_bounds`
   computes them, then per layer the input vector quantised to integers (`quantise`:
   one scale per vector, |x_q| <= Q_l), an exact integer product with the int8
   weights, then y = scale_row * s_x * acc + bias and the activation. The board does
   the integer part in viper where it has the native emitter; the integers make
   float32 (board) and float64 (here) agree to a rounding of x_q, and the output
   map clipped into the limits.
3. IK_FABRIK_PASSES fixed passes of FABRIK (section 3.6; `ik.fabrik`'s Phase I and
   Phase II with the joint limits, `clip_angle`), with the pen angle theta fixing the
   direction of the last link: Phase I sets the tip on the target and the wrist at
   t - d_3 (cos theta, sin theta) and pulls the other joints back with the limits,
   Phase II sets the root on the base and each angle clipped, q_3 = theta - q_1 - q_2
   clipped. Every pass ends on a configuration inside the limits.
4. No answer when the tip ends farther than IK_TOL_UM from the target.

Q_l = min(32767, (2**30 - 1) // (127 * cols)): the accumulator stays a MicroPython
small int (31 bits) and a viper machine word; 32767 for arm3r's layers.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik.arm3r_ann import scaler_bounds
from armbridge.ik.fabrik import clip_angle
from armbridge.ik.flat_int8 import read_flat_int8
from armbridge.ik.region import SafeRegion
from armbridge.robots.planar import PlanarChain

WEIGHTS_NAME = "int8.bin"  # in models/onnx/arm3r-ik: flashed to the board as cfg.IK_WEIGHTS
ACC_LIMIT = (1 << 30) - 1
Q_MAX = 32767


def quant_levels(cols: int) -> int:
    """Q_l of a layer with `cols` inputs: |acc| <= 127 * Q_l * cols stays below 2**30."""
    return min(Q_MAX, ACC_LIMIT // (127 * cols))


def quantise(h: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Per row of h (B, cols): integers x_q = rint(h * levels / max|h|) and the step s = max|h| / levels."""
    m = np.max(np.abs(h), axis=-1, keepdims=True)
    k = np.where(m > 0, levels / np.where(m > 0, m, 1.0), 0.0)
    return np.rint(h * k).astype(np.int64), np.where(m > 0, m / levels, 0.0)


def activate(h: np.ndarray, code: int) -> np.ndarray:
    """The flat format's activation codes (ik.export's docstring)."""
    if code == 1:
        return np.where(h > 0, h, 0.01 * h)
    if code == 2:
        return np.maximum(h, 0.0)
    if code == 3:
        return np.tanh(h)
    if code == 4:
        return h / (1 + np.exp(-h))
    return h


def board_forward(layers: list[dict[str, Any]], features: np.ndarray, dtype: Any = np.float64) -> np.ndarray:
    """The board's int8 MLP on features (B, n_in) -> (B, n_out), integer products (module
    docstring); float arithmetic in `dtype` (np.float32: the ESP32's floats)."""
    h = np.asarray(features, dtype=dtype)
    for lay in layers:
        xq, step = quantise(h, quant_levels(lay["cols"]))
        acc = (xq @ lay["weight"].astype(np.int64).T).astype(dtype)  # exact: |acc| < 2**30
        h = activate(acc * step * lay["scale"].astype(dtype) + lay["bias"].astype(dtype), lay["activation"])
    return h


def config_chain(cfg: Any) -> PlanarChain:
    """The chain the board knows: link lengths (m) and limits (mrad) of its config."""
    lim = np.asarray(cfg.LIMITS_MRAD, dtype=float) / 1000.0
    n = lim.shape[0]
    return PlanarChain(name=str(getattr(cfg, "FW_NAME", "board")), link_lengths=np.asarray(cfg.LINK_LENGTHS_M, float),
                       q_min=lim[:, 0], q_max=lim[:, 1], v_max=np.ones(n),
                       joint_names=tuple(f"j{i + 1}" for i in range(n)))


@dataclass(frozen=True)
class BoardIKReference:
    """The board's IK for one config and weight file: `solve(targets (B, 3)) -> BoardSolution`."""

    chain: PlanarChain
    region: SafeRegion
    passes: int
    tol: float
    layers: list[dict[str, Any]]

    @classmethod
    def from_config(cls, cfg: Any, weights: Path | None = None) -> "BoardIKReference":
        """From a firmware config (its IK_* constants) and a flat int8 file (default: the shipped one)."""
        chain = config_chain(cfg)
        if chain.n != 3:
            raise ArmbridgeError(f"the board IK is for a 3-joint arm; this config has {chain.n} joints")
        cx, cy, r = (float(v) * 1e-6 for v in cfg.IK_REGION_UM)
        layers = read_flat_int8(Path(weights) if weights is not None else shipped_weights())
        return cls(chain, SafeRegion((cx, cy), r), int(cfg.IK_FABRIK_PASSES), float(cfg.IK_TOL_UM) * 1e-6, layers)

    def net(self, poses: np.ndarray, dtype: Any = np.float64) -> np.ndarray:
        """Step 2: the int8 net's q (B, 3) for poses (B, 3) = (x, y, theta), clipped into the limits."""
        b = {k: np.asarray(v, dtype=dtype) for k, v in scaler_bounds(self.chain).items()}
        z = board_forward(self.layers, (np.asarray(poses, dtype) - b["in_min"]) / (b["in_max"] - b["in_min"]), dtype)
        return np.clip(b["out_min"] + z * (b["out_max"] - b["out_min"]), b["out_min"], b["out_max"])

    def refine(self, poses: np.ndarray, q0: np.ndarray, passes: int | None = None,
               dtype: Any = np.float64) -> np.ndarray:
        """Step 3: fixed FABRIK passes from q0 with the last link along theta; q (B, 3) in the limits."""
        d = self.chain.link_lengths.astype(dtype)
        lo, hi = self.chain.q_min.astype(dtype), self.chain.q_max.astype(dtype)
        poses = np.asarray(poses, dtype)
        t, th = poses[:, :2], poses[:, 2]
        q = np.asarray(q0, dtype).copy()
        p1 = d[0] * _dirs(q[:, 0])
        wrist = t - d[2] * _dirs(th)
        for _ in range(self.passes if passes is None else passes):
            # Phase I: tip on t, wrist fixed by theta, the elbow pulled back, limits on q3 and q2
            v = wrist - p1
            h2 = th - clip_angle(th - np.arctan2(v[:, 1], v[:, 0]), lo[2], hi[2])
            p1 = wrist - d[1] * _dirs(h2)
            # Phase II: root on the base, each angle clipped, the last link along theta
            q1 = clip_angle(np.arctan2(p1[:, 1], p1[:, 0]), lo[0], hi[0])
            p1 = d[0] * _dirs(q1)
            v = wrist - p1
            q2 = clip_angle(np.arctan2(v[:, 1], v[:, 0]) - q1, lo[1], hi[1])
            q3 = clip_angle(th - q1 - q2, lo[2], hi[2])
            q = np.stack([q1, q2, q3], axis=-1)
        return q

    def solve(self, poses: Any, dtype: Any = np.float64) -> "BoardSolution":
        """Steps 1-4 on targets (B, 3) = (x_m, y_m, theta_rad); float arithmetic in `dtype`
        (np.float32 models the chip's rounding; the tip error is measured in float64)."""
        poses = np.asarray(poses, dtype=float)
        if poses.ndim != 2 or poses.shape[1] != 3:
            raise ArmbridgeError(f"board IK targets must have shape (B, 3) for (x, y, theta), got {poses.shape}")
        inside = self.region.contains(poses[:, :2])
        q = self.refine(poses, self.net(poses, dtype), dtype=dtype).astype(float)
        err = np.linalg.norm(self.chain.ee_point(q) - poses[:, :2], axis=-1)
        return BoardSolution(q=q, error=err, inside=inside, ok=inside & (err <= self.tol))


@dataclass(frozen=True)
class BoardSolution:
    """Per target: q (B, 3), tip error (m), inside the safe disc, answered (inside and within tol)."""

    q: np.ndarray
    error: np.ndarray
    inside: np.ndarray
    ok: np.ndarray


def _dirs(angle: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1)


def shipped_weights() -> Path:
    """models/onnx/arm3r-ik/int8.bin, the file the board is flashed with."""
    from armbridge.boards.files import config_file

    return config_file("IK_WEIGHTS")  # the board's config names it: boards/files.py CONFIG_FILES


def firmware_config() -> Any:
    """The ESP32 firmware's constants (boards.config: its config module read as data)."""
    from armbridge import boards

    return boards.config("esp32")
