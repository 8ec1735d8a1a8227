"""`armbridge bench`: one subcommand per measured capability."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Optional

import typer

from armbridge.shards import cli as shard_options

bench_app = typer.Typer(help="Measure the numbers in docs/benchmarks.md; each writes JSON.", no_args_is_help=True)


def write_json(result: dict, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1) + "\n")


@bench_app.command("link")
def link_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 20,000 damaged lines per version, "
                               "300 waypoints, 50 pings, 5 e-stops, 15 s soak."),
    soak_s: float = typer.Option(None, "--soak", min=1.0, help="Soak length in seconds (full run: 600)."),
    damaged: int = typer.Option(None, "--damaged", min=1, help="Damaged lines per protocol version (full run: 10^7)."),
    workers: int = typer.Option(2, "--workers", min=1, help="Processes for the damage model."),
    json_out: Path = typer.Option(None, "--json", help="Where to write the results "
                                  "[default: runs/bench-link.json, runs/bench-link-BOARD.json for another board]."),
    board: str = typer.Option("esp32", "--board", help="The emulated board: esp32 (the MicroPython firmware, paced "
                              "to the wall clock) or arduino_pump (the .elf in simavr in lockstep, on its clock; "
                              "adds the Modbus round trip, leaves out the damage model)."),
    load: float = typer.Option(0.0, "--load", min=0.0, help="Busy-loop processes per core beside the run: then "
                               "throughput, round trip and e-stop only, for the figures at load (bench load)."),
) -> None:
    """The line protocol: undetected errors of v1 and v2 under the UART fault mix, and,
    over a pty paced at 115200 baud, throughput, round trip, e-stop latency and a soak
    under link faults and board resets."""
    from dataclasses import replace

    from rich.console import Console

    from armbridge.bench import link

    if board not in link.BOARDS:
        raise typer.BadParameter(f"{board!r}: use one of {', '.join(link.BOARDS)}", param_hint="--board")
    if json_out is None:
        tag = ("" if board == "esp32" else f"-{board}") + (f"-load{load:g}" if load else "")
        json_out = Path(f"runs/bench-link{tag}.json")
    size = link.QUICK if quick else link.FULL
    if soak_s is not None:
        size = replace(size, soak_s=soak_s, reset_every_s=min(size.reset_every_s, soak_s / 2))
    if damaged is not None:
        size = replace(size, damaged_lines=damaged)
    console = Console()
    result = link.run(size, progress=lambda text: console.print(f"[dim]bench link: {text}[/]"), workers=workers,
                      board=board, load=load)
    write_json(result, json_out)
    link.print_result(result, console)
    console.print(f"wrote {json_out}")


@bench_app.command("masr-ik")
def masr_ik_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 40 trials, NR on 4 of them with m = 50."),
    trials: int = typer.Option(None, "--trials", help="Table I trials (full run: 5000)."),
    nr_trials: int = typer.Option(None, "--nr-trials", help="How many of the trials the NR baseline solves (full: all)."),
    nr_restarts: int = typer.Option(None, "--nr-restarts", help="NR restarts m (full run: 1000)."),
    card12: Path = typer.Option(None, "--card", help="IK-NN (12) model card [default: models/onnx/masr5-iknn-card.json]."),
    card11: Path = typer.Option(None, "--card11", help="IK-NN (11) model card [default: models/onnx/masr5-iknn-reg11-card.json]."),
    seed: int = typer.Option(2024, "--seed", help="Seed of the random trials."),
    json_out: Path = typer.Option(Path("runs/bench-masr-ik.json"), "--json", help="Where to write the results."),
) -> None:
    """Table I of the masr paper (section V-B): IK-NN (11), IK-NN (12), + refinement, + fallback,
    int8, and the numeric NR baseline; accuracy, action time and time per query. Success is the
    goal check over the robot's joint margin d_margin (every answer holds it)."""
    from dataclasses import replace

    from rich.console import Console
    from rich.table import Table

    from armbridge.bench import masr_ik

    size = masr_ik.QUICK if quick else masr_ik.FULL
    for name, v in (("trials", trials), ("nr_trials", nr_trials), ("nr_restarts", nr_restarts)):
        if v is not None:
            size = replace(size, **{name: v})
    console = Console()
    result = masr_ik.run(size, card12=card12 or masr_ik.CARD_12, card11=card11 or masr_ik.CARD_11,
                         seed=seed, progress=lambda text: console.print(f"[dim]bench masr-ik: {text}[/]"))
    write_json(result, json_out)

    table = Table(title=f"armbridge bench masr-ik (Table I protocol, {size.trials} trials, "
                        f"e_p 8 mm, e_phi 4 deg; NR on {result['nr_trials']})")
    for col in ("row", "mean dp (mm)", "mean dphi (deg)", "success (%)", "mean action time (s)",
                "single query (ms, median)", "batched (queries/s)"):
        table.add_column(col, justify="left" if col == "row" else "right")
    for r in result["rows"]:
        if "missing" in r:
            table.add_row(r["row"], r["missing"], "", "", "", "", "")
            continue
        table.add_row(f"{r['row']}" + (f" [{r['model']}]" if r["row"].startswith("NR") else ""),
                      f"{r['mean_dp_mm']:.2f}", f"{r['mean_dphi_deg']:.2f}", f"{r['success_rate']:.1f}",
                      f"{r['mean_action_time_s']:.2f}", f"{r['single']['median_ms']:.3f}",
                      f"{r['batched_queries_per_s']:,.0f}")
    console.print(table)
    if result["nr_trials"]:
        sub = Table(title=f"on the NR trials ({result['nr_trials']}): same queries for every row")
        for col in ("row", "mean dp (mm)", "success (%)", "mean action time (s)"):
            sub.add_column(col, justify="left" if col == "row" else "right")
        for r in result["rows"]:
            s = r if r["row"].startswith("NR") else r.get("on_nr_subset")
            if s:
                sub.add_row(r["row"], f"{s['mean_dp_mm']:.2f}", f"{s['success_rate']:.1f}",
                            f"{s['mean_action_time_s']:.2f}")
        console.print(sub)
    fb = next((r["fallback"] for r in result["rows"] if "fallback" in r), None)
    if fb:
        console.print(f"fallback: {fb['queries']} queries ({fb['share_pct']:.2f} %), {fb['solved']} solved, "
                      f"+{fb['added_ms_per_fallback_query']:.2f} ms per fallback query "
                      f"(+{fb['added_ms_per_query_batched'] * 1e3:.1f} us per query batched); "
                      f"goal check over d_margin = {result['d_margin_m'] * 1e3:g} mm")
    console.print("targets: " + ", ".join(f"{k} {'met' if v else 'MISSED'}" for k, v in result["targets"].items()))
    console.print(f"wrote {json_out}")


@bench_app.command("masr-plan")
def masr_plan_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 3 environments, 4 trials, 200 iterations."),
    environments: int = typer.Option(None, "--environments", help="Fig. 5 random environments (full run: 300)."),
    fig5_iterations: int = typer.Option(None, "--fig5-iterations", help="Fig. 5 iterations per run (full: 3000)."),
    trials: int = typer.Option(None, "--trials", help="Fig. 7 trials per environment and planner (full: 200)."),
    fig7_iterations: int = typer.Option(None, "--fig7-iterations", help="Fig. 7 iterations per trial (full: 12000)."),
    timing_runs: int = typer.Option(None, "--timing-runs", help="Runs of 1,000 iterations per planner and environment."),
    ompl_runs: int = typer.Option(None, "--ompl-runs", help="OMPL RRT* runs per environment (0: skip)."),
    parts: str = typer.Option("timing,ompl,fig7,fig5", "--parts", help="Which parts to run (comma-separated)."),
    card: Path = typer.Option(None, "--card", help="Goal IK model card [default: models/onnx/masr5-iknn-card.json]."),
    json_out: Path = typer.Option(Path("runs/bench-masr-plan.json"), "--json", help="Where to write the results."),
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

    from armbridge.bench import masr_plan as mp

    size = mp.QUICK if quick else mp.FULL
    for name, v in (("environments", environments), ("fig5_iterations", fig5_iterations), ("trials", trials),
                    ("fig7_iterations", fig7_iterations), ("timing_runs", timing_runs), ("ompl_runs", ompl_runs)):
        if v is not None:
            size = replace(size, **{name: v})
    console = Console()
    chosen = tuple(p.strip() for p in parts.split(",") if p.strip())
    with shard_options.runner(ray, workers, checkpoint, progress) as runner:
        result = mp.run(size, card=card or mp.CARD_12, parts=chosen,
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
    tgt = result["target_masr_not_worse"]
    console.print(f"MASR-RRT* (p_c 0.6) at least as good as RRT* at every iteration count: "
                  f"{'met' if tgt['met'] else 'MISSED: ' + ', '.join(tgt['violations'][:10])}")
    if png_dir is not None:
        for p in mp.plots(result, png_dir):
            console.print(f"wrote {p}")
    console.print(f"wrote {json_out}")


@bench_app.command("masr-exec")
def masr_exec_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 3 random environments, 300 iterations, "
                                                      "no E1-E3."),
    environments: int = typer.Option(None, "--environments", help="Random solvable environments (full run: 50)."),
    iterations: int = typer.Option(None, "--iterations", help="MASR-RRT* iterations per plan (full run: 1000)."),
    json_out: Path = typer.Option(Path("runs/bench-masr-exec.json"), "--json", help="Where to write the results."),
) -> None:
    """MASR plans executed on the emulated MA (emu:masr_ma): planned tau against executed time, the true final
    pose errors, localisation errors, and what the ramps and loops add over eq. (8), beside the paper's Table II."""
    from dataclasses import replace

    from rich.console import Console
    from rich.table import Table

    from armbridge.bench import masr_exec as mx

    size = mx.QUICK if quick else mx.FULL
    if environments is not None:
        size = replace(size, environments=environments)
    if iterations is not None:
        size = replace(size, iterations=iterations)
    console = Console()
    result = mx.run(size, progress=lambda text: console.print(f"[dim]bench masr-exec: {text}[/]"))
    write_json(result, json_out)
    t = Table(title="MASR plans executed on the emulated MA (true pose from the plant)")
    for col in ("set", "runs", "tau (s)", "executed (s)", "executed / tau", "within 10 %", "dp mm (mean / max)",
                "dphi deg (mean / max)", "at goal"):
        t.add_column(col, justify="left" if col == "set" else "right")
    paper = mx.PAPER_TABLE_II
    t.add_row("paper, Table II (E1)", "-", f"{paper['planned_s']:.2f}",
              f"{paper['executed_mean_s']:.2f} +- {paper['executed_std_s']:.2f}",
              f"{paper['executed_mean_s'] / paper['planned_s']:.3f}", "-", "-", "-", "-")
    for key, label in (("random", f"{size.environments} random"), ("fixed", "E1-E3")):
        s = result.get(key, {}).get("summary")
        if not s or not s.get("completed"):
            continue
        t.add_row(label, f"{s['completed']}/{s['runs']}", f"{s['tau_s']['mean']:.2f} +- {s['tau_s']['std']:.2f}",
                  f"{s['executed_s']['mean']:.2f} +- {s['executed_s']['std']:.2f}",
                  f"{s['time_ratio']['mean']:.3f} (max {s['time_ratio']['max']:.3f})", f"{s['within_10_percent']:.0%}",
                  f"{s['dp_mm']['mean']:.2f} / {s['dp_mm']['max']:.2f}",
                  f"{s['dphi_deg']['mean']:.2f} / {s['dphi_deg']['max']:.2f}", f"{s['at_goal']:.0%}")
    console.print(t)
    s = result["random"]["summary"]
    if s.get("completed"):
        o = Table(title="what the ramps and loops add over eq. (8), per action (random environments)")
        for col in ("action", "count", "measured (s)", "trapezoid ramp alone (s)", "share of tau"):
            o.add_column(col, justify="left" if col == "action" else "right")
        for kd, v in s["overhead"].items():
            if v["actions"]:
                o.add_row(kd, str(v["actions"]), f"{v['per_action_s']:.3f}", f"{v['ramp_per_action_s']:.3f}",
                          f"{v['share_of_tau']:.1%}")
        console.print(o)
        console.print(f"localisation |estimate - true d|: mean {s['loc_mean_mm']:.2f} mm, max {s['loc_max_mm']:.2f} "
                      f"mm ({s['loc_max_over_bound']:.0%} of the board's bound at worst); right after a magnet: mean "
                      f"{s['after_magnet_mean_mm']:.2f} mm, max {s['after_magnet_max_mm']:.2f} mm; every action once: "
                      f"{'yes' if s['log_exactly_once'] else 'NO'}")
    console.print(f"wrote {json_out}")


@bench_app.command("smm")
def smm_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 40 locations, 2 for realtime-smm, 20 trials."),
    locations: int = typer.Option(None, "--locations", help="Table III locations for the 3R and 4R (full run: 10000)."),
    robots: str = typer.Option("planar3r,spatial4r,spatial7r", "--robots", help="Comma-separated SMM arms."),
    json_out: Path = typer.Option(Path("runs/bench-smm.json"), "--json", help="Where to write the results."),
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

    from armbridge.bench import smm
    from armbridge.smm.arms import get_smm_arm

    size = smm.QUICK if quick else smm.FULL
    if locations is not None:
        size = replace(size, locations=locations)
    names = tuple(r.strip() for r in robots.split(",") if r.strip())
    for name in names:
        get_smm_arm(name)  # a clear error before any work
    console = Console()
    with shard_options.runner(ray, workers, checkpoint, progress) as runner:
        result = smm.run(size, names, progress=lambda text: console.print(f"[dim]bench smm: {text}[/]"),
                         models=models or smm.MODELS, runner=runner)
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
        console.print(f"wrote {smm.fig3_png(result, png)}")


@bench_app.command("firmware")
def firmware_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 200 repetitions per item."),
    reps: int = typer.Option(None, "--reps", min=10, help="Repetitions per item (full run: 2000)."),
    device: str = typer.Option("esp32", "--device", help="A MicroPython board of the emulator."),
    json_out: Path = typer.Option(Path("runs/bench-firmware.json"), "--json", help="Where to write the results."),
) -> None:
    """The firmware's cost per received line (each verb) and per control tick under
    the real MicroPython interpreter (WebAssembly, by Node) and under CPython."""
    from rich.console import Console

    from armbridge.bench import firmware_cost as fc

    console = Console()
    n = reps if reps is not None else (fc.QUICK_REPS if quick else fc.REPS)
    result = fc.run(device, n, progress=lambda text: console.print(f"[dim]bench firmware: {text}[/]"))
    write_json(result, json_out)
    fc.print_result(result, console)
    console.print(f"wrote {json_out}")


@bench_app.command("arm3r")
def arm3r_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 3 of the 12 samples, 2,000 random CBF "
                               "targets, 10 points timed singly and solved by RTB LM."),
    seed: int = typer.Option(10, "--seed", help="Seed of the random CBF targets."),
    json_out: Path = typer.Option(Path("runs/bench-arm3r.json"), "--json", help="Where to write the results."),
    lyapunov_png: Path = typer.Option(None, "--lyapunov-png", help="Also plot Fig. 13 (the CBF's Lyapunov "
                                      "function along each sample) to this PNG."),
) -> None:
    """Tables 5-8 of the 3R drawing-arm paper on its twelve samples: MSE, RMSE, MAE in
    x, y, q1-q3, theta for ANN, ANN + FABRIK, ANN + FABRIK + CBF, the closed form and
    RTB LM; time per point; CBF violations over random targets; the Lyapunov function
    checked to decrease (Fig. 13); int8 against float."""
    from rich.console import Console
    from rich.table import Table

    from armbridge.bench import arm3r

    console = Console()
    result = arm3r.run(arm3r.QUICK if quick else arm3r.FULL, seed=seed, lyapunov_png=lyapunov_png,
                       progress=lambda text: console.print(f"[dim]bench arm3r: {text}[/]"))
    write_json(result, json_out)
    table = Table(title="armbridge bench arm3r: overall (Tables 5, 8); x, y mm, angles deg: MSE / RMSE / MAE")
    for col in ("row", *arm3r.COLS, "mean tip (mm)"):
        table.add_column(col, justify="left" if col == "row" else "right")
    for row, s in result["overall"].items():
        if "missing" in s:
            table.add_row(row, s["missing"], *[""] * 6)
            continue
        table.add_row(row, *[f"{s[c]['mse']:.3g} / {s[c]['rmse']:.3g} / {s[c]['mae']:.3g}" for c in arm3r.COLS],
                      f"{s['tip_mm']['mean']:.2g}")
    console.print(table)
    rc = result["random_cbf"]
    console.print(f"CBF on {rc['targets']:,} random targets ({rc['outside_region']:,} outside the region): "
                  f"{rc['region_violations']} region and {rc['limit_violations']} joint-limit violations")
    ly = result["lyapunov"]
    console.print(f"Lyapunov V on {ly['rows']} samples, {ly['checked']:,} filter steps: {ly['violations']} rises "
                  f"(max change {ly['max_increase']:.3g} rad^2), {ly['constrained_steps']} steps constrained"
                  + (f"; wrote {ly['png']}" if "png" in ly else ""))
    dr = result["drawing"]
    for name, run in dr["runs"].items():
        console.print(f"ROBOTICS at {dr['speed_m_s']:g} m/s on {name}: " + (
            f"trace from strokes {run['trace_mean_mm']:.2f} / {run['trace_max_mm']:.2f} mm, strokes from trace "
            f"{run['target_mean_mm']:.2f} / {run['target_max_mm']:.2f} mm (mean / max), "
            f"{run['s_per_character']:.2f} s per character" if run.get("completed") else f"FAILED: {run.get('error')}"))
    console.print("targets: " + ", ".join(f"{k} {'met' if v else 'MISSED'}" for k, v in result["targets"].items()))
    console.print(f"wrote {json_out}")


@bench_app.command("board-ik")
def board_ik_cmd(
    points: int = typer.Option(2000, "--points", min=10, help="Random targets per set (two sets: at the pen "
                               "angle, and +- 0.25 rad around it)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the random targets."),
    json_out: Path = typer.Option(Path("runs/bench-board-ik.json"), "--out", "--json",
                                  help="Where to write the results."),
) -> None:
    """The ESP32's Cartesian IK (int8 net + FABRIK, firmware/esp32/ik3r.py) under the
    real MicroPython interpreter and CPython: net size, multiply-adds and time per
    point, answers against the host's int8 reference and the float net, tip errors."""
    from rich.console import Console

    from armbridge.bench import board_ik

    console = Console()
    result = board_ik.board_ik_report(points, seed,
                                      progress=lambda text: console.print(f"[dim]bench board-ik: {text}[/]"))
    write_json(result, json_out)
    board_ik.print_report(result, console)
    console.print(f"wrote {json_out}")


@bench_app.command("wjrrt")
def wjrrt_cmd(
    seeds: int = typer.Option(None, "--seeds", min=1, help="Seeds per scene and planner (full run: 100)."),
    scenes: str = typer.Option("two-arm,three-arm,seven-tube,horn", "--scenes",
                               help="Comma-separated fixed scenes (planning/soft/scenes)."),
    planners: str = typer.Option("wjrrt,jt-rrt,birrt,RRTConnect,KPIECE1,STRIDE", "--planners",
                                 help="Comma-separated: ours (wjrrt, jt-rrt, birrt) and OMPL's (RRTConnect, "
                                      "KPIECE1, STRIDE)."),
    time_limit: float = typer.Option(None, "--time-limit", min=0.001,
                                     help="Wall-clock budget T per run, every planner (s; full run: 2)."),
    iterations: int = typer.Option(None, "--iterations", min=1,
                                   help="Our planners' iteration budget [default: each scene's, Table 1's Iter.]."),
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 2 seeds, T = 0.5 s."),
    json_out: Path = typer.Option(Path("runs/bench-wjrrt.json"), "--json", help="Where to write the results."),
    png: Path = typer.Option(None, "--png", help="Also write the figures (wjrrt-success.png, wjrrt-time.png) "
                                                 "into this folder."),
    ray: Optional[str] = shard_options.ray_option(),
    workers: int = shard_options.workers_option(),
    checkpoint: Optional[Path] = shard_options.checkpoint_option("none: shards are not kept"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show the shards' progress bar."),
) -> None:
    """Table 1 of the WJRRT paper (success, iterations, time, nodes, track / goal / random nodes,
    obstacle checks, H) for WJRRT, JT-RRT, Bi-RRT and OMPL's RRTConnect, KPIECE1, STRIDE on the
    same scenes and checker, every run with the same time budget; success against the budget.

    One shard per scene and seed, every planner on it in turn (--ray, --workers; docs/cluster.md):
    our planners' runs are the serial run's but their times, where no run ran out of the budget;
    OMPL's are time-bound and not reproducible; times are measured where each shard ran."""
    from dataclasses import replace

    from rich.console import Console

    from armbridge.bench import wjrrt

    size = wjrrt.QUICK if quick else wjrrt.FULL
    if seeds is not None:
        size = replace(size, seeds=seeds)
    if time_limit is not None:
        size = replace(size, time_limit=time_limit)
    console = Console()
    with shard_options.runner(ray, workers, checkpoint, progress) as runner:
        result = wjrrt.run(size, tuple(s.strip() for s in scenes.split(",") if s.strip()),
                           tuple(p.strip() for p in planners.split(",") if p.strip()), iterations=iterations,
                           progress=lambda text: console.print(f"[dim]bench wjrrt: {text}[/]"), runner=runner)
    write_json(result, json_out)
    wjrrt.print_result(result, console)
    if png is not None:
        from armbridge.bench.wjrrt_plots import plots

        for p in plots(result, png):
            console.print(f"wrote {p}")
    console.print(f"wrote {json_out}")


@bench_app.command("shards")
def shards_cmd(
    locations: int = typer.Option(1024, "--locations", min=1, help="Locations of the fixed SMM data job."),
    robot: str = typer.Option("spatial7r", "--robot", help="SMM arm of the job (the projection is the 7R's only)."),
    shard: int = typer.Option(256, "--shard", min=1, help="Locations per shard."),
    workers: str = typer.Option("1,2", "--workers", help="Worker counts to time, comma-separated (1: serial here; "
                                                         "N > 1: a local Ray of N CPUs)."),
    json_out: Path = typer.Option(Path("runs/bench-shards.json"), "--json", help="Where to write the results."),
) -> None:
    """Scaling of a fixed SMM data job (7R nullspace SMMs in shards) with the worker count: wall
    time, speed-up, efficiency; and the projected time of the paper's 7R grid on N workers."""
    from rich.console import Console

    from armbridge.bench import shards
    from armbridge.errors import ArmbridgeError

    try:
        counts = tuple(int(w) for w in workers.split(",") if w.strip())
    except ValueError:
        raise ArmbridgeError(f"--workers must be counts like 1,2, got {workers!r}") from None
    if not counts or min(counts) < 1:
        raise ArmbridgeError(f"--workers must be counts >= 1 like 1,2, got {workers!r}")
    console = Console()
    result = shards.run(locations, shard, counts, robot,
                        progress=lambda text: console.print(f"[dim]bench shards: {text}[/]"))
    write_json(result, json_out)
    for r in result["rows"]:
        eff = "-" if r["efficiency"] is None else f"{r['efficiency']:.2f}"
        console.print(f"{r['workers']} worker(s): {r['wall_s']:.1f} s wall, shards' nullspace {r['shard_seconds_sum']:.1f} s, "
                      f"efficiency {eff}, identical {r['identical_to_first']}")
    projection = result["projection_paper_7r_grid"]
    if projection:
        days = projection["days_on_n_workers"]
        console.print("paper's 7R grid (1.536e8 SMMs): " + ", ".join(f"{n} workers {d:.3g} days" for n, d in days.items()))
    console.print(f"wrote {json_out}")


@bench_app.command("load")
def load_cmd(
    loads: str = typer.Option("0,1,3", "--loads", metavar="L,L,...",
                              help="Busy-loop processes per core beside the runs, one measurement each."),
    boards: str = typer.Option("esp32,arduino_pump", "--boards", help="Boards of the session measurement."),
    where: str = typer.Option("emu,pty", "--where", help="emu: the emulator paced in this process; pty: "
                              "`armbridge emulate` in another process, on its pseudo-terminal."),
    engines: str = typer.Option("inline,auto", "--engines", help="Where the session runs: inline (the caller's "
                                "thread), thread, process, auto (thread for emu, process for pty)."),
    busy_caller: bool = typer.Option(True, "--busy-caller/--idle-caller",
                                     help="Keep the caller's thread busy: pure-Python work per telemetry sample "
                                          "and a 1.5 s call holding the GIL every 4 s."),
    seconds: float = typer.Option(12.0, "--seconds", min=2.0, help="Length of each session's plan (board time)."),
    demos: str = typer.Option("", "--demos", metavar="R,R,...",
                              help="Also run these demos (arm3r, masr, soft) as a user does, --runs times each, "
                                   "on emu and pty, at the highest load; empty: none."),
    runs: int = typer.Option(20, "--runs", min=1, help="Runs of each demo."),
    demo_loads: str = typer.Option(None, "--demo-loads", help="Loads of the demo runs [default: the highest "
                                                               "of --loads]."),
    realtime: bool = typer.Option(False, "--realtime", help="Run the pty boards with `armbridge emulate "
                                  "--realtime` (the board as a chip of its own, not slowed by the load)."),
    json_out: Path = typer.Option(Path("runs/bench-load.json"), "--json", help="Where to write the results."),
) -> None:
    """Runs under load (docs/benchmarks.md, "Runs under load"): keep-alive lateness, timeouts,
    spurious timeouts and watchdog trips with N busy processes per core and the caller's thread
    kept busy, the session in the caller's thread or in the link engine; and the demos as a
    user runs them, on the in-process emulator and on `armbridge emulate`'s pty."""
    from rich.console import Console

    from armbridge.bench import load as L

    def floats(text: str, name: str) -> list[float]:
        try:
            return [float(x) for x in text.split(",") if x.strip()]
        except ValueError:
            raise typer.BadParameter(f"{text!r}: numbers separated by commas", param_hint=name) from None

    def names(text: str, allowed, name: str) -> list[str]:
        out = [x.strip() for x in text.split(",") if x.strip()]
        bad = [x for x in out if x not in allowed]
        if bad:
            raise typer.BadParameter(f"{', '.join(bad)}: use {', '.join(allowed)}", param_hint=name)
        return out

    load_list = floats(loads, "--loads")
    console = Console(width=160)
    progress = lambda text: console.print(f"[dim]bench load: {text}[/]")  # noqa: E731
    result: dict = {"cores": os.cpu_count(), "hog_s": L.HOG_S, "hog_every_s": L.HOG_EVERY_S,
                    "spin_per_sample_s": L.SPIN_PER_SAMPLE_S, "realtime": realtime}
    result["sessions"] = L.run_sessions(names(boards, L.ROBOT_OF, "--boards"), names(where, ("emu", "pty"), "--where"),
                                        names(engines, ("inline", "thread", "process", "auto"), "--engines"),
                                        load_list, busy_caller, seconds, progress, realtime)
    if demos:
        robots = names(demos, L.DEMO_BOARD, "--demos")
        dl = floats(demo_loads, "--demo-loads") if demo_loads else [max(load_list)]
        rows = L.run_demos(robots, names(where, ("emu", "pty"), "--where"), dl, runs, progress, realtime)
        result["demo_runs"] = rows
        result["demos"] = L.summarize_demos(rows)
    write_json(result, json_out)
    L.print_result(result, console)
    console.print(f"wrote {json_out}")
