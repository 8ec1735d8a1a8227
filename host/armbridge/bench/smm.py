"""`armbridge bench smm`: Table III, Fig. 3 and the Figs. 15-16 simulation of the SMM paper.

Table III protocol (section VI-A): random workspace locations (the tips of
uniform random configurations, so all reachable; one seed for every method;
for the 7R with a model, uniform over the model's region: `bench_locations`).
Per method: time per location (batched: every location in one call, best of
`repeats`; single: one location per call, median), the FK error of eq. (19)
in % (per location the mean over every point of its branches, then mean and
std over locations), and the share of locations whose branch count differs
from our nullspace method's. Methods:

* nullspace (ours): armbridge.smm.nullspace.compute, the ground truth, in
  shards of GROUND_TRUTH_SHARD locations (smm.trace.trace_smms: each shard
  with IK seed 0; they may run on a Ray cluster, --ray), its batched time the
  sum of the shards' nullspace seconds over the locations;
* learned before / after correction: the shipped models (models/onnx/smm-*)
  through onnxruntime, with 0 and 3 eq. (18) iterations;
* realtime-smm: the paper's own code (PyPI realtime-smm, its nullspace
  method Robot.workspace_smms), one location per call, on the first
  `peer_locations` locations (it takes seconds per location).

Fig. 3: low-pass error against K on the nullspace SMMs of random locations.
Simulation: simulate.compare's scenario on the same trials with each
method's measured single-location latency and its own SMMs.

Everything runs on one thread (torch and onnxruntime): on this 2-core
machine a second thread only waits for a core.
"""
from __future__ import annotations

import platform
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

import numpy as np
import typer

from armbridge import resources
from armbridge.bench.command import write_json
from armbridge.shards import cli as shard_options

if TYPE_CHECKING:
    from armbridge.shards import Runner

MODELS = resources.models_dir()
CORRECT_ITERS = 3  # the paper's "three inverse kinematics iterations"
# Table III of the paper: (FK error % before, after correction, branch-count mismatch %).
PAPER = {"planar3r": (0.29, 7.3e-5, 0.70), "spatial4r": (0.66, 0.0011, 2.16), "spatial7r": (2.07, 0.016, 6.02)}
TARGET_BATCHED_MS = 0.5
GROUND_TRUTH_SHARD = 1024  # locations per shard of the nullspace ground truth (nullspace.compute's chunk)
PAPER_FIG16_LATENCY_S = 4.3


@dataclass(frozen=True)
class SmmBenchSize:
    locations: int  # Table III locations for the 3R and 4R
    locations_7r: int  # the 7R's (its nullspace SMMs take ~0.1 s each batched, so 2,000 is 3-4 minutes)
    peer_locations: int  # of them, how many realtime-smm computes (3R, 4R)
    peer_locations_7r: int
    single: int  # single-location timing calls per method
    repeats: int  # batched timing repeats (best of)
    fig3_locations: int
    sim_trials: int


FULL = SmmBenchSize(locations=10000, locations_7r=2000, peer_locations=100, peer_locations_7r=10, single=50,
                    repeats=3, fig3_locations=100, sim_trials=1000)
QUICK = SmmBenchSize(locations=40, locations_7r=4, peer_locations=2, peer_locations_7r=0, single=3, repeats=1,
                     fig3_locations=5, sim_trials=20)


def location_fk_error(arm: Any, smm: Any, x: np.ndarray) -> np.ndarray:
    """(L,) eq. (19) FK error in %, the mean over every point of a location's branches (NaN: none)."""
    from armbridge.train.smm import fk_errors

    out = np.full(len(smm), np.nan)
    has = smm.count > 0
    if has.any():
        sub = type(smm)(smm.points[has], smm.count[has], smm.singular[has])
        err = fk_errors(arm, sub, x[has]) * 100
        points = smm.count[has] * smm.points.shape[2]
        out[has] = np.add.reduceat(err, np.concatenate([[0], np.cumsum(points)[:-1]])) / points
    return out


def _stats(err: np.ndarray) -> dict[str, float]:
    e = err[np.isfinite(err)]
    return {"mean": float(e.mean()), "std": float(e.std()), "median": float(np.median(e)),
            "max": float(e.max())} if e.size else {}


def _time_batched(fn: Callable[[np.ndarray], Any], x: np.ndarray, repeats: int) -> tuple[Any, float]:
    best, out = np.inf, None
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        out = fn(x)
        best = min(best, time.perf_counter() - t0)
    return out, best / x.shape[0] * 1e3


def _time_single(fn: Callable[[np.ndarray], Any], x: np.ndarray, count: int) -> float:
    fn(x[:1])  # warm-up: sessions, first-touch
    ts = []
    for i in range(min(count, x.shape[0])):
        t0 = time.perf_counter()
        fn(x[i : i + 1])
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts) * 1e3)


def _row(name: str, arm: Any, x: np.ndarray, smm: Any, reference: np.ndarray | None, batched_ms: float | None,
         single_ms: float) -> dict[str, Any]:
    row: dict[str, Any] = {"method": name, "locations": int(x.shape[0]), "batched_ms_per_location": batched_ms,
                           "single_ms": single_ms, "fk_error_pct": _stats(location_fk_error(arm, smm, x)),
                           "branches_mean": float(smm.count.mean()), "singular_pct": float(smm.singular.mean() * 100)}
    if reference is not None:
        ref = reference[: len(smm)]
        row["branch_count_mismatch_pct"] = float(np.mean(smm.count != ref) * 100)
        row["mismatch_by_true_count"] = mismatch_by_count(smm.count, ref)
    return row


def mismatch_by_count(count: np.ndarray, reference: np.ndarray) -> dict[str, dict[str, Any]]:
    """Per true (reference) branch count: its locations, how many got another count, and which."""
    out = {}
    for b in np.unique(reference):
        got = count[reference == b]
        wrong = got[got != b]
        out[str(int(b))] = {"locations": int(got.size), "mismatched": int(wrong.size),
                            "mismatch_pct": float(wrong.size / got.size * 100),
                            "got": {str(int(k)): int(np.sum(wrong == k)) for k in np.unique(wrong)}}
    return out


def target_matrix(arm: Any, x: np.ndarray) -> np.ndarray:
    """(L, 4, 4) homogeneous targets of locations x (L, m): 'xy' at z = 0, positions with the identity rotation."""
    import torch

    from armbridge.robots.rotations import rot_from_vec

    t = np.tile(np.eye(4), (len(x), 1, 1))
    t[:, : min(arm.m, 3), 3] = x[:, :3]
    if arm.space == "pose":
        t[:, :3, :3] = rot_from_vec(torch.as_tensor(x[:, 3:], dtype=torch.float64)).numpy()
    return t


def peer_compute(arm: Any, x: np.ndarray) -> tuple[Any, list[str]]:
    """realtime-smm's nullspace SMMs at locations x (L, m), as an SmmSet, and its status per location."""
    from realtime_smm.helpers.robot import Robot  # type: ignore[import-untyped]
    from realtime_smm.helpers.types import DHLink, SMMStatus, TaskSpace  # type: ignore[import-untyped]

    from armbridge.smm.manifold import SmmSet

    space = {"xy": TaskSpace.X | TaskSpace.Y, "xyz": TaskSpace.X | TaskSpace.Y | TaskSpace.Z,
             "pose": TaskSpace.X | TaskSpace.Y | TaskSpace.Z | TaskSpace.SO3}[arm.space]
    robot = Robot([DHLink(a=float(a), alpha=float(al), d=float(d), theta=float(t))
                   for a, al, d, t in zip(arm.a, arm.alpha, arm.d, arm.theta)], taskspace=space)
    np.random.seed(0)  # it draws IK starts from numpy's global generator
    found, statuses = [], []
    for target in target_matrix(arm, x):
        res = robot.workspace_smms(target)
        statuses.append(SMMStatus(res.status).name)
        found.append([s.data for s in res.data if s.data is not None])
    bmax = max(1, max(len(f) for f in found))
    points = np.full((len(found), bmax, 128, arm.n), np.nan)
    for i, f in enumerate(found):
        for b, data in enumerate(f):
            points[i, b] = data
    count = np.array([len(f) for f in found], dtype=np.int64)
    return SmmSet(points, count, np.array([s == "SINGULAR" for s in statuses])), statuses


def bench_locations(arm: Any, count: int, model: Path) -> tuple[np.ndarray, str]:
    """Table III's locations (seed 1) and where they lie: the tips of random configurations; for a
    tool-roll arm with a model, uniform over the model's region (its positions, every tool direction and
    roll, any turn about the base), as the paper samples its 7R within its grid."""
    from armbridge.smm.grid import GridSpec, region_locations
    from armbridge.smm.learned import read_card

    if arm.tool_roll and (model / "card.json").is_file():
        info = read_card(model, arm.name)["dataset"]
        grid = GridSpec(tuple(info["grid_lo"]), tuple(info["grid_hi"]), tuple(info["grid_shape"]))
        rng = np.random.default_rng(2)
        shift = np.zeros((count, arm.n))
        shift[:, 0], shift[:, -1] = rng.uniform(-np.pi, np.pi, (2, count))
        lo, hi = grid.lo, grid.hi
        where = (f"in the model's region (rho {lo[0]:.2f} to {hi[0]:.2f} m, z {lo[1]:.2f} to {hi[1]:.2f} m, "
                 "every tool direction)")
        return np.asarray(arm.uncanonical(region_locations(grid, count, seed=1), shift)), where
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, (count, arm.n))
    return np.asarray(arm.task(q)), "(tips of random configurations, all reachable)"


def table3(arm_name: str, size: SmmBenchSize, progress: Callable[[str], None], models: Path = MODELS,
           runner: Runner | None = None) -> dict[str, Any]:
    from armbridge.smm import nullspace
    from armbridge.smm.arms import get_smm_arm
    from armbridge.smm.trace import trace_smms
    from armbridge.smm.learned import LearnedSmm

    arm = get_smm_arm(arm_name)
    count = size.locations_7r if arm_name == "spatial7r" else size.locations
    model = models / f"smm-{arm_name}"
    x, where = bench_locations(arm, count, model)
    progress(f"{arm_name}: nullspace on {count} locations {where}")
    took: list[float] = []  # the ground truth in shards (GROUND_TRUTH_SHARD locations each, seed 0 each)
    ours = trace_smms(arm, x, 128, GROUND_TRUTH_SHARD, runner=runner, job=f"table3-{arm_name}", seconds=took)
    ns_ms = sum(took) / count * 1e3
    rows = [_row("nullspace (ours)", arm, x, ours, None, ns_ms,
                 _time_single(lambda xx: nullspace.compute(arm, xx), x, min(size.single, 10)))]
    if (model / "card.json").is_file():
        learned = LearnedSmm.load(model, threads=1)
        for label, iters in (("learned, before correction", 0), (f"learned, after correction ({CORRECT_ITERS})",
                                                                 CORRECT_ITERS)):
            progress(f"{arm_name}: {label}")

            def fn(xx: np.ndarray, iters: int = iters) -> Any:
                return learned.compute(xx, correct_iters=iters)

            fn(x[: min(256, count)])  # warm-up
            smm, ms = _time_batched(fn, x, size.repeats)
            rows.append(_row(label, arm, x, smm, ours.count, ms, _time_single(fn, x, size.single)))
    else:
        rows.append({"method": "learned", "missing": f"no model at {model}"})
    k = min(size.peer_locations_7r if arm_name == "spatial7r" else size.peer_locations, count)
    if k:
        progress(f"{arm_name}: realtime-smm on {k} locations")
        t0 = time.perf_counter()
        peer, statuses = peer_compute(arm, x[:k])
        ms = (time.perf_counter() - t0) / k * 1e3
        row = _row("realtime-smm 0.1.2 (paper's code, nullspace)", arm, x[:k], peer, ours.count, None, ms)
        row["statuses"] = {s: statuses.count(s) for s in sorted(set(statuses))}
        rows.append(row)
    return {"robot": arm_name, "locations": count, "where": where, "rows": rows, "paper": dict(zip(
        ("fk_before_pct", "fk_after_pct", "mismatch_pct"), PAPER[arm_name]))}


def targets(result: dict[str, Any]) -> dict[str, bool]:
    out = {}
    for t in result["table3"]:
        name, (before, after, mismatch) = t["robot"], PAPER[t["robot"]]
        if name == "spatial7r":
            continue  # the issue asks for the 7R numbers reached, not a target
        by = {r["method"].split(" (")[0]: r for r in t["rows"]}
        b, a = by.get("learned, before correction"), by.get("learned, after correction")
        if b is None or a is None:
            out[f"{name}_learned_model_present"] = False
            continue
        out[f"{name}_fk_before_le_{before}pct"] = b["fk_error_pct"]["mean"] <= before
        out[f"{name}_fk_after_le_{after}pct"] = a["fk_error_pct"]["mean"] <= after
        out[f"{name}_mismatch_le_{mismatch}pct"] = a["branch_count_mismatch_pct"] <= mismatch
        out[f"{name}_batched_lt_{TARGET_BATCHED_MS}ms"] = max(b["batched_ms_per_location"],
                                                              a["batched_ms_per_location"]) < TARGET_BATCHED_MS
    return out


def simulation(size: SmmBenchSize, rows: list[dict[str, Any]], progress: Callable[[str], None],
               models: Path = MODELS) -> dict[str, Any]:
    """Figs. 15-16 on the planar 3R: each method plans with its own SMMs after its measured latency."""
    from armbridge.smm import nullspace
    from armbridge.smm.arms import get_smm_arm
    from armbridge.smm.learned import LearnedSmm
    from armbridge.smm.simulate import draw_trials, simulate

    arm = get_smm_arm("planar3r")
    trials = draw_trials(arm, size.sim_trials, seed=0)
    by = {r["method"]: r for r in rows}
    out: dict[str, Any] = {"robot": arm.name, "trials": size.sim_trials}
    progress(f"simulation: {size.sim_trials} trials per method")
    ours = nullspace.compute(arm, trials.x)
    out["nullspace (ours)"] = simulate(arm, ours, trials, by["nullspace (ours)"]["single_ms"] / 1e3).to_dict()
    label = f"learned, after correction ({CORRECT_ITERS})"
    if label in by:
        learned = LearnedSmm.load(models / "smm-planar3r").compute(trials.x, correct_iters=CORRECT_ITERS)
        out["learned"] = simulate(arm, learned, trials, by[label]["single_ms"] / 1e3).to_dict()
    peer = [r for r in rows if r["method"].startswith("realtime-smm")]
    if peer:  # its SMMs are the same loops: only its latency differs
        out["realtime-smm latency, our SMMs"] = simulate(arm, ours, trials, peer[0]["single_ms"] / 1e3).to_dict()
    # the paper's nullspace latency in its Fig. 16 (7R, 4.3 s): where a slow method leaves the arm
    out["paper's Fig. 16 latency (4.3 s), our SMMs"] = simulate(arm, ours, trials, PAPER_FIG16_LATENCY_S).to_dict()
    return out


def run(size: SmmBenchSize, robots: tuple[str, ...] = ("planar3r", "spatial4r", "spatial7r"),
        progress: Callable[[str], None] = lambda s: None, models: Path = MODELS,
        runner: Runner | None = None) -> dict[str, Any]:
    """The whole bench; the Table III ground truth runs as shards where `runner` says (None: here,
    serially), every timed part here."""
    import torch

    from armbridge.smm.arms import get_smm_arm
    from armbridge.smm.dataset import fig3

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    result: dict[str, Any] = {"benchmark": "smm (Table III, Fig. 3, Figs. 15-16)", "size": asdict(size),
                              "machine": {"python": platform.python_version(),
                                          "cpu": platform.processor() or platform.machine(), "threads": 1}}
    result["shards"] = runner.backend if runner is not None else "serial"
    result["table3"] = [table3(name, size, progress, models, runner) for name in robots]
    Ks = (10, 20, 40, 90)
    progress("fig3")
    result["fig3"] = {"K": list(Ks), "mean_abs_error_rad": {
        name: [float(e) for e in fig3(get_smm_arm(name), Ks, locations=size.fig3_locations)] for name in robots}}
    if "planar3r" in robots:
        rows = next(t["rows"] for t in result["table3"] if t["robot"] == "planar3r")
        result["simulation"] = simulation(size, rows, progress, models)
    result["targets"] = targets(result)
    result["wall_s"] = time.perf_counter() - t0
    return result


def fig3_png(result: dict[str, Any], path: Path) -> Path:
    """Fig. 3: mean absolute joint error against K, one line per arm (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f3 = result["fig3"]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for name, errs in f3["mean_abs_error_rad"].items():
        ax.semilogy(f3["K"], errs, marker="o", label=name)
    ax.set_xlabel("K (Fourier components kept of N = 128)")
    ax.set_ylabel("mean |joint error| (rad)")
    ax.set_title("Fig. 3: low-pass error of the SMMs")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def smm_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 40 locations, 2 for realtime-smm, 20 trials."),
    locations: int = typer.Option(None, "--locations", help="Table III locations for the 3R and 4R (full run: 10000)."),
    robots: str = typer.Option("planar3r,spatial4r,spatial7r", "--robots", help="Comma-separated SMM arms."),
    json_out: Path = typer.Option(Path("runs/bench-smm.json"), "--json", help="Where to write the results ('-': stdout)."),
    png: Path = typer.Option(None, "--png", help="Also plot Fig. 3 (error against K) to this PNG."),
    models: Path = typer.Option(None, "--models", help="Folder holding the learned models, smm-ROBOT each (default: models/onnx; the 7R's is not shipped, see docs/smm.md)."),
    ray: Optional[str] = shard_options.ray_option(),
    workers: int = shard_options.workers_option(),
    checkpoint: Optional[Path] = shard_options.checkpoint_option("none: shards are not kept"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show the shards' progress bar."),
) -> None:
    """Table III of the SMM paper (time per location, FK error before/after
    correction, branch-count mismatch; ours, learned, realtime-smm), Fig. 3, and
    the Figs. 15-16 locked-joint simulation.

    The nullspace ground truth of Table III runs in shards of 1,024 locations
    (--ray, --workers; docs/cluster.md); its time per location is the sum of the
    shards' seconds. Every other timing runs here."""
    from dataclasses import replace

    from rich.console import Console
    from rich.table import Table

    from armbridge.smm.arms import get_smm_arm

    size = QUICK if quick else FULL
    if locations is not None:
        size = replace(size, locations=locations)
    names = tuple(r.strip() for r in robots.split(",") if r.strip())
    for name in names:
        get_smm_arm(name)  # a clear error before any work
    console = Console()
    with shard_options.runner(ray, workers, checkpoint, progress) as runner:
        result = run(size, names, progress=lambda text: console.print(f"[dim]bench smm: {text}[/]"),
                     models=models or MODELS, runner=runner)
    write_json(result, json_out)

    def num(v: float | None, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    for t in result["table3"]:
        table = Table(title=f"Table III protocol, {t['robot']}: {t['locations']} random locations {t['where']} "
                            f"(paper: {t['paper']['fk_before_pct']} % / {t['paper']['fk_after_pct']} %, "
                            f"mismatch {t['paper']['mismatch_pct']} %)")
        for col in ("method", "ms/location batched", "ms single", "FK error % mean +- std", "branch mismatch %",
                    "mismatched / locations by true count"):
            table.add_column(col, justify="left" if col in ("method", "mismatched / locations by true count")
                             else "right")
        for r in t["rows"]:
            if "missing" in r:
                table.add_row(r["method"], r["missing"], "", "", "", "")
                continue
            fk = r["fk_error_pct"]
            by = r.get("mismatch_by_true_count") or {}
            table.add_row(f"{r['method']} ({r['locations']})", num(r["batched_ms_per_location"], ".3f"),
                          num(r["single_ms"], ".2f"), f"{fk['mean']:.3g} +- {fk['std']:.2g}" if fk else "-",
                          num(r.get("branch_count_mismatch_pct"), ".2f"),
                          ", ".join(f"{b}: {v['mismatched']}/{v['locations']}" for b, v in by.items()))
        console.print(table)
    f3 = result["fig3"]
    table = Table(title="Fig. 3: mean |joint error| (rad) after keeping K Fourier components")
    table.add_column("robot")
    for k in f3["K"]:
        table.add_column(f"K={k}", justify="right")
    for name, errs in f3["mean_abs_error_rad"].items():
        table.add_row(name, *(f"{e:.2e}" for e in errs))
    console.print(table)
    if "simulation" in result:
        sim = result["simulation"]
        table = Table(title=f"Figs. 15-16 simulation ({sim['robot']}, {sim['trials']} trials, a joint locks at random)")
        for col in ("SMMs from", "latency (s)", "success %"):
            table.add_column(col, justify="left" if col == "SMMs from" else "right")
        for name, o in sim.items():
            if isinstance(o, dict):
                table.add_row(name, f"{o['latency_s']:.4f}", f"{100 * o['success'] / o['trials']:.1f}")
        console.print(table)
    console.print("targets: " + ", ".join(f"{k} {'met' if v else 'MISSED'}" for k, v in result["targets"].items()))
    console.print(f"wrote {json_out}")
    if png is not None:
        console.print(f"wrote {fig3_png(result, png)}")
