"""`armbridge train ...`: the typer app `train_app` (registered by cli.py as `train`).

Where a run writes: everything under its work folder, `runs/<model>/` below
the current directory (checkpoints, the data-set cache, and the exported model
in `runs/<model>/model/`), as training tools commonly do, and printed at the
end. A model is never written over an existing one, and in particular never
over a shipped model (resources.models_dir()), unless --force is given: to
update a shipped model from a checkout, pass `--out models/onnx/... --force`.
"""
from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from armbridge import resources
from armbridge.jsonfile import JSON_HELP, emit_json
from armbridge.errors import ArmbridgeError
from armbridge.extras import require
from armbridge.shards import cli as shard_options

train_app = typer.Typer(help="Train models and export them as ONNX with a model card (into runs/ unless --out).",
                        no_args_is_help=True)

#: What training needs beyond the runtime (the `train` extra).
TRAIN_MODULES = ("torch", "onnx", "scipy")


def _require_train_extra() -> None:
    for module in TRAIN_MODULES:
        require(module, "train", "`armbridge train`")


def check_output(card: Path, force: bool, resume: bool) -> None:
    """Refuse to write a model whose card already exists unless force; --resume may finish
    its own run's model again, never a shipped one (resources.models_dir())."""
    if force or not card.exists():
        return
    shipped = card.resolve().is_relative_to(resources.models_dir().resolve())
    if resume and not shipped:
        return
    what = "a shipped model" if shipped else "a model"
    raise ArmbridgeError(f"{card} exists ({what}); pass --force to overwrite it, or choose another --out")


def _command_line() -> str:
    """How this run was started, as `armbridge train masr-iknn ...` (without --resume)."""
    argv = sys.argv
    at = argv.index("masr-iknn") if "masr-iknn" in argv else len(argv)
    return " ".join(["armbridge", "train", *(shlex.quote(a) for a in argv[at:] if a != "--resume")])


@train_app.command("masr-iknn")
def masr_iknn_cmd(
    robot: str = typer.Option("masr5", "--robot", help="Catalog MASR to train for."),
    reg: str = typer.Option("action", "--reg", help="Regulariser: action (eq. 12) or joint (eq. 11)."),
    lam: float = typer.Option(0.1, "--lam", help="Regulariser weight lambda (in the loss units below)."),
    hidden: str = typer.Option("120,100,50,30", "--hidden", help="Hidden layer sizes."),
    activation: str = typer.Option("leaky_relu", "--activation", help="leaky_relu, relu, tanh or silu."),
    epochs: int = typer.Option(250, "--epochs", help="Epochs over the data set (fresh q_c each epoch)."),
    batch: int = typer.Option(2048, "--batch", help="Batch size."),
    lr: float = typer.Option(3e-3, "--lr", help="Peak learning rate (Adam; warm-up then cosine decay)."),
    lr_final: float = typer.Option(1e-5, "--lr-final", help="Learning rate at the end of the cosine decay."),
    pos_unit: float = typer.Option(0.008, "--pos-unit", help="Twist position unit in m (0.008 = e_p; 1 = plain SI twist)."),
    ang_unit: float = typer.Option(0.0698132, "--ang-unit", help="Twist angle unit in rad (0.0698 = e_phi = 4 deg)."),
    link_softness: float = typer.Option(0.0, "--link-softness", help="Soft phi blend over links in m (0 = hard FK)."),
    grid: str = typer.Option("1800x1600", "--grid", help="Occupancy grid NXxNY over W+."),
    rho: int = typer.Option(10, "--rho", help="Largest enclosed vacancy (cells) allowed before sampling stops."),
    max_samples: int = typer.Option(10_000_000, "--max-samples", help="Cap on random configurations for the data set."),
    seed: int = typer.Option(0, "--seed", help="Seed of training and data set."),
    out: Optional[Path] = typer.Option(None, "--out", help="Folder for the ONNX files and the card [default: WORK_DIR/model]."),
    name: str = typer.Option("", "--name", help="Model name [default: ROBOT-iknn]."),
    work_dir: Path = typer.Option(Path("runs/masr-iknn"), "--work-dir", help="Checkpoints and the data-set cache, below the current directory."),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing model in --out (also a shipped one)."),
    resume: bool = typer.Option(False, "--resume", help="Continue from the checkpoint in --work-dir."),
    eval_trials: int = typer.Option(5000, "--eval-trials", help="Random trials for the card's accuracy."),
    nr_trials: int = typer.Option(0, "--nr-trials", help="Also measure the numeric baseline on this many trials."),
    max_steps: int = typer.Option(0, "--max-steps", help="Stop after this many steps (0: all epochs)."),
    int8_epochs: int = typer.Option(2, "--int8-epochs", help="Quantisation-aware fine-tune epochs for int8 (0: none)."),
    int8_lr: float = typer.Option(3e-4, "--int8-lr", help="Learning rate of the int8 fine-tune."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show a progress bar."),
    json_out: Optional[str] = typer.Option(None, "--json", metavar="FILE|-",
                                           help=JSON_HELP.format(what="the accuracy")),
    ray: Optional[str] = shard_options.ray_option(),
    workers: int = shard_options.workers_option(),
    checkpoint: Optional[Path] = shard_options.checkpoint_option("WORK_DIR/shards, deleted once the data set is saved"),
) -> None:
    """Build/cache the data set, train the IK-NN, export float/int8 ONNX + flat int8, write the card.

    The data set's sampling batches are shards (--ray, --workers; docs/cluster.md),
    merged here in batch order; the network trains here."""
    _require_train_extra()
    from armbridge.ik.masr_data import GridSpec
    from armbridge.ik.masr_nn_train import TrainConfig
    from armbridge.train.masr_iknn import PipelineConfig, parse_hidden, run

    if reg not in ("action", "joint"):
        raise ArmbridgeError(f"--reg must be action or joint, got {reg!r}")
    for opt, v in (("--epochs", epochs), ("--batch", batch), ("--rho", rho)):
        if v <= 0:
            raise ArmbridgeError(f"{opt} must be > 0, got {v}")
    if lr <= 0 or lam < 0 or pos_unit <= 0 or ang_unit <= 0:
        raise ArmbridgeError("--lr, --pos-unit and --ang-unit must be > 0 and --lam >= 0")
    nx, ny = GridSpec.parse(grid)
    tcfg = TrainConfig(hidden=parse_hidden(hidden), activation=activation, reg=reg, lam=lam, pos_unit=pos_unit,
                       ang_unit=ang_unit, link_softness=link_softness, lr=lr, lr_final=lr_final, epochs=epochs,
                       batch=batch, seed=seed, max_steps=max_steps)
    cfg = PipelineConfig(robot=robot, name=name, nx=nx, ny=ny, rho=rho, max_samples=max_samples, data_seed=seed,
                         out=out or work_dir / "model", work_dir=work_dir, eval_trials=eval_trials, nr_trials=nr_trials, train=tcfg,
                         int8_epochs=int8_epochs, int8_lr=int8_lr,
                         command=_command_line())
    check_output(cfg.out / f"{cfg.model_name}-card.json", force, resume)
    console = Console(stderr=True)
    with shard_options.runner(ray, workers, checkpoint or work_dir / "shards", progress) as runner:
        card = run(cfg, resume=resume, progress=progress, log=lambda s: console.print(s, highlight=False),
                   runner=runner)
    acc = card["accuracy"]
    table = Table(title=f"{card['name']}: {acc['trials']} random trials (Table I protocol)")
    for col in ("model", "mean dp (mm)", "mean dphi (deg)", "success (%)", "action time (s)", "ms/query (batch)"):
        table.add_column(col, justify="right" if col != "model" else "left")
    rows = [("IK-NN float", acc["nn"]), ("IK-NN + distal joints held", acc["nn_hold_distal"]),
            ("IK-NN + DLS refine", acc["nn_refined"]),
            (f"IK-NN int8 ONNX ({acc['int8_onnx']['scheme']})", acc["int8_onnx"][acc["int8_onnx"]["scheme"]]),
            ("IK-NN int8 flat", acc["int8_flat"])]
    if "nr" in acc:
        rows.append((f"numeric IK ({acc['nr']['method']})", acc["nr"]))
    for label, m in rows:
        table.add_row(label, f"{m['mean_dp_mm']:.2f}", f"{m['mean_dphi_deg']:.2f}", f"{m['success_rate']:.1f}",
                      f"{m['mean_action_time_s']:.2f}", f"{m['batched_ms_per_query']:.4f}")
    Console().print(table)
    if json_out is not None:
        emit_json(acc, json_out, "the accuracy")


@train_app.command("arm3r-ik")
def arm3r_ik_cmd(
    samples: int = typer.Option(150_000, "--samples", help="FK samples, q uniform within the limits (paper: 150,000)."),
    epochs: int = typer.Option(150, "--epochs", help="Epochs (Table 2: 150)."),
    batch: int = typer.Option(128, "--batch", help="Batch size."),
    lr: float = typer.Option(1e-3, "--lr", help="Adam learning rate at the start."),
    lr_final: float = typer.Option(1e-5, "--lr-final", help="Learning rate at the end of the cosine decay."),
    seed: int = typer.Option(0, "--seed", help="Seed of the data set, split and training."),
    max_steps: int = typer.Option(0, "--max-steps", help="Stop after this many steps (0: all epochs)."),
    eval_points: int = typer.Option(20_000, "--eval-points", help="Points for the card's accuracy."),
    out: Optional[Path] = typer.Option(None, "--out", help="Model folder [default: WORK_DIR/model]."),
    work_dir: Path = typer.Option(Path("runs/arm3r-ik"), "--work-dir", help="Scratch files, below the current directory."),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing model in --out (also a shipped one)."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Log every 10 epochs."),
) -> None:
    """Train the 3R drawing arm's ANN (Table 2), export float/int8 ONNX + flat int8, write the card."""
    _require_train_extra()
    from armbridge.ik.arm3r_ann import CARD_NAME
    from armbridge.train.arm3r_ik import Arm3rTrainConfig, run

    for opt, v in (("--samples", samples), ("--epochs", epochs), ("--batch", batch), ("--eval-points", eval_points)):
        if v <= 0:
            raise ArmbridgeError(f"{opt} must be > 0, got {v}")
    if not (lr > 0 and lr_final > 0):
        raise ArmbridgeError("--lr and --lr-final must be > 0")
    model_dir = out or work_dir / "model"
    check_output(model_dir / CARD_NAME, force, resume=False)
    console = Console(stderr=True)
    argv = sys.argv[sys.argv.index("arm3r-ik") + 1:] if "arm3r-ik" in sys.argv else []
    cfg = Arm3rTrainConfig(samples=samples, epochs=epochs, batch=batch, lr=lr, lr_final=lr_final, seed=seed,
                           max_steps=max_steps, eval_points=min(eval_points, samples))
    card = run(cfg, model_dir, work_dir, command=" ".join(["armbridge", "train", "arm3r-ik", *map(shlex.quote, argv)]),
               progress=progress, log=lambda s: console.print(s, highlight=False))
    table = Table(title=f"{card['name']}: tip error (mm) on {card['accuracy']['drawing_disc']['points']} drawing-disc points")
    for col in ("model", "mean", "max", "converged (%)", "ms/point (batch)"):
        table.add_column(col, justify="right" if col != "model" else "left")
    acc = card["accuracy"]
    for label, m in (("ANN float", acc["drawing_disc"]["ann"]), ("ANN + FABRIK", acc["drawing_disc"]["ann_fabrik"]),
                     (f"ANN int8 ONNX ({acc['int8_onnx']['scheme']})", acc["int8_onnx"][acc["int8_onnx"]["scheme"]]["ann"]),
                     ("ANN int8 flat", acc["int8_flat"]["ann"])):
        table.add_row(label, f"{m['tip']['mean_mm']:.4f}", f"{m['tip']['max_mm']:.4f}",
                      f"{m['converged_pct']:.1f}" if "converged_pct" in m else "", f"{m['batched_ms_per_point']:.4f}")
    Console().print(table)


@train_app.command("smm-7r")
@train_app.command("smm-4r")
@train_app.command("smm-3r")
def smm_cmd(
    ctx: typer.Context,
    robot: str = typer.Option("", "--robot", help="SMM arm; smm-3r also takes arm3r [default: planar3r, spatial4r, spatial7r]."),
    dataset: Optional[Path] = typer.Option(None, "--dataset", help="SMM data set .npz; built over --grid and saved there if absent [default: WORK_DIR/dataset.npz]."),
    grid: str = typer.Option("", "--grid", help="Cells of the data-set grid, e.g. 200 (3R), 250x400 (4R) or 3x3x24x48 (7R: rho, z, tool polar, azimuth over one region) [default: the paper's; the 7R: 3x3x24x48]."),
    k: int = typer.Option(40, "--k", help="Fourier components kept when building the data set."),
    sing_tol: float = typer.Option(0.02, "--sing-tol", help="Singular flag of the nullspace tracer when building the data set (smallest singular value of the weighted Jacobian; flagged cells separate clusters)."),
    boundary_points: int = typer.Option(4, "--boundary-points", help="Random points traced per cluster-boundary cell when building the data set, classifier-only (0: none)."),
    refine: int = typer.Option(0, "--refine", min=0, help="When building the data set, grid the boxes around the cells no cluster can label (e.g. the 4R's three-branch slivers) this many times finer per axis (0: no refinement; docs/smm.md)."),
    margin: int = typer.Option(0, "--margin", min=0, help="7R: after the grid (and --refine), trace this many more classifier-only locations where a branch-count classifier trained on the grid is least sure (margin sampling; docs/smm.md)."),
    cls_hidden: str = typer.Option("", "--cls-hidden", help="Classifier hidden layers, e.g. 5,5 or 3x50 [default: section VI-A]."),
    reg_hidden: str = typer.Option("", "--reg-hidden", help="Regressor hidden layers, e.g. 4x150 [default: section VI-A]."),
    epochs: int = typer.Option(200, "--epochs", help="Epochs over each network's training locations."),
    min_steps: int = typer.Option(2000, "--min-steps", help="Least optimiser steps per network (small clusters)."),
    batch: int = typer.Option(256, "--batch", help="Batch size."),
    cls_lr: float = typer.Option(1e-3, "--cls-lr", help="Classifier AdamW learning rate (paper: 1e-3)."),
    reg_lr: float = typer.Option(3e-3, "--reg-lr", help="Regressor AdamW learning rate (paper: 3e-3)."),
    lr_decay: float = typer.Option(0.01, "--lr-decay", help="Final lr / initial lr of the cosine decay (1 = constant)."),
    holdout: float = typer.Option(0.1, "--holdout", help="Share of each cluster held out for the card's accuracy."),
    correct_iters: int = typer.Option(3, "--correct-iters", help="Eq. (18) iterations for the card's 'after' FK error."),
    seed: int = typer.Option(0, "--seed", help="Seed of training (and of the data set's IK seeds)."),
    out: Optional[Path] = typer.Option(None, "--out", help="Model folder [default: WORK_DIR/model]."),
    work_dir: Optional[Path] = typer.Option(None, "--work-dir", help="Checkpoint and data set [default: runs/smm-ROBOT below the current directory]."),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing model in --out (also a shipped one)."),
    resume: bool = typer.Option(False, "--resume", help="Continue from the checkpoint in --work-dir."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show progress bars."),
    ray: Optional[str] = shard_options.ray_option(),
    workers: int = shard_options.workers_option(),
    checkpoint: Optional[Path] = shard_options.checkpoint_option("WORK_DIR/shards, deleted once the data set is saved"),
) -> None:
    """Train the learned-SMM networks (section V-D), export ONNX and a card with held-out accuracy.

    The data set's SMMs are traced in shards of 2,048 locations (--ray,
    --workers; docs/cluster.md), each written to --checkpoint as it
    finishes, so a stopped build resumes; the networks train here (CUDA
    when a device is visible)."""
    _require_train_extra()
    from armbridge.smm.arms import get_smm_arm
    from armbridge.smm.networks import default_architecture
    from armbridge.train import smm as tr
    from armbridge.train.smm_data import load_or_build
    from armbridge.train.smm_fit import SmmTrainConfig, parse_sizes

    kind = ctx.info_name or "smm-3r"
    arm = get_smm_arm(robot or tr.ROBOTS[kind])
    if f"{arm.n}r" != kind.split("-")[1]:
        raise ArmbridgeError(f"--robot {arm.name!r} has {arm.n} joints; `train {kind}` trains a {kind[4:-1]}-joint arm")
    arch = default_architecture(arm.n) if not (cls_hidden and reg_hidden) else None
    cfg = SmmTrainConfig(
        cls_hidden=parse_sizes(cls_hidden, "--cls-hidden") if cls_hidden else arch.classifier,  # type: ignore[union-attr]
        reg_hidden=parse_sizes(reg_hidden, "--reg-hidden") if reg_hidden else arch.regressor,  # type: ignore[union-attr]
        epochs=epochs, min_steps=min_steps, batch=batch, cls_lr=cls_lr, reg_lr=reg_lr, lr_decay=lr_decay,
        holdout=holdout, seed=seed)
    work = work_dir or Path("runs") / f"smm-{arm.name}"
    data_path = dataset or work / "dataset.npz"
    model_dir = out or work / "model"
    check_output(model_dir / tr.CARD_NAME, force, resume)
    console = Console(stderr=True)

    def log(s: str) -> None:
        console.print(s, highlight=False)

    argv = sys.argv[sys.argv.index(kind) + 1 :] if kind in sys.argv else []
    command = " ".join(["armbridge", "train", kind, *(shlex.quote(a) for a in argv if a != "--resume")])
    with shard_options.runner(ray, workers, checkpoint or work / "shards", progress) as runner:
        ds, info = load_or_build(arm, data_path, grid, k, 128, seed, progress, log, boundary_points, sing_tol,
                                 runner, refine, margin)
    pcfg = tr.PipelineConfig(robot=arm.name, train=cfg, dataset=data_path, out=model_dir,
                             work_dir=work, correct_iters=correct_iters, command=command, dataset_info=info)
    card = tr.run(pcfg, ds, resume=resume, progress=progress, log=log)
    held = card["accuracy"]["held_out"]
    table = Table(title=f"{card['name']}: {held['locations'] if held else 0} held-out locations")
    for col in ("metric", "value"):
        table.add_column(col)
    if held:
        table.add_row("classifier accuracy (%)", f"{held['classifier_accuracy_pct']:.2f}")
        table.add_row("branch-count mismatch (%)", f"{held['branch_count_mismatch_pct']:.2f}")
        for label in ("before", "after"):
            e = held[f"fk_error_pct_{label}"]
            nan = float("nan")
            table.add_row(f"FK error (%) {label} ({e['correct_iters']} iters): mean +- std, median",
                          f"{e.get('mean', nan):.3g} +- {e.get('std', nan):.2g}, {e.get('median', nan):.2g}")
    Console().print(table)
