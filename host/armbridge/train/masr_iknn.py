"""The MASR IK-NN pipeline: data set -> training -> export -> measured accuracy -> card.

Used by `armbridge train masr-iknn`; every step is a function so tests can run
the pipeline on a tiny grid for a few steps.
"""
from __future__ import annotations

import json
import platform
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from armbridge.errors import ArmbridgeError

CARD_VERSION = 1


@dataclass
class PipelineConfig:
    robot: str = "masr5"
    name: str = ""  # default: ROBOT-iknn
    nx: int = 1800
    ny: int = 1600
    rho: int = 10
    max_samples: int = 10_000_000
    data_seed: int = 0
    out: Path = Path("runs/masr-iknn/model")  # the shipped models: resources.models_dir()
    work_dir: Path = Path("runs/masr-iknn")
    eval_trials: int = 5000
    eval_seed: int = 20240501
    nr_trials: int = 0
    nr_restarts: int = 1000
    refine_iters: int = 8
    int8_epochs: int = 2
    int8_lr: float = 3e-4
    command: str = ""
    train: Any = None  # masr_nn_train.TrainConfig
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def model_name(self) -> str:
        return self.name or f"{self.robot}-iknn"


def _say(log: Callable[[str], None] | None, msg: str) -> None:
    if log:
        log(msg)


def build_dataset(cfg: PipelineConfig, log: Callable[[str], None] | None = None, runner: Any = None) -> Any:
    from armbridge.ik.masr_data import GridSpec, load_or_generate
    from armbridge.robots import get_masr

    arm = get_masr(cfg.robot)
    spec = GridSpec(nx=cfg.nx, ny=cfg.ny, rho=cfg.rho, max_samples=cfg.max_samples, seed=cfg.data_seed)
    t0 = time.perf_counter()
    ds, cached = load_or_generate(arm, spec, cfg.work_dir / "cache", runner=runner)
    info = ds.info()
    _say(log, f"data set: {info['size']} poses from {info['samples']} samples "
              f"(largest enclosed vacancy {info['largest_enclosed_vacancy_cells']} cells, rho {cfg.rho}; "
              f"{'cached' if cached else f'{time.perf_counter() - t0:.1f} s'})")
    if not ds.converged:
        _say(log, f"note: density rho={cfg.rho} not reached within {cfg.max_samples} samples; using what was sampled")
    return ds


def measure(arm: Any, solver: Callable[[np.ndarray, np.ndarray], np.ndarray], trials: int, seed: int) -> dict[str, Any]:
    from armbridge.ik.masr_ik import evaluate, random_trials

    x_goal, q0 = random_trials(arm, trials, seed)
    t0 = time.perf_counter()
    q = solver(x_goal, q0)
    dt = time.perf_counter() - t0
    out = evaluate(arm, x_goal, q0, q)
    out["batched_ms_per_query"] = dt / trials * 1e3
    return out


def run(cfg: PipelineConfig, resume: bool = False, progress: bool = True,
        log: Callable[[str], None] | None = None, runner: Any = None) -> dict[str, Any]:
    """Run the whole pipeline; returns the card (also written to OUT/NAME-card.json).

    runner (armbridge.shards.Runner): where the data set's sampling shards run (None: here)."""
    import torch

    from armbridge.ik import export as ex
    from armbridge.ik.masr_ik import MasrIK, refine
    from armbridge.ik.masr_nn_train import finetune_int8, train
    from armbridge.robots import get_masr

    arm = get_masr(cfg.robot)
    tcfg = cfg.train
    ds = build_dataset(cfg, log, runner)
    if runner is not None:
        runner.close()  # a Ray it started has done its part: training runs here
    cfg.work_dir.mkdir(parents=True, exist_ok=True)
    ckpt = cfg.work_dir / f"{cfg.model_name}.pt"
    res = train(arm, ds.poses, tcfg, checkpoint=ckpt, resume=resume, progress=progress,
                log=lambda s: _say(log, s))
    model = res.model
    total_seconds = res.history[-1]["seconds"] if res.history else res.seconds
    _say(log, f"trained {res.steps} steps, last epoch loss {res.history[-1]['loss']:.5f}" if res.history else "trained")

    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    name = cfg.model_name
    f_float = ex.export_float(model, out / f"{name}-float.onnx")
    tmp_w = cfg.work_dir / f"{name}-int8-weightonly.onnx"
    tmp_o = cfg.work_dir / f"{name}-int8-ortdynamic.onnx"
    ex.export_weight_only_int8(model, f_float, tmp_w)
    ex.export_ort_dynamic_int8(f_float, tmp_o)
    q_model, qat = None, None
    if cfg.int8_epochs > 0:
        qat = finetune_int8(arm, model, ds.poses, tcfg, cfg.int8_epochs, cfg.int8_lr, log=log)
        q_model = qat.model
        tmp_qf = cfg.work_dir / f"{name}-qat-float.onnx"
        tmp_q = cfg.work_dir / f"{name}-int8-weightonly-qat.onnx"
        ex.export_float(q_model, tmp_qf)
        ex.export_weight_only_int8(q_model, tmp_qf, tmp_q)

    # torch vs ONNX agreement on random inputs
    from armbridge.ik.masr_ik import random_trials

    xg, q0 = random_trials(arm, 2000, 7)
    inp = np.concatenate([xg, q0], axis=1).astype(np.float32)
    with torch.no_grad():
        ref = model(torch.as_tensor(inp)).numpy()
    onnx_err = float(np.abs(ex.onnx_run(f_float, inp) - ref).max())

    def onnx_solver(path: Path) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        ik = MasrIK(arm, {}, path)
        return ik.predict

    acc: dict[str, Any] = {
        "protocol": ("Table I: trials with q0 uniform in C_f and x_goal = f(q) for an independent uniform q in C_f; "
                     "success = dp <= 8 mm and |dphi| <= 4 deg (eq. 9); action time = c(q0 -> q), eq. (8)"),
        "trials": cfg.eval_trials,
        "seed": cfg.eval_seed,
        "onnx_vs_torch_max_abs": onnx_err,
    }
    nn_solver = onnx_solver(f_float)
    acc["nn"] = measure(arm, nn_solver, cfg.eval_trials, cfg.eval_seed)
    acc["nn_hold_distal"] = measure(arm, lambda x, q: refine(arm, x, nn_solver(x, q), iters=0, q_c=q),
                                    cfg.eval_trials, cfg.eval_seed)
    acc["nn_refined"] = measure(arm, lambda x, q: refine(arm, x, nn_solver(x, q), iters=cfg.refine_iters, q_c=q),
                                cfg.eval_trials, cfg.eval_seed)
    acc["nn_refined"]["refine_iters"] = cfg.refine_iters
    schemes = {"weight-only": tmp_w, "ort-dynamic": tmp_o}
    if q_model is not None:
        schemes["weight-only-qat"] = tmp_q
    measured = {k: measure(arm, onnx_solver(v), cfg.eval_trials, cfg.eval_seed) for k, v in schemes.items()}
    better = max(measured, key=lambda k: (measured[k]["success_rate"], -measured[k]["mean_dp_mm"]))
    f_int8 = out / f"{name}-int8.onnx"
    f_int8.write_bytes(schemes[better].read_bytes())
    acc["int8_onnx"] = {"scheme": better, **measured}
    if qat is not None:
        acc["int8_onnx"]["qat"] = {"epochs": cfg.int8_epochs, "lr": cfg.int8_lr, "steps": qat.steps,
                                   "seconds": round(qat.seconds, 1), "history": qat.history,
                                   "how": "quantisation-aware fine-tune of the float model: per-row int8 weights "
                                          "in the forward pass, straight-through gradients, same loss and data"}
    # the board file is weight-only int8: from the fine-tuned weights when they measured better
    use_qat = q_model is not None and (measured["weight-only-qat"]["success_rate"], -measured["weight-only-qat"]["mean_dp_mm"]) >= (
        measured["weight-only"]["success_rate"], -measured["weight-only"]["mean_dp_mm"])
    f_flat = ex.write_flat_int8(q_model if use_qat and q_model is not None else model, out / f"{name}-int8.bin")
    acc["int8_flat_weights"] = "weight-only-qat" if use_qat else "weight-only"
    acc["int8_onnx_refined"] = measure(arm, lambda x, q: refine(arm, x, onnx_solver(f_int8)(x, q), iters=cfg.refine_iters, q_c=q),
                                       cfg.eval_trials, cfg.eval_seed)
    card_scaling = model.scaling.describe()
    layers = ex.read_flat_int8(f_flat)
    acc["int8_flat"] = measure(arm, lambda x, q: ex.flat_int8_solve(layers, {"scaling": card_scaling}, x, q),
                               cfg.eval_trials, cfg.eval_seed)
    # single-query latency of the float model in onnxruntime
    one_x, one_q = xg[:1], q0[:1]
    nn_solver(one_x, one_q)
    t0 = time.perf_counter()
    for i in range(200):
        nn_solver(xg[i : i + 1], q0[i : i + 1])
    acc["single_query_ms"] = (time.perf_counter() - t0) / 200 * 1e3
    if cfg.nr_trials > 0:
        from armbridge.ik.masr_nr import MasrNR

        nr = MasrNR(arm, restarts=cfg.nr_restarts, seed=cfg.eval_seed)
        acc["nr"] = measure(arm, nr.solve, cfg.nr_trials, cfg.eval_seed)
        acc["nr"].update(nr.describe())
    for k in ("nn", "nn_hold_distal", "nn_refined", "int8_flat", "int8_onnx_refined", *(("nr",) if "nr" in acc else ())):
        _say(log, f"{k}: " + json.dumps({a: round(b, 3) if isinstance(b, float) else b for a, b in acc[k].items()}))

    import onnx
    import onnxruntime  # type: ignore[import-untyped]

    card: dict[str, Any] = {
        "card_version": CARD_VERSION,
        "name": name,
        "kind": "masr-iknn",
        "description": ("IK-NN of the masr paper (section III): g(x_goal, q_c) -> q, trained only through the "
                        "differentiable FK with loss (10) and the action-time regulariser (12)"
                        if tcfg.reg == "action" else "IK-NN with the joint regulariser (11)"),
        "robot": arm.to_dict(),
        "scaling": card_scaling,
        "architecture": {"inputs": 3 + arm.n + 1, "features": 4 + arm.n + 1, "hidden": list(tcfg.hidden),
                         "activation": tcfg.activation, "outputs": arm.n + 1,
                         "parameters": int(sum(p.numel() for p in model.parameters()))},
        "training": {
            **asdict(tcfg),
            "loss": "mean ||log(x_d^-1 f(q))|| with v in units of pos_unit (m) and omega in units of ang_unit (rad), "
                    "+ lam * mean reg",
            "regulariser": "eq. (12) action time (s^2)" if tcfg.reg == "action" else "eq. (11) joint motion (rad)",
            "optimizer": "Adam, linear warm-up then cosine lr decay per step",
            "fk_link_selection": "hard (j_d without gradient; gradients through d_link and the angles)"
                                 if tcfg.link_softness == 0 else f"soft phi blend, width {tcfg.link_softness} m",
            "q_c": "fresh uniform random q_c in C_f for every pose every epoch, numpy Generator([seed, epoch])",
            "steps": res.steps,
            "seconds": round(total_seconds, 1),
            "epochs_done": res.history[-1]["epoch"] if res.history else 0,
            "final_epoch": res.history[-1] if res.history else {},
            "threads": 1,
            "command": cfg.command,
            "versions": {"python": platform.python_version(), "torch": torch.__version__, "numpy": np.__version__,
                         "onnx": onnx.__version__, "onnxruntime": onnxruntime.__version__},
            "machine": f"{platform.machine()} CPU, torch.set_num_threads(1)",
        },
        "dataset": {**ds.info(), "method": "occupancy grid over W+ (x in [-l, l], y in [0, l]), mirrored to W-"},
        "accuracy": acc,
        "files": {
            "onnx": ex.file_entry(f_float, out),
            "onnx_int8": ex.file_entry(f_int8, out),
            "int8_flat": ex.file_entry(f_flat, out),
        },
        "python": sys.version.split()[0],
    }
    card_path = out / f"{name}-card.json"
    card_path.write_text(json.dumps(card, indent=2) + "\n")
    _say(log, f"wrote {card_path}")
    return card


def parse_hidden(text: str) -> list[int]:
    try:
        sizes = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise ArmbridgeError(f"--hidden must be comma-separated layer sizes like 120,100,50,30, got {text!r}") from None
    if not sizes or any(s <= 0 for s in sizes):
        raise ArmbridgeError(f"--hidden needs positive layer sizes, got {text!r}")
    return sizes
