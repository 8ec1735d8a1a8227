"""The ANN of the 3R drawing arm (Murai, Vairagi, Semwal, section 3.7 and Table 2).

`(x, y, theta) -> (q1, q2, q3)`: three inputs, two hidden layers of 100 ReLU
units, a linear output, MinMax scaling of inputs and outputs (Table 2) inside
the ONNX graph, so a caller feeds metres and radians and gets radians. Trained
by `armbridge.train.arm3r_ik` on forward kinematics, eq. (3)-(4), of joint
angles drawn uniformly within the arm's limits (section 4.2.1: 150,000 pairs).

theta is the raw sum q1 + q2 + q3 (eq. 4), not wrapped: on `arm3r` it spans
[-3 pi / 2, 3 pi / 2], and with q2 <= 0 the inverse map is single-valued, so a
plain MLP can learn it (one elbow branch; q1 and q3 have one copy in their
limits). Inference is numpy + onnxruntime only, no torch.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.robots.planar import PlanarChain

#: Where the shipped model lives below resources.models_dir().
MODEL_DIR = "arm3r-ik"
CARD_NAME = "card.json"


def fk_samples(chain: PlanarChain, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """`count` joint vectors uniform in the limits and their poses (x, y, theta), eq. (3)-(4).

    Returns (poses (count, 3), q (count, 3)); theta = q1 + q2 + q3 unwrapped.
    The same (count, seed) always gives the same arrays (numpy default_rng).
    """
    if count <= 0:
        raise ArmbridgeError(f"a data set needs at least one sample, got {count}")
    rng = np.random.default_rng(seed)
    q = chain.q_min + rng.random((count, chain.n)) * (chain.q_max - chain.q_min)
    return poses_of(chain, q), q


def poses_of(chain: PlanarChain, q: np.ndarray) -> np.ndarray:
    """(x, y, theta) of q with theta the unwrapped joint sum: the network's input, eq. (3)-(4)."""
    return np.concatenate([chain.ee_point(q), q.sum(axis=-1, keepdims=True)], axis=-1)


def scaler_bounds(chain: PlanarChain) -> dict[str, list[float]]:
    """MinMaxScaler ranges of Table 2, from the limits rather than the sample (so they are exact
    and a fresh sample maps into [0, 1] too): inputs x, y in [-reach, reach], theta in
    [sum q_min, sum q_max]; outputs q in [q_min, q_max]."""
    r = chain.reach
    return {"in_min": [-r, -r, float(chain.q_min.sum())], "in_max": [r, r, float(chain.q_max.sum())],
            "out_min": chain.q_min.tolist(), "out_max": chain.q_max.tolist()}


def tip_errors(chain: PlanarChain, q: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Distance (m) of the tip at q from the target points xy, shape (...)."""
    return np.linalg.norm(chain.ee_point(q) - xy, axis=-1)


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def flat_int8_predictor(chain: PlanarChain, flat_path: Path) -> Callable[[np.ndarray], np.ndarray]:
    """poses (B, 3) -> q (B, 3) by the flat int8 file (what the board runs): the Table 2
    MinMax scalers from the limits (`scaler_bounds`), the int8 MLP, clipped into the limits."""
    from armbridge.ik.flat_int8 import flat_int8_forward, read_flat_int8

    layers = read_flat_int8(flat_path)
    b = {k: np.asarray(v) for k, v in scaler_bounds(chain).items()}

    def predict(p: np.ndarray) -> np.ndarray:
        z = flat_int8_forward(layers, (np.asarray(p, dtype=float) - b["in_min"]) / (b["in_max"] - b["in_min"]))
        return np.clip(b["out_min"] + z * (b["out_max"] - b["out_min"]), chain.q_min, chain.q_max)

    return predict


def shipped_card() -> Path:
    """The card of the shipped model (models/onnx/arm3r-ik/card.json)."""
    from armbridge import resources

    return resources.models_dir() / MODEL_DIR / CARD_NAME


@dataclass
class Arm3rANN:
    """The network of a model card: `predict(poses) -> q`, within the joint limits."""

    chain: PlanarChain
    card: dict[str, Any]
    onnx_path: Path
    threads: int = 1
    _session: Any = field(default=None, repr=False)

    @classmethod
    def load(cls, card_path: str | Path | None = None, int8: bool = False, verify: bool = True,
             threads: int = 1) -> "Arm3rANN":
        """The card (default: the shipped one) and its float or int8 ONNX model, sha256 checked."""
        card_path = Path(shipped_card() if card_path is None else card_path)
        try:
            card = json.loads(card_path.read_text())
            entry = card["files"]["onnx_int8" if int8 else "onnx"]
            chain = PlanarChain.from_dict(card["robot"])
        except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
            raise ArmbridgeError(f"cannot read model card {card_path}: {exc!r}") from None
        path = card_path.parent / entry["path"]
        if verify:
            try:
                digest = sha256(path)
            except OSError as exc:
                raise ArmbridgeError(f"cannot read model {path}: {exc.strerror}") from None
            if digest != entry["sha256"]:
                raise ArmbridgeError(f"{path}: sha256 {digest[:12]}... does not match its card ({entry['sha256'][:12]}...)")
        return cls(chain, card, path, threads)

    @property
    def session(self) -> Any:
        if self._session is None:
            import onnxruntime as ort  # type: ignore[import-untyped]

            opts = ort.SessionOptions()
            opts.intra_op_num_threads = self.threads
            opts.inter_op_num_threads = 1
            self._session = ort.InferenceSession(str(self.onnx_path), opts, providers=["CPUExecutionProvider"])
        return self._session

    def predict(self, poses: Any) -> np.ndarray:
        """Joint angles (..., 3) for poses (..., 3) = (x, y, theta), clipped into the limits."""
        poses = np.asarray(poses, dtype=float)
        if poses.ndim == 0 or poses.shape[-1] != 3:
            raise ArmbridgeError(f"the 3R ANN takes poses of shape (..., 3) for (x, y, theta), got {poses.shape}")
        flat = np.ascontiguousarray(poses.reshape(-1, 3), dtype=np.float32)
        out = self.session.run(None, {self.session.get_inputs()[0].name: flat})[0].astype(float)
        return np.clip(out, self.chain.q_min, self.chain.q_max).reshape(poses.shape)
