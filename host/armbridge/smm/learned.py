"""SMMs from the learned networks (section V-D), with the eq. (18) correction.

    smm = LearnedSmm.load("models/onnx/smm-planar3r")
    s = smm.compute(x, n_points=128, correct_iters=3)   # x (L, m) -> SmmSet

Per batch of locations: canonical coordinates (joint-1 symmetry removed) ->
classifier argmax -> cluster -> that cluster's regressor on its locations only
-> Fourier coefficients -> q += shift (theta_1 += phi, and theta_7 += psi for
the 7R: a phase factor on those joints' series) -> inverse transform (eq. 10).
Clusters with no branches (out of reach) give count 0. Then, optionally, a few
steps of q += J^+ Delta x_e (eq. 18) on every point of every branch at once.

The networks run in onnxruntime (CPU), the kinematics and the correction in
numpy float64: inference needs no torch (the `train` extra). The learned
method cannot see singular configurations, so `singular` is all False.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.smm.arms import SmmArm, get_smm_arm
from armbridge.smm.correction import correct
from armbridge.smm.manifold import SmmSet

CARD_NAME = "card.json"
KIND = "smm-learned"
CARD_VERSION = 1


def read_card(folder: Path, robot: str | None = None) -> dict[str, Any]:
    """The model card of a learned-SMM folder, checked for kind and (optionally) robot."""
    path = Path(folder) / CARD_NAME
    try:
        card = json.loads(path.read_text())
    except FileNotFoundError:
        raise ArmbridgeError(f"{folder}: no {CARD_NAME}; train one with `armbridge train smm-3r|smm-4r|smm-7r`") from None
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ArmbridgeError(f"{path}: not a readable model card ({exc})") from None
    if not isinstance(card, dict) or card.get("kind") != KIND:
        kind = card.get("kind") if isinstance(card, dict) else type(card).__name__
        raise ArmbridgeError(f"{path}: kind is {kind!r}, expected {KIND!r}")
    if card.get("card_version") != CARD_VERSION:
        raise ArmbridgeError(f"{path}: card_version {card.get('card_version')!r}, this reader knows {CARD_VERSION}")
    for key, sub in (("robot", None), ("fourier", "K"), ("clusters", "branches"), ("files", "classifier"),
                     ("files", "regressors")):
        if key not in card or (sub is not None and not (isinstance(card[key], dict) and sub in card[key])):
            raise ArmbridgeError(f"{path}: missing field {key + ('.' + sub if sub else '')!r}")
    if robot is not None and card["robot"] != robot:
        raise ArmbridgeError(f"{path}: the model is for robot {card['robot']!r}, not {robot!r}")
    return card


def _session(folder: Path, entry: dict[str, Any], threads: int, verify: bool) -> Any:
    """An onnxruntime CPU session of a file named in the card, its sha256 checked."""
    import onnxruntime as ort  # type: ignore[import-untyped]

    path = Path(folder) / entry["path"]
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ArmbridgeError(f"{path}: cannot read the model file named in the card ({exc.strerror})") from None
    if verify and hashlib.sha256(data).hexdigest() != entry["sha256"]:
        raise ArmbridgeError(f"{path}: sha256 does not match its card (file changed or corrupt)")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    try:
        return ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # noqa: BLE001  (onnxruntime raises its own exception types for bad graphs)
        raise ArmbridgeError(f"{path}: not a loadable ONNX model ({str(exc).splitlines()[0]})") from None


def _run(session: Any, canon: np.ndarray) -> np.ndarray:
    name = session.get_inputs()[0].name
    return session.run(None, {name: np.ascontiguousarray(canon, dtype=np.float32)})[0]


def scatter(parts: list[tuple[np.ndarray, np.ndarray]], count: np.ndarray, bmax: int, n_points: int, n: int) -> np.ndarray:
    """(L, Bmax, N, n) NaN-padded from per-cluster (rows, points (M, B, N, n))."""
    out = np.full((count.size, bmax, n_points, n), np.nan)
    for rows, pts in parts:
        out[rows, : pts.shape[1]] = pts
    return out


@dataclass
class LearnedSmm:
    """The classifier and per-cluster regressors of one model folder (see module doc)."""

    arm: SmmArm
    card: dict[str, Any]
    classifier: Any
    regressors: dict[int, Any]
    threads: int = 1

    @classmethod
    def load(cls, folder: str | Path, robot: str | None = None, threads: int = 1, verify: bool = True) -> LearnedSmm:
        """Read FOLDER/card.json and its ONNX files.

        `threads`: onnxruntime intra-op threads. 1 is fastest on a busy 2-core
        machine: small ops stall when a second thread has to wait for a core.
        """
        folder = Path(folder)
        if threads < 1:
            raise ArmbridgeError(f"threads must be >= 1, got {threads}")
        card = read_card(folder, robot)
        files = card["files"]
        classifier = _session(folder, files["classifier"], threads, verify)
        regressors = {int(c): _session(folder, e, threads, verify) for c, e in files["regressors"].items()}
        branches = card["clusters"]["branches"]
        missing = [c for c, b in enumerate(branches) if b > 0 and c not in regressors]
        if missing:
            raise ArmbridgeError(f"{folder / CARD_NAME}: clusters {missing} have branches but no regressor file")
        return cls(get_smm_arm(card["robot"]), card, classifier, regressors, threads)

    @property
    def branches(self) -> np.ndarray:
        """Branch count of every cluster (0 = out of reach)."""
        return np.asarray(self.card["clusters"]["branches"], dtype=np.int64)

    def classify(self, canon: np.ndarray) -> np.ndarray:
        """Cluster of every canonical location: argmax of the classifier's logits (eq. 16)."""
        return np.argmax(_run(self.classifier, canon), axis=1)

    def coefficients(self, cluster: int, canon: np.ndarray) -> np.ndarray:
        """Fourier coefficients (M, B, n, K) complex of the branches of locations in `cluster`."""
        from armbridge.smm.fourier import target_to_coeffs

        return target_to_coeffs(_run(self.regressors[cluster], canon), int(self.branches[cluster]), self.arm.n,
                                int(self.card["fourier"]["K"]))

    def compute(self, x: Any, n_points: int = 128, correct_iters: int = 0) -> SmmSet:
        """SMMs of the locations x (L, m), each branch sampled at n_points configurations."""
        from armbridge.smm.fourier import decode

        arm = self.arm
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != arm.m:
            raise ArmbridgeError(f"locations for {arm.name} must be (L, {arm.m}), got shape {x.shape}")
        if not np.isfinite(x).all():
            raise ArmbridgeError(f"locations for {arm.name} must be finite numbers")
        if n_points < 2 or correct_iters < 0:
            raise ArmbridgeError(f"n_points must be >= 2 and correct_iters >= 0, got {n_points} and {correct_iters}")
        canon, shift = arm.canonical(x)
        cluster = self.classify(canon)
        count = self.branches[cluster]
        parts = []
        for c in np.unique(cluster[count > 0]):
            rows = np.flatnonzero(cluster == c)
            coeffs = self.coefficients(int(c), canon[rows])
            # q += shift (uncanonical) as the factor exp(j shift_i) on joint i's series: T of eq. (7) is
            # multiplicative, so decode's atan2 returns the wrapped sum
            coeffs *= np.exp(1j * shift[rows]).astype(coeffs.dtype)[:, None, :, None]
            parts.append((rows, decode(coeffs, n_points=n_points)))
        points = scatter(parts, count, int(self.branches.max(initial=0)), n_points, arm.n)
        if correct_iters > 0 and count.any():
            valid = np.arange(points.shape[1])[None, :] < count[:, None]  # (L, Bmax)
            q = points[valid].reshape(-1, arm.n)
            target = np.repeat(x[np.nonzero(valid)[0]], n_points, axis=0)
            points[valid] = correct(arm, q, target, correct_iters).reshape(-1, n_points, arm.n)
        return SmmSet(points=points, count=count, singular=np.zeros(len(x), dtype=bool))
