"""A learned SMM's torch networks packed small: weight-only int8 regressors in files of bounded size.

Why: the 7R's model (one regressor per cluster, outputs B x n x K x 2 per
location) came to 180 MB as float32 ONNX (docs/smm.md), and a lent GPU run
sends back at most 8 files of 16 MiB. Weight matrices of the regressors are
stored as int8 with one float32 scale per output row (w = scale * q,
scale = max|row| / 127): 4x smaller than float32, and far more accurate than
full int8 quantisation for MLPs this size (docs/notes: 0.02 against 0.36 max
error on a test MLP); biases, the input box and the output scaling stay
float32. The classifier stays float32: a branch-count error costs more than a
coefficient's rounding, and it is small.

Files: PREFIX.json (the architecture, the caller's metadata, the file list)
and PREFIX-<i>.npz, each at most max_bytes; `unpack` rebuilds the
networks (dequantised, float32) and `TorchSession` runs one in place of an
onnxruntime session, so LearnedSmm (smm/learned.py) measures the packed
model with the same code as a shipped one. ONNX export of the unpacked
networks is train/smm.export_all's (it needs onnxscript, which a lent GPU
machine may lack).
"""
from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from armbridge.errors import ArmbridgeError
from armbridge.smm import networks as nets

FORMAT = "armbridge-smm-packed/1"


def quantise(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weight-only int8 of a matrix (out, in): (q int8, scale float32 per row), w ~ scale[:, None] * q."""
    w = np.asarray(w, dtype=np.float32)
    scale = np.abs(w).max(axis=1) / 127.0
    scale = np.where(scale > 0, scale, 1.0).astype(np.float32)
    return np.clip(np.rint(w / scale[:, None]), -127, 127).astype(np.int8), scale


def _arrays(name: str, model: torch.nn.Module, int8: bool) -> dict[str, np.ndarray]:
    out = {}
    for key, t in model.state_dict().items():
        a = t.detach().cpu().float().numpy()
        if int8 and a.ndim == 2:
            out[f"{name}/{key}"], out[f"{name}/{key}.scale"] = quantise(a)
        else:
            out[f"{name}/{key}"] = a
    return out


def pack(classifier: nets.SmmClassifier, regressors: dict[int, nets.SmmRegressor], meta: dict[str, Any], out: Path,
         prefix: str = "model", max_bytes: int = 15 * 2**20) -> list[Path]:
    """Write the networks to out/PREFIX.json + out/PREFIX-<i>.npz (each <= max_bytes); the paths written."""
    out.mkdir(parents=True, exist_ok=True)
    nets_arrays = [("classifier", _arrays("classifier", classifier, int8=False))]
    nets_arrays += [(f"regressor-{c}", _arrays(f"regressor-{c}", m, int8=True)) for c, m in sorted(regressors.items())]
    files: list[dict[str, np.ndarray]] = [{}]
    size = 0
    for _, arrays in nets_arrays:
        n = sum(a.nbytes + 200 for a in arrays.values())  # npz: a header per array
        if n > max_bytes:
            raise ArmbridgeError(f"one network needs {n} bytes, more than a file's {max_bytes}")
        if size + n > max_bytes and files[-1]:
            files.append({})
            size = 0
        files[-1].update(arrays)
        size += n
    paths = []
    for i, arrays in enumerate(files):
        p = out / f"{prefix}-{i}.npz"
        np.savez(p, **arrays)  # type: ignore[arg-type]  # (numpy's stub types **kwds as its keywords)
        paths.append(p)
    card = {"format": FORMAT, **meta, "periodic": list(classifier.periodic),
            "classifier": {"hidden": _hidden(classifier), "outputs": _outputs(classifier)},
            "regressors": {str(c): {"hidden": _hidden(m), "outputs": _outputs(m)} for c, m in sorted(regressors.items())},
            "files": [p.name for p in paths]}
    (out / f"{prefix}.json").write_text(json.dumps(card, indent=1) + "\n")
    return [out / f"{prefix}.json"] + paths


def _linears(model: torch.nn.Module) -> list[torch.nn.Linear]:
    return [m for m in model.modules() if isinstance(m, torch.nn.Linear)]


def _hidden(model: torch.nn.Module) -> list[int]:
    return [m.out_features for m in _linears(model)[:-1]]


def _outputs(model: torch.nn.Module) -> int:
    return int(_linears(model)[-1].out_features)


def unpack(folder: Path, prefix: str = "model") -> tuple[nets.SmmClassifier, dict[int, nets.SmmRegressor], dict[str, Any]]:
    """The networks of pack's files (float32, int8 weights dequantised) and the metadata."""
    path = Path(folder) / f"{prefix}.json"
    try:
        card = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ArmbridgeError(f"{path}: not a packed SMM model ({e})") from None
    if card.get("format") != FORMAT:
        raise ArmbridgeError(f"{path}: format {card.get('format')!r}, expected {FORMAT!r}")
    arrays: dict[str, np.ndarray] = {}
    for name in card["files"]:
        with np.load(Path(folder) / name) as z:
            arrays.update({k: z[k] for k in z.files})

    def state(net: str) -> dict[str, torch.Tensor]:
        out = {}
        for k, a in arrays.items():
            if not k.startswith(net + "/") or k.endswith(".scale"):
                continue
            key = k[len(net) + 1:]
            scale = arrays.get(k + ".scale")
            out[key] = torch.as_tensor(a.astype(np.float32) * scale[:, None] if scale is not None else a)
        return out

    lo = np.zeros(len(card["lo"]), np.float32)
    periodic = card.get("periodic")  # packs before the (cos, sin) inputs have none: no periodic inputs
    clf = nets.SmmClassifier(lo, lo + 1, card["classifier"]["hidden"], card["classifier"]["outputs"], periodic)
    clf.load_state_dict(state("classifier"))
    regs = {}
    for c, r in card["regressors"].items():
        m = nets.SmmRegressor(lo, lo + 1, r["hidden"], np.zeros(r["outputs"], np.float32), 1.0, periodic)
        m.load_state_dict(state(f"regressor-{c}"))
        regs[int(c)] = m.eval()
    return clf.eval(), regs, card


class TorchSession:
    """A torch network where LearnedSmm expects an onnxruntime session (its input "canon", float32)."""

    class _Input:
        name = "canon"

    def __init__(self, model: torch.nn.Module, device: torch.device | str = "cpu") -> None:
        self.model, self.device = model.eval().to(device), torch.device(device)

    def get_inputs(self) -> list[Any]:
        return [self._Input()]

    def run(self, _: Any, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        with torch.no_grad():
            x = torch.as_tensor(np.ascontiguousarray(feeds["canon"], dtype=np.float32), device=self.device)
            return [self.model(x).cpu().numpy()]


def learned(arm_name: str, branches: np.ndarray, K: int, classifier: torch.nn.Module,
            regressors: Mapping[int, torch.nn.Module], device: torch.device | str = "cpu") -> Any:
    """A LearnedSmm over torch networks (TorchSession), for measuring a model before or without export."""
    from armbridge.smm.arms import get_smm_arm
    from armbridge.smm.learned import LearnedSmm

    card = {"robot": arm_name, "clusters": {"branches": [int(b) for b in branches]}, "fourier": {"K": int(K)}}
    return LearnedSmm(get_smm_arm(arm_name), card, TorchSession(classifier, device),
                      {int(c): TorchSession(m, device) for c, m in regressors.items()})
