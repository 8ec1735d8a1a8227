"""The learned-SMM pipeline: data set -> classifier and per-cluster regressors
-> ONNX -> measured accuracy on held-out locations -> card.

Used by `armbridge train smm-3r|smm-4r|smm-7r`. `run` puts the stages
together: the data set, checked and split (train/smm_data.py), the networks
trained (train/smm_fit.py: section VI-A, resumable), then what this module
holds: the export to ONNX (checked against torch), the accuracy measured on
the held-out locations through the files as shipped (Table III's metrics),
and the card that records all of it.

Files in the output folder: classifier.onnx, regressor-<c>.onnx for every
cluster c with branches, card.json. One regressor file per cluster because
inference runs each regressor only on the locations classified into its
cluster; one graph holding them all would run every regressor on every
location (or need control flow in the graph).
"""
from __future__ import annotations

import json
import platform
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from armbridge.errors import ArmbridgeError
from armbridge.smm import networks as nets
from armbridge.smm.arms import SmmArm, get_smm_arm
from armbridge.smm.dataset import SmmDataset
from armbridge.smm.learned import CARD_NAME, CARD_VERSION, KIND, LearnedSmm
from armbridge.smm.manifold import SmmSet
from armbridge.train.smm_data import check_dataset, split
from armbridge.train.smm_fit import Log, SmmTrainConfig, Trained, train

ROBOTS = {"smm-3r": "planar3r", "smm-4r": "spatial4r", "smm-7r": "spatial7r"}


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
