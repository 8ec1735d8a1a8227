"""`armbridge bench masr-plan`: the planning experiments of the masr paper (section V-C).

* Fig. 5: `environments` random environments (planning.masr.random_env.
  random_environment, seeds 0..environments-1, each with a known solution);
  per environment one run of each planner with the same seed: the baseline
  RRT* (p_c = 0, goal bias 0.1, the paper's "p_c = 0") and MASR-RRT* with
  p_c in {0.2, 0.6, 1} (goal IK: the shipped IK-NN, MasrIK.solve). Success
  rate (share of environments with a path) and cost vs iterations; the cost
  is the mean best tau (eq. 7, s) over the environments every planner has
  solved by that iteration count (so the means are over the same set), plus
  the mean over each planner's own solved set.
* Fig. 7: E1-E3, `trials` runs (seeds 0..trials-1) of MASR-RRT* (p_c 0.6)
  and RRT*, `fig7_iterations` iterations each; the share of trials whose best
  cost is at or below the 15th / 25th percentile of the normalised cost range
  (rrt_star.percentile_success: range over every cost recorded in all trials
  of both planners on that environment).
* Timing: seconds per 1,000 iterations of each planner on E1-E3 (median of
  `timing_runs` runs).
* OMPL: OMPL's RRT* (PyPI `ompl`, planning.masr.ompl_compare, objective eq. 8, our
  collision checker) for 1,000 iterations on E1-E3: time per 1,000 iterations
  and the eq. (7) cost of its path, beside ours at 1,000 iterations.
* Margin (`--parts margin`, not in the default set): MASR-RRT* on E1-E3 with
  clearance margins up to 1.6 x the MA's execution bound (bench.masr_margin).
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

from armbridge.bench.command import write_json
from armbridge.bench.masr_ik import CARD_12
from armbridge.shards import cli as shard_options

if TYPE_CHECKING:
    from armbridge.shards import Runner

P_CS = (0.0, 0.2, 0.6, 1.0)
FIXED = ("E1", "E2", "E3")
LEVELS = (0.15, 0.25)


@dataclass(frozen=True)
class MasrPlanBenchSize:
    environments: int  # Fig. 5
    fig5_iterations: int
    trials: int  # Fig. 7, per environment and planner
    fig7_iterations: int
    timing_runs: int
    ompl_runs: int  # per environment (0: skip OMPL)


FULL = MasrPlanBenchSize(environments=300, fig5_iterations=3000, trials=200, fig7_iterations=12000,
                         timing_runs=20, ompl_runs=5)
QUICK = MasrPlanBenchSize(environments=3, fig5_iterations=200, trials=4, fig7_iterations=200,
                          timing_runs=1, ompl_runs=0)


def checkpoints(iterations: int) -> list[int]:
    """Iteration counts to report: 1-2-5 steps up to `iterations`, which is always last."""
    out = []
    for dec in (10, 100, 1000, 10000, 100000):
        for m in (1, 2, 5):
            k = m * dec
            if 50 <= k < iterations:
                out.append(k)
    return out + [iterations]


def label(p_c: float) -> str:
    return "RRT* (p_c = 0)" if p_c == 0 else f"MASR-RRT* p_c = {p_c:g}"


def fig5(size: MasrPlanBenchSize, card: Path, progress: Callable[[str], None],
         runner: Runner | None = None) -> dict[str, Any]:
    from armbridge.bench.masr_shards import sweep

    its = size.fig5_iterations
    # one shard per environment e: every planner at seed e (bench.masr_shards)
    done = sweep("fig5", card, its, [(e, [(p, e) for p in P_CS]) for e in range(size.environments)], runner)
    costs = {p: np.array([c[j] for c, _, _ in done]).reshape(-1, its) for j, p in enumerate(P_CS)}
    times = {p: np.array([t[j] for _, t, _ in done]) for j, p in enumerate(P_CS)}
    gen_s = sum(g for _, _, g in done)
    progress(f"fig5: {size.environments} environments")
    cps = checkpoints(its)
    rows = []
    for k in cps:
        at = {p: costs[p][:, k - 1] for p in P_CS}
        common = np.all([np.isfinite(at[p]) for p in P_CS], axis=0)
        row: dict[str, Any] = {"iterations": k, "common_solved": int(common.sum())}
        for p in P_CS:
            ok = np.isfinite(at[p])
            row[label(p)] = {
                "success_rate": float(ok.mean()),
                "mean_cost_common_s": float(at[p][common].mean()) if common.any() else None,
                "mean_cost_own_s": float(at[p][ok].mean()) if ok.any() else None,
            }
        rows.append(row)
    return {"environments": size.environments, "iterations": its, "environment_generation_s": gen_s,
            "rows": rows,
            "time_per_1000_s_mean": {label(p): float(times[p].mean() / its * 1000) for p in P_CS},
            "curves": {label(p): {"success_rate": np.isfinite(costs[p]).mean(0).tolist()} for p in P_CS}}


def fig7(size: MasrPlanBenchSize, card: Path, progress: Callable[[str], None],
         runner: Runner | None = None) -> dict[str, Any]:
    from armbridge.bench.masr_shards import FIG7_CHUNK, sweep
    from armbridge.planning.masr.rrt_star import percentile_success

    its = size.fig7_iterations
    cps = checkpoints(its)
    out: dict[str, Any] = {"trials": size.trials, "iterations": its, "environments": {}}
    # one shard per environment, planner and FIG7_CHUNK trial seeds (bench.masr_shards)
    groups = [(name, p, range(s, min(s + FIG7_CHUNK, size.trials))) for name in FIXED for p in (0.0, 0.6)
              for s in range(0, size.trials, FIG7_CHUNK)]
    done = sweep("fig7", card, its, [(name, [(p, s) for s in seeds]) for name, p, seeds in groups], runner)
    for name in FIXED:
        by = {label(p): [d for (env, q, _), d in zip(groups, done) if env == name and q == p] for p in (0.0, 0.6)}
        costs = {pl: np.concatenate([c for c, _, _ in ds]) for pl, ds in by.items()}
        times = {pl: np.concatenate([t for _, t, _ in ds]) for pl, ds in by.items()}
        rates = percentile_success(costs, LEVELS)
        seen = np.concatenate([c[np.isfinite(c)] for c in costs.values()])
        rows = []
        for k in cps:
            row: dict[str, Any] = {"iterations": k}
            for pl, c in costs.items():
                ok = np.isfinite(c[:, k - 1])
                row[pl] = {"success_rate": float(ok.mean()),
                           "mean_cost_s": float(c[ok, k - 1].mean()) if ok.any() else None,
                           **{f"below_p{int(lv * 100)}": float(rates[pl][lv][k - 1]) for lv in LEVELS}}
            rows.append(row)
        out["environments"][name] = {
            "cost_range_s": [float(seen.min()), float(seen.max())] if seen.size else None,
            "rows": rows,
            "time_per_1000_s_mean": {pl: float(t.mean() / its * 1000) for pl, t in times.items()},
            "curves": {pl: {f"below_p{int(lv * 100)}": rates[pl][lv].tolist() for lv in LEVELS} for pl in costs},
        }
        progress(f"fig7: {name} done")
    return out


def timing(size: MasrPlanBenchSize, goal_ik: Callable, progress: Callable[[str], None]) -> dict[str, Any]:
    from armbridge.bench.masr_shards import run_planner
    from armbridge.planning.masr.environment import fixed_environment

    out: dict[str, Any] = {}
    for name in FIXED:
        env = fixed_environment(name)
        chk = env.checker()
        row = {}
        for p in (0.0, 0.6):
            runs = [run_planner(env, p, 1000, 1000 + s, goal_ik, chk) for s in range(size.timing_runs)]
            ts = np.array([r.time_s for r in runs])
            cs = np.array([r.cost for r in runs])
            row[label(p)] = {"median_s_per_1000": float(np.median(ts)), "max_s_per_1000": float(ts.max()),
                             "success_rate": float(np.isfinite(cs).mean()),
                             "mean_cost_s": float(cs[np.isfinite(cs)].mean()) if np.isfinite(cs).any() else None}
        out[name] = row
    progress("timing done")
    return out


def ompl(size: MasrPlanBenchSize, progress: Callable[[str], None]) -> dict[str, Any]:
    from armbridge.planning.masr.environment import fixed_environment
    from armbridge.planning.masr.ompl_compare import ompl_available, ompl_rrt_star

    why = ompl_available()
    if why or size.ompl_runs == 0:
        return {"skipped": why or "ompl_runs = 0"}
    out: dict[str, Any] = {}
    for name in FIXED:
        env = fixed_environment(name)
        rs = [ompl_rrt_star(env, iterations=1000, seed=s) for s in range(size.ompl_runs)]
        cs = np.array([r["cost_s"] if r["success"] else np.inf for r in rs])
        out[name] = {"runs": len(rs), "median_s_per_1000": float(np.median([r["time_per_1000_s"] for r in rs])),
                     "success_rate": float(np.isfinite(cs).mean()),
                     "mean_cost_s": float(cs[np.isfinite(cs)].mean()) if np.isfinite(cs).any() else None,
                     "iterations_done": [int(r["iterations"]) for r in rs]}
        progress(f"ompl: {name} done")
    return out


def masr_not_worse(result: dict[str, Any]) -> dict[str, Any]:
    """Target check: MASR-RRT* (p_c 0.6) at least as good as RRT* at every reported iteration count."""
    base, masr = label(0.0), label(0.6)
    bad = []
    if "fig5" in result:
        for row in result["fig5"]["rows"]:
            b, m = row[base], row[masr]
            if m["success_rate"] < b["success_rate"]:
                bad.append(f"fig5 success @ {row['iterations']}")
            if b["mean_cost_common_s"] is not None and m["mean_cost_common_s"] > b["mean_cost_common_s"] + 1e-9:
                bad.append(f"fig5 cost @ {row['iterations']}")
    for name, e in result.get("fig7", {}).get("environments", {}).items():
        for row in e["rows"]:
            for key in ("success_rate", "below_p15", "below_p25"):
                if row[masr][key] < row[base][key]:
                    bad.append(f"fig7 {name} {key} @ {row['iterations']}")
    return {"met": not bad, "violations": bad}


def run(size: MasrPlanBenchSize, card: Path = CARD_12, parts: tuple[str, ...] = ("fig5", "fig7", "timing", "ompl"),
        progress: Callable[[str], None] = lambda s: None, runner: Runner | None = None) -> dict[str, Any]:
    """The parts asked for; Fig. 5 and Fig. 7 run as shards where `runner` says (None: here, serially),
    the timing and OMPL parts here (they measure this machine)."""
    from armbridge.bench.masr_shards import goal_ik

    result: dict[str, Any] = {"benchmark": "masr-plan (section V-C)", "size": asdict(size), "goal_ik": card.name,
                              "machine": {"python": platform.python_version(),
                                          "cpu": platform.processor() or platform.machine()},
                              "shards": runner.backend if runner is not None else "serial"}
    t0 = time.perf_counter()
    from armbridge.planning.base import compile_note

    note = compile_note("masr")
    if note is not None:
        progress(note)
    if "timing" in parts:
        result["timing"] = timing(size, goal_ik(card), progress)
    if "ompl" in parts:
        result["ompl"] = ompl(size, progress)
    if "fig7" in parts:
        result["fig7"] = fig7(size, card, progress, runner)
    if "fig5" in parts:
        result["fig5"] = fig5(size, card, progress, runner)
    if "margin" in parts:
        from armbridge.bench.masr_margin import margins

        result["margin"] = margins(max(size.timing_runs, 1), goal_ik(card), progress)
    result["target_masr_not_worse"] = masr_not_worse(result)
    result["wall_s"] = time.perf_counter() - t0
    return result


def plots(result: dict[str, Any], png_dir: Path) -> list[Path]:
    """Fig. 5 (success rate and cost vs iterations) and Fig. 7 (share below the 15th/25th percentile), as PNGs.

    The figures themselves are bench.plots.fig5_figure / fig7_figure.
    """
    from armbridge.bench.plots import fig5_figure, fig7_figure
    from armbridge.planning.figure import finish

    written: list[Path] = []
    if "fig5" in result:
        written.append(finish(fig5_figure(result["fig5"]), png_dir / "masr-fig5.png"))
    if "fig7" in result:
        written.append(finish(fig7_figure(result["fig7"], LEVELS), png_dir / "masr-fig7.png"))
    return written


def masr_plan_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 3 environments, 4 trials, 200 iterations."),
    environments: int = typer.Option(None, "--environments", help="Fig. 5 random environments (full run: 300)."),
    fig5_iterations: int = typer.Option(None, "--fig5-iterations", help="Fig. 5 iterations per run (full: 3000)."),
    trials: int = typer.Option(None, "--trials", help="Fig. 7 trials per environment and planner (full: 200)."),
    fig7_iterations: int = typer.Option(None, "--fig7-iterations", help="Fig. 7 iterations per trial (full: 12000)."),
    timing_runs: int = typer.Option(None, "--timing-runs", help="Runs of 1,000 iterations per planner and environment."),
    ompl_runs: int = typer.Option(None, "--ompl-runs", help="OMPL RRT* runs per environment (0: skip)."),
    parts: str = typer.Option("timing,ompl,fig7,fig5", "--parts",
                              help="Which parts to run (comma-separated): timing, ompl, fig7, fig5, margin (clearance "
                                   "margins on E1-E3, --timing-runs seeds each)."),
    card: Path = typer.Option(None, "--card", help="Goal IK model card [default: models/onnx/masr5-iknn-card.json]."),
    json_out: Path = typer.Option(Path("runs/bench-masr-plan.json"), "--json", help="Where to write the results ('-': stdout)."),
    png_dir: Path = typer.Option(None, "--png-dir", help="Also write Fig. 5 / Fig. 7 plots (PNG) here."),
    ray: Optional[str] = shard_options.ray_option(),
    workers: int = shard_options.workers_option(),
    checkpoint: Optional[Path] = shard_options.checkpoint_option("none: shards are not kept"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show the shards' progress bar."),
) -> None:
    """Section V-C of the masr paper: Fig. 5 (random environments, p_c in {0, 0.2, 0.6, 1}),
    Fig. 7 (E1-E3 cost percentiles), time per 1,000 iterations, and OMPL's RRT* beside ours.

    Fig. 5 (one shard per environment) and Fig. 7 (one per environment, planner and 10
    trials) run as shards (--ray, --workers; docs/cluster.md) with the serial run's costs;
    the timing and OMPL parts run here."""
    from dataclasses import replace

    from rich.console import Console
    from rich.table import Table

    size = QUICK if quick else FULL
    for name, v in (("environments", environments), ("fig5_iterations", fig5_iterations), ("trials", trials),
                    ("fig7_iterations", fig7_iterations), ("timing_runs", timing_runs), ("ompl_runs", ompl_runs)):
        if v is not None:
            size = replace(size, **{name: v})
    console = Console()
    chosen = tuple(p.strip() for p in parts.split(",") if p.strip())
    with shard_options.runner(ray, workers, checkpoint, progress) as runner:
        result = run(size, card=card or CARD_12, parts=chosen,
                     progress=lambda text: console.print(f"[dim]bench masr-plan: {text}[/]"), runner=runner)
    write_json(result, json_out)

    def fmt(v: object, spec: str = ".2f") -> str:
        return "-" if v is None else format(v, spec)

    if "timing" in result:
        t = Table(title="seconds per 1,000 iterations (median) and cost at 1,000 iterations")
        for col in ("env", "planner", "s / 1000 it (median)", "success", "mean cost (s)"):
            t.add_column(col, justify="left" if col in ("env", "planner") else "right")
        om = result.get("ompl", {})
        for env, row in result["timing"].items():
            for pl, r in row.items():
                t.add_row(env, pl, f"{r['median_s_per_1000']:.3f}", f"{r['success_rate']:.0%}", fmt(r["mean_cost_s"]))
            if env in om:
                o = om[env]
                t.add_row(env, "OMPL RRTstar (eq. 8)", f"{o['median_s_per_1000']:.3f}", f"{o['success_rate']:.0%}",
                          fmt(o["mean_cost_s"]))
        console.print(t)
    if "fig5" in result:
        f5 = result["fig5"]
        t = Table(title=f"Fig. 5: {f5['environments']} random environments: success rate / mean cost (s) "
                        "over the commonly solved")
        t.add_column("iterations", justify="right")
        for pl in f5["curves"]:
            t.add_column(pl, justify="right")
        for row in f5["rows"]:
            t.add_row(str(row["iterations"]), *[f"{row[pl]['success_rate']:.0%} / {fmt(row[pl]['mean_cost_common_s'])}"
                                                for pl in f5["curves"]])
        console.print(t)
    if "fig7" in result:
        f7 = result["fig7"]
        t = Table(title=f"Fig. 7: E1-E3, {f7['trials']} trials each: share below the 15th / 25th percentile "
                        "of the normalised cost range")
        t.add_column("env")
        t.add_column("iterations", justify="right")
        pls = None
        for env, e in f7["environments"].items():
            if pls is None:
                pls = list(e["curves"])
                for pl in pls:
                    t.add_column(pl, justify="right")
            for row in e["rows"]:
                t.add_row(env, str(row["iterations"]),
                          *[f"{row[pl]['below_p15']:.0%} / {row[pl]['below_p25']:.0%}" for pl in pls])
        console.print(t)
    if "margin" in result:
        from armbridge.bench.masr_margin import table

        console.print(table(result))
    tgt = result["target_masr_not_worse"]
    console.print(f"MASR-RRT* (p_c 0.6) at least as good as RRT* at every iteration count: "
                  f"{'met' if tgt['met'] else 'MISSED: ' + ', '.join(tgt['violations'][:10])}")
    if png_dir is not None:
        for p in plots(result, png_dir):
            console.print(f"wrote {p}")
    console.print(f"wrote {json_out}")
