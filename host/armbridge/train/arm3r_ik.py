"""Train the 3R drawing arm's ANN (Murai, Vairagi, Semwal, Table 2, section 4.2) and ship it.

Data set: `count` joint vectors uniform within the limits and their poses by
FK (eq. 3-4), 150,000 by default (section 4.2.1), split 70 / 15 / 15 into
train / validation / test (section 4.2.2). Network: (x, y, theta) ->
MinMax -> 100 ReLU -> 100 ReLU -> linear -> inverse MinMax -> (q1, q2, q3);
MSE on the scaled outputs, Adam, shuffled, torch's uniform (Kaiming)
initialisation. One deviation from Table 2, measured: a cosine decay of
Adam's rate from `lr` to `lr_final` over the run (a constant 1e-3 leaves the
last epochs' noise in the weights). Export: float ONNX, the better-measuring
of two int8 ONNX schemes and the flat int8 file for boards (`ik.export`),
and the card (`card.json`) with the accuracy on the held-out test split and
on targets in the drawing disc (`ik.arm3r_pipeline.measure`).
"""
from __future__ import annotations

import json
import platform
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from torch import nn

from armbridge.ik import export as ex
from armbridge.ik.arm3r_ann import CARD_NAME, Arm3rANN, fk_samples, flat_int8_predictor, scaler_bounds
from armbridge.ik.arm3r_pipeline import drawing_samples, measure
from armbridge.ik.region import pen_angle, safe_region
from armbridge.ik.masr_nn_train import restore_torch, set_determinism
from armbridge.robots import get_robot

CARD_VERSION = 1


@dataclass
class Arm3rTrainConfig:
    samples: int = 150_000
    epochs: int = 150
    batch: int = 128
    lr: float = 1e-3
    lr_final: float = 1e-5
    seed: int = 0
    max_steps: int = 0  # 0: all epochs
    eval_points: int = 20_000


class Arm3rNet(nn.Module):
    """Table 2's MLP with the MinMax scalers as buffers, so they are part of the ONNX graph."""

    activation = "relu"  # ik.export.write_flat_int8 reads it
    in_min: torch.Tensor  # the scalers' bounds (buffers, registered from `bounds`)
    in_max: torch.Tensor
    out_min: torch.Tensor
    out_max: torch.Tensor

    def __init__(self, bounds: dict[str, list[float]], hidden: int = 100) -> None:
        super().__init__()
        for k, v in bounds.items():
            self.register_buffer(k, torch.tensor(v, dtype=torch.float32))
        self.mlp = nn.Sequential(nn.Linear(3, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                                 nn.Linear(hidden, 3))

    def scaled(self, x: torch.Tensor) -> torch.Tensor:
        """The network on scaled inputs, scaled outputs (what the loss sees)."""
        return self.mlp((x - self.in_min) / (self.in_max - self.in_min))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out_min + self.scaled(x) * (self.out_max - self.out_min)

    def linear_layers(self) -> list[nn.Linear]:
        return [m for m in self.mlp if isinstance(m, nn.Linear)]


def disc_targets(chain: Any) -> str:
    """The card's words for the drawing-disc targets (`ik.region`: the drawing's and the CBF's disc)."""
    reg = safe_region(chain)
    return (f"uniform in the safe region (ik.region) centre [{reg.center[0]:.4f}, {reg.center[1]:.4f}] m radius "
            f"{reg.radius:.4f} m, theta uniform in the pen angle {pen_angle(chain):.4f} +- 0.25 rad")


def disc_accuracy(chain: Any, f_float: Path, schemes: dict[str, Path], f_flat: Path, count: int,
                  seed: int) -> tuple[dict[str, Any], str]:
    """The card's drawing-disc sections (float, both int8 ONNX schemes, the flat int8 file) on
    `count` targets of `drawing_samples`, and the better-measuring int8 scheme."""
    disc = drawing_samples(chain, count, seed)
    floatp = Arm3rANN(chain, {}, f_float).predict
    acc: dict[str, Any] = {"drawing_disc": {**measure(chain, floatp, disc), "targets": disc_targets(chain)}}
    measured = {k: measure(chain, Arm3rANN(chain, {}, v).predict, disc) for k, v in schemes.items()}
    better = min(measured, key=lambda k: measured[k]["ann"]["tip"]["mean_mm"])
    flat_predict = flat_int8_predictor(chain, f_flat)
    acc["int8_onnx"] = {"scheme": better, **measured}
    acc["int8_flat"] = measure(chain, flat_predict, disc)
    acc["int8_flat"]["vs_float_max_abs_rad"] = float(np.abs(flat_predict(disc) - floatp(disc)).max())
    return acc, better


def split(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """70 / 15 / 15 index split (section 4.2.2), seeded."""
    idx = np.random.default_rng([seed, 1]).permutation(n)
    a, b = int(0.7 * n), int(0.85 * n)
    return idx[:a], idx[a:b], idx[b:]


def train(cfg: Arm3rTrainConfig, poses: np.ndarray, q: np.ndarray, tr: np.ndarray, va: np.ndarray,
          bounds: dict[str, list[float]], progress: bool = False,
          log: Callable[[str], None] | None = None) -> tuple[Arm3rNet, dict[str, Any]]:
    """Adam on the MSE of the scaled outputs; returns the model and its history."""
    saved = set_determinism(cfg.seed)
    try:
        model = Arm3rNet(bounds)
        x, y = torch.as_tensor(poses, dtype=torch.float32), torch.as_tensor(q, dtype=torch.float32)
        ys = (y - model.out_min) / (model.out_max - model.out_min)
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
        per_epoch = max(1, -(-len(tr) // cfg.batch))
        total = cfg.epochs * per_epoch if cfg.max_steps <= 0 else min(cfg.max_steps, cfg.epochs * per_epoch)
        history, steps, t0 = [], 0, time.perf_counter()
        gen = torch.Generator().manual_seed(cfg.seed)
        tr_t, va_t = torch.as_tensor(tr), torch.as_tensor(va)
        for epoch in range(cfg.epochs):
            order = tr_t[torch.randperm(len(tr_t), generator=gen)]
            run_loss = 0.0
            for k in range(per_epoch):
                if steps >= total:
                    break
                lr = cfg.lr_final + 0.5 * (cfg.lr - cfg.lr_final) * (1 + np.cos(np.pi * steps / total))
                for g in opt.param_groups:
                    g["lr"] = lr
                b = order[k * cfg.batch:(k + 1) * cfg.batch]
                loss = torch.mean((model.scaled(x[b]) - ys[b]) ** 2)
                opt.zero_grad()
                loss.backward()
                opt.step()
                steps += 1
                run_loss += float(loss.detach())
            with torch.no_grad():
                val = float(torch.mean((model.scaled(x[va_t]) - ys[va_t]) ** 2))
            history.append({"epoch": epoch + 1, "train_mse": run_loss / max(1, k + 1), "val_mse": val,
                            "seconds": round(time.perf_counter() - t0, 1)})
            if progress and log and (epoch % 10 == 9 or steps >= total):
                log(f"epoch {epoch + 1}: train mse {history[-1]['train_mse']:.2e}, val mse {val:.2e}")
            if steps >= total:
                break
        return model.eval(), {"steps": steps, "history": history, "seconds": round(time.perf_counter() - t0, 1)}
    finally:
        restore_torch(saved)


def run(cfg: Arm3rTrainConfig, out: Path, work_dir: Path, command: str = "", progress: bool = False,
        log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Data set, training, export, measurements; writes OUT/card.json and returns the card."""
    chain = get_robot("arm3r")
    say = log or (lambda s: None)
    poses, q = fk_samples(chain, cfg.samples, cfg.seed)
    tr, va, te = split(cfg.samples, cfg.seed)
    bounds = scaler_bounds(chain)
    model, hist = train(cfg, poses, q, tr, va, bounds, progress, log)
    say(f"trained {hist['steps']} steps in {hist['seconds']} s")
    out.mkdir(parents=True, exist_ok=True)
    work_dir.mkdir(parents=True, exist_ok=True)
    f_float = ex.export_float(model, out / "float.onnx", example=torch.as_tensor(poses[:2], dtype=torch.float32))
    schemes = {"weight-only": ex.export_weight_only_int8(model, f_float, work_dir / "int8-weightonly.onnx"),
               "ort-dynamic": ex.export_ort_dynamic_int8(f_float, work_dir / "int8-ortdynamic.onnx")}
    f_flat = ex.write_flat_int8(model, out / "int8.bin")

    with torch.no_grad():
        ref = model(torch.as_tensor(poses[te[:2000]], dtype=torch.float32)).numpy()
    onnx_err = float(np.abs(ex.onnx_run(f_float, poses[te[:2000]]) - ref).max())

    te = te[: cfg.eval_points]
    acc: dict[str, Any] = {
        "test_split": measure(chain, Arm3rANN(chain, {}, f_float).predict, poses[te], q[te]),
        "onnx_vs_torch_max_abs_rad": onnx_err,
    }
    disc, better = disc_accuracy(chain, f_float, schemes, f_flat, cfg.eval_points, cfg.seed + 1)
    acc.update(disc)
    f_int8 = out / "int8.onnx"
    f_int8.write_bytes(schemes[better].read_bytes())
    say("disc: ANN mean tip error {:.2f} mm, + FABRIK {:.4f} mm ({:.1f} % converged)".format(
        acc["drawing_disc"]["ann"]["tip"]["mean_mm"], acc["drawing_disc"]["ann_fabrik"]["tip"]["mean_mm"],
        acc["drawing_disc"]["ann_fabrik"]["converged_pct"]))

    import onnx
    import onnxruntime  # type: ignore[import-untyped]

    card = {
        "card_version": CARD_VERSION,
        "name": "arm3r-ik",
        "kind": "arm3r-ik",
        "description": "ANN of the 3R drawing-arm paper (Murai, Vairagi, Semwal; Table 2): (x, y, theta) -> (q1, q2, q3)",
        "robot": chain.to_dict(),
        "scaling": {"input": ["x (m)", "y (m)", "theta = q1 + q2 + q3, unwrapped (rad)"],
                    "output": ["q1 (rad)", "q2 (rad)", "q3 (rad)"],
                    "features": "MinMax: (input - in_min) / (in_max - in_min); output = out_min + z * (out_max - out_min)",
                    **bounds},
        "architecture": {"inputs": 3, "hidden": [100, 100], "activation": "relu", "outputs": 3,
                         "parameters": int(sum(p.numel() for p in model.parameters()))},
        "training": {**asdict(cfg), "loss": "MSE of the MinMax-scaled joint angles",
                     "optimizer": "Adam, cosine decay from lr to lr_final per step",
                     "split": "70 / 15 / 15 train / validation / test, numpy Generator([seed, 1])",
                     "steps": hist["steps"], "seconds": hist["seconds"], "final_epoch": hist["history"][-1],
                     "command": command, "threads": 1,
                     "versions": {"python": platform.python_version(), "torch": torch.__version__,
                                  "numpy": np.__version__, "onnx": onnx.__version__,
                                  "onnxruntime": onnxruntime.__version__},
                     "machine": f"{platform.machine()} CPU, torch.set_num_threads(1)"},
        "dataset": {"samples": cfg.samples, "seed": cfg.seed,
                    "method": "q uniform within the joint limits (numpy default_rng(seed)), poses by FK eq. (3)-(4)"},
        "accuracy": acc,
        "files": {"onnx": ex.file_entry(f_float, out), "onnx_int8": ex.file_entry(f_int8, out),
                  "int8_flat": ex.file_entry(f_flat, out)},
    }
    (out / CARD_NAME).write_text(json.dumps(card, indent=2) + "\n")
    say(f"wrote {out / CARD_NAME}")
    return card
