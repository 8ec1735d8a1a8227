"""`armbridge smm ROBOT --at x,y[,z...]`: the SMM branches of one task location.

Prints the branch count, each branch's bounding box per joint (section III-A,
the smallest arc covering the branch; "full" when the joint winds all the way
round) and its eq. (19) FK error, and optionally plots the branches projected
on pairs of joints as in Figs. 12-14.
"""
from __future__ import annotations

import importlib.util

import math
import time
from pathlib import Path

import numpy as np
import typer

from armbridge import resources
from armbridge.errors import ArmbridgeError
from armbridge.extras import require
from armbridge.geometry import wrap_angle

METHODS = ("nullspace", "learned")


def smm_cmd(
    robot: str = typer.Argument(..., help="planar3r, spatial4r, spatial7r or arm3r."),
    at: str = typer.Option(..., "--at", help="Task location: x,y (planar), x,y,z (4R) or x,y,z,rx,ry,rz (7R: "
                           "position in m and rotation vector in rad)."),
    method: str = typer.Option("auto", "--method", help="nullspace (ground truth; needs the train extra's torch), "
                                                         "learned (the shipped ONNX networks) or auto (nullspace "
                                                         "where torch is installed, else learned)."),
    model: Path | None = typer.Option(None, "--model", help="Learned model folder [default: the shipped smm-ROBOT]."),
    correct: int = typer.Option(0, "--correct", min=0, help="Eq. (18) correction steps for --method learned."),
    png: Path | None = typer.Option(None, "--png", help="Write the branches projected on joint planes to this PNG."),
) -> None:
    """Compute and describe the self-motion manifolds of ROBOT at one task location."""
    import rich.console
    import rich.table

    from armbridge.smm.arms import get_smm_arm
    from armbridge.smm.bbox import branch_boxes

    arm = get_smm_arm(robot)
    x = parse_location(at, arm.m, arm.name)
    if method == "auto":
        method = "nullspace" if importlib.util.find_spec("torch") is not None else "learned"
    if method not in METHODS:
        raise ArmbridgeError(f"--method must be one of auto, {', '.join(METHODS)}, got {method!r}")
    t0 = time.perf_counter()
    if method == "nullspace":
        torch = require("torch", "train", "--method nullspace")
        from armbridge.smm.nullspace import compute

        torch.set_num_threads(1)  # small ops: threads only add hand-offs (see nullspace)
        smm = compute(arm, x[None, :])
    else:
        from armbridge.smm.learned import LearnedSmm

        smm = LearnedSmm.load(model or resources.model_dir(f"smm-{arm.name}"), robot=arm.name).compute(
            x[None, :], correct_iters=correct
        )
    elapsed = time.perf_counter() - t0
    console = rich.console.Console()
    count = int(smm.count[0])
    note = " (passes near a singular configuration)" if smm.singular[0] else ""
    console.print(f"{arm.name} at {_fmt(x)}: {count} SMM branch{'es' if count != 1 else ''}{note} "
                  f"[{method}, {elapsed * 1e3:.0f} ms]", markup=False)
    if count == 0:
        console.print("out of reach: no configuration reaches this location")
        return
    table = rich.table.Table(title="bounding box per joint: arc from lo counter-clockwise to hi (deg)")
    table.add_column("branch")
    for j in range(arm.n):
        table.add_column(f"theta{j + 1}")
    table.add_column("FK error %")
    for b, (box, branch) in enumerate(zip(branch_boxes(smm, 0), smm.branches(0))):
        cells = ["full" if full else f"{math.degrees(lo):.1f} .. {math.degrees(wrap_angle(lo + w)):.1f}"
                 for lo, w, full in zip(box.lo, box.width, box.full)]
        err = arm.fk_error(branch, np.broadcast_to(x, (branch.shape[0], arm.m)).copy())
        table.add_row(str(b + 1), *cells, f"{100 * float(np.mean(err)):.2g}")
    console.print(table)
    if png is not None:
        plot_branches(smm.branches(0), png, f"{arm.name} at {_fmt(x)} ({method})")
        console.print(f"wrote {png}", markup=False)


def parse_location(text: str, m: int, robot: str) -> np.ndarray:
    """'x,y[,z...]' as m finite numbers, or an ArmbridgeError saying what is wrong."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != m:
        raise ArmbridgeError(f"--at for {robot} needs {m} comma-separated numbers, got {len(parts)} in {text!r}")
    try:
        x = np.array([float(p) for p in parts])
    except ValueError:
        raise ArmbridgeError(f"--at must be numbers separated by commas, got {text!r}") from None
    if not np.all(np.isfinite(x)):
        raise ArmbridgeError(f"--at must be finite numbers, got {text!r}")
    return x


def joint_pairs(n: int) -> list[tuple[int, int]]:
    """The joint planes of Figs. 12-14: (1,2), (2,3) for 3R; (1,2), (3,4), ... closing with (n,1) for odd n."""
    if n == 3:
        return [(0, 1), (1, 2)]
    return [(j, (j + 1) % n) for j in range(0, n, 2)]


def plot_branches(branches: list[np.ndarray], path: Path, title: str) -> None:
    """Each branch (N, n) projected on the joint planes, one colour per branch, at a size a paper
    prints (8 pt type); the legend below the panels, outside the data; joint names in mathtext."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = branches[0].shape[1]
    pairs = joint_pairs(n)
    width = min(7.2, 2.5 * len(pairs) + 0.4)
    with plt.rc_context({"font.size": 8, "axes.labelsize": 8, "xtick.labelsize": 7, "ytick.labelsize": 7,
                         "legend.fontsize": 8}):
        fig, axes = plt.subplots(1, len(pairs), figsize=(width, width / len(pairs) + 0.9), squeeze=False)
        ticks = [-math.pi, -math.pi / 2, 0.0, math.pi / 2, math.pi]
        names = [r"$-\pi$", r"$-\pi/2$", "0", r"$\pi/2$", r"$\pi$"]
        for ax, (i, j) in zip(axes[0], pairs):
            for b, branch in enumerate(branches):
                loop = np.vstack([branch, branch[:1]])
                # Break the line where a joint wraps from pi to -pi.
                jump = np.any(np.abs(np.diff(loop[:, [i, j]], axis=0)) > math.pi, axis=1)
                xs, ys = loop[:, i].copy(), loop[:, j].copy()
                xs[1:][jump], ys[1:][jump] = np.nan, np.nan
                ax.plot(xs, ys, lw=1.2, label=f"branch {b + 1}")
            ax.set_xlim(-math.pi, math.pi)
            ax.set_ylim(-math.pi, math.pi)
            ax.set_xticks(ticks, names)
            ax.set_yticks(ticks, names)
            ax.set_xlabel(rf"$\theta_{{{i + 1}}}$ (rad)")
            ax.set_ylabel(rf"$\theta_{{{j + 1}}}$ (rad)")
            ax.set_aspect("equal")
            ax.grid(lw=0.3, alpha=0.5)
        handles, labels = axes[0][0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=min(6, len(labels)), frameon=False)
        fig.suptitle(title, fontsize=9)
        fig.tight_layout(rect=(0, 0.08, 1, 1))
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=200)
        plt.close(fig)


def _fmt(x: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:g}" for v in x) + "]"
