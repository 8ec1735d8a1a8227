"""Figures of `armbridge bench wjrrt`: success against the time budget, and the time per plan.

* success_figure: one panel per scene, the share of runs that reached the
  goal within a budget of t seconds (the equal-time curve of bench/wjrrt.py:
  the empirical distribution of the time to success), t on a log axis.
* time_figure: per scene a group of boxes, one per planner, of the time of
  the successful runs (log axis), the success count under each box.

Every planner keeps one colour, marker and line style in every panel and
both figures. Colours are Okabe-Ito (colour-blind safe) in two families: our
planners in the cool colours (WJRRT blue, JT-RRT sky blue, Bi-RRT green),
OMPL's in the warm ones (RRTConnect vermillion, KPIECE1 orange, STRIDE
reddish purple); ours are solid, OMPL's dashed with hollow markers. Curves
that coincide stay visible: ours are drawn first and wider (a curve on top
of another leaves its neighbour's edges showing) and each curve's markers
sit at budgets shifted a little per planner. Log axes carry plain 1-2-5
tick labels in seconds (0.01, 0.02, 0.05, ...), the legend sits below the
panels, never on the data.

`wjrrt_cmd` is the `armbridge bench wjrrt` command: it lives here, above
bench/wjrrt.py, because it runs the bench and then draws these figures
(`--png`); wjrrt.py cannot import this module back (no circles).
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Optional

import numpy as np
import typer

from armbridge.bench.command import write_json
from armbridge.bench.wjrrt import (FULL, LABELS, OURS, PLANNERS, QUICK, TARGET_MEDIAN_S, run,
                                    time_to_success)
from armbridge.bench.wjrrt_table import print_result
from armbridge.planning.figure import OKABE_ITO, pyplot
from armbridge.shards import cli as shard_options

STYLE: dict[str, dict[str, Any]] = {
    "wjrrt": {"color": OKABE_ITO["blue"], "marker": "o", "lw": 2.8},
    "jt-rrt": {"color": OKABE_ITO["sky"], "marker": "s", "lw": 2.2},
    "birrt": {"color": OKABE_ITO["green"], "marker": "^", "lw": 1.7},
    "wjrrt-connect": {"color": OKABE_ITO["black"], "marker": "*", "lw": 2.4},
    "RRTConnect": {"color": OKABE_ITO["vermillion"], "marker": "D", "lw": 1.5},
    "KPIECE1": {"color": OKABE_ITO["orange"], "marker": "v", "lw": 1.5},
    "STRIDE": {"color": OKABE_ITO["purple"], "marker": "P", "lw": 1.5},
}


def line_style(planner: str) -> dict[str, Any]:
    s = STYLE[planner]
    ours = planner in OURS
    return {"color": s["color"], "marker": s["marker"], "lw": s["lw"], "ls": "-" if ours else (0, (4, 2)),
            "mfc": s["color"] if ours else "white", "mec": s["color"], "mew": 1.3, "ms": 5.5,
            "label": LABELS[planner], "gid": planner}


def log_seconds_axis(ax: Any, lo: float, hi: float, axis: str = "x", mark: float = 0.0) -> None:
    """A log axis from lo to hi s with plain tick labels (0.001, 0.01, 0.1, 1; not 10^k).

    Up to two decades every 1-2-5 step is labelled; over a longer range the
    decades (and `mark`, e.g. the budget T) carry the labels and the 2 and 5
    steps are unlabelled ticks.
    """
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter

    steps = [m * 10.0 ** e for e in range(-6, 4) for m in (1, 2, 5) if lo * 0.999 <= m * 10.0 ** e <= hi * 1.001]
    if hi / lo <= 150:
        major, minor = steps, []
    else:
        major = [t for t in steps if abs(np.log10(t) - round(np.log10(t))) < 1e-9]
        if mark and mark not in major:
            major.append(mark)
        minor = [t for t in steps if t not in major]
    a = ax.xaxis if axis == "x" else ax.yaxis
    (ax.set_xscale if axis == "x" else ax.set_yscale)("log")
    (ax.set_xlim if axis == "x" else ax.set_ylim)(lo, hi)
    a.set_major_locator(FixedLocator(major))
    a.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    a.set_minor_locator(FixedLocator(minor))
    a.set_minor_formatter(NullFormatter())
    ax.tick_params(axis=axis, labelsize=8)
    ax.grid(True, axis=axis, which="major", lw=0.4, color="0.85")
    ax.grid(True, axis=axis, which="minor", lw=0.25, color="0.92")


def _floor(result: dict[str, Any]) -> float:
    """The left end of the time axes: the decade below the fastest successful run (at most 10 ms)."""
    ts = [r["time_s"] for sc in result["scenes"].values() for d in sc["planners"].values() for r in d["runs"]
          if r["success"] and r["time_s"] > 0]
    fastest = min(ts) if ts else 0.01
    return float(10.0 ** np.floor(np.log10(min(fastest, 0.01))))


def _order(result: dict[str, Any]) -> list[str]:
    present = {pl for sc in result["scenes"].values() for pl in sc["planners"]}
    return [pl for pl in PLANNERS if pl in present]


def _legend(fig: Any, planners: Sequence[str], note: str = "") -> None:
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], **line_style(pl)) for pl in planners]
    fig.legend(handles=handles, loc="outside lower center", ncol=len(planners), fontsize=8, frameon=False,
               title=note or None, title_fontsize=8)


def success_figure(result: dict[str, Any]) -> Any:
    """Success (%) against the time budget t, one panel per scene (module doc); returns the unsaved figure."""
    plt = pyplot()
    scenes = list(result["scenes"])
    T = float(result["size"]["time_limit"])
    lo = _floor(result)
    planners = _order(result)
    cols = 2 if len(scenes) > 2 else len(scenes)
    rows = -(-len(scenes) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols + 0.4, 3.3 * rows + 0.9), layout="constrained",
                             squeeze=False, sharey=True)
    for ax in axes.flat[len(scenes):]:
        ax.set_visible(False)
    grid = np.logspace(np.log10(lo), np.log10(T), 400)
    for ax, name in zip(axes.flat, scenes):
        sc = result["scenes"][name]
        for k, pl in enumerate(planners):
            if pl not in sc["planners"]:
                continue
            tts = time_to_success(sc["planners"][pl]["runs"])
            y = 100.0 * np.mean(tts[None, :] <= grid[:, None], axis=1)
            marks = [int(np.searchsorted(grid, m * 10 ** (0.045 * (k - 2.5)))) for m in
                     np.logspace(np.log10(lo), np.log10(T), 7)[1:-1]]
            style = line_style(pl)
            ax.plot(grid, y, drawstyle="steps-post", markevery=[m for m in marks if 0 <= m < grid.size],
                    zorder=3 if pl in OURS else 4, **style)
        log_seconds_axis(ax, lo, T, mark=T)
        ax.set_ylim(-3, 103)
        ax.set_xlabel("time budget per query t (s)")
        ax.set_title(f"{name} ({sc['links']} links, {len(next(iter(sc['planners'].values()))['runs'])} runs)",
                     fontsize=9)
    for r in range(rows):
        axes[r][0].set_ylabel("queries solved within t (%)")
    _legend(fig, planners, "ours solid, OMPL dashed; the same runs read at every budget (budget = T "
                           f"{T:g} s per run)")
    return fig


def time_figure(result: dict[str, Any]) -> Any:
    """Box plots of the successful runs' time, per scene (groups) and planner (boxes); log y axis."""
    plt = pyplot()
    scenes = list(result["scenes"])
    planners = _order(result)
    T = float(result["size"]["time_limit"])
    lo = _floor(result)
    fig, ax = plt.subplots(figsize=(1.0 + 0.42 * len(planners) * len(scenes) + 0.5 * len(scenes), 4.3),
                           layout="constrained")
    width, gap = 0.8, 1.0
    centres = []
    for g, name in enumerate(scenes):
        sc = result["scenes"][name]
        x0 = g * (len(planners) + gap)
        centres.append(x0 + (len(planners) - 1) / 2)
        for k, pl in enumerate(planners):
            if pl not in sc["planners"]:
                continue
            runs = sc["planners"][pl]["runs"]
            ts = np.array([r["time_s"] for r in runs if r["success"]])
            x = x0 + k
            s = STYLE[pl]
            if ts.size:
                ax.boxplot([ts], positions=[x], widths=width * 0.8, whis=(5, 95), patch_artist=True,
                           showfliers=True, manage_ticks=False,
                           boxprops={"facecolor": s["color"] + "55", "edgecolor": s["color"], "linewidth": 1.3,
                                     "linestyle": "-" if pl in OURS else "--"},
                           medianprops={"color": "black", "linewidth": 1.6},
                           whiskerprops={"color": s["color"], "linewidth": 1.1},
                           capprops={"color": s["color"], "linewidth": 1.1},
                           flierprops={"marker": s["marker"], "ms": 3, "mec": s["color"], "mfc": "none"})
            ax.text(x, lo * 1.15, f"{ts.size}", ha="center", va="bottom", fontsize=7, color="0.2")
    log_seconds_axis(ax, lo, T * 1.6, axis="y", mark=T)
    ax.axhline(TARGET_MEDIAN_S, color="0.35", lw=0.8, ls=":", zorder=0)
    ax.text(-0.6, TARGET_MEDIAN_S * 1.05, f"target median {TARGET_MEDIAN_S:g} s", ha="left", va="bottom",
            fontsize=7, color="0.35")
    ax.axhline(T, color="0.35", lw=0.8, ls="--", zorder=0)
    ax.text(centres[-1] + len(planners) / 2, T * 1.05, f"budget T = {T:g} s", ha="right", va="bottom",
            fontsize=7, color="0.35")
    ax.set_xticks(centres, [f"{n} ({result['scenes'][n]['links']} links)" for n in scenes], fontsize=9)
    ax.set_xlim(-0.8, (len(scenes) - 1) * (len(planners) + gap) + len(planners) - 0.2)
    ax.set_ylabel("time per successful plan (s)")
    ax.set_title("boxes: quartiles, whiskers 5th-95th percentile, black line the median; "
                 "numbers: successful runs", fontsize=8)
    _legend(fig, planners)
    return fig


def clearance_excess(result: dict[str, Any]) -> Optional[dict[str, list[float]]]:
    """Per planner, how far each successful path's least clearance lies above the margin its scene was
    planned for (mm); None when the scenes carry no margins (a result from before they did)."""
    excess: dict[str, list[float]] = {pl: [] for pl in _order(result)}
    for sc in result["scenes"].values():
        if "margin_m" not in sc:
            return None
        for pl, d in sc["planners"].items():
            excess[pl] += [1000.0 * (r["clearance_min_m"] - sc["margin_m"]) for r in d["runs"]
                           if r["success"] and r.get("clearance_min_m") is not None]
    return excess


def clearance_figure(result: dict[str, Any]) -> Any:
    """Histogram of clearance_excess (log bins; every scene's runs together, one step line per planner);
    None without margins or paths."""
    plt = pyplot()
    planners = _order(result)
    excess = clearance_excess(result)
    if excess is None:
        return None
    values = [v for vs in excess.values() for v in vs]
    if not values:
        return None
    lo = max(min(max(v, 1e-4) for v in values), 1e-4)
    hi = max(max(values), lo * 10)
    bins = np.logspace(np.log10(lo) - 0.05, np.log10(hi) + 0.05, 40)
    fig, ax = plt.subplots(figsize=(7.2, 3.8), layout="constrained")
    for pl in planners:
        if excess[pl]:
            s = line_style(pl)
            ax.hist(np.maximum(excess[pl], lo), bins=bins, histtype="step", color=s["color"], lw=s["lw"],
                    ls=s["ls"], label=f"{LABELS[pl]} ({len(excess[pl])} paths)")
    from matplotlib.ticker import FuncFormatter

    ax.set_xscale("log")
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.set_xlabel("least clearance of the path above its margin (mm; 0 would be on the margin)")
    ax.set_ylabel("successful paths")
    ax.set_title("every link's surface to every obstacle, over the whole path (sampled 0.2 mm apart)", fontsize=9)
    fig.legend(loc="outside lower center", ncol=2, fontsize=8, frameon=False)
    return fig


def by_group(result: dict[str, Any]) -> dict[str, Any]:
    """The result with each group of generated scenes as one scene (its scenes' runs together), so the
    figures keep a panel per fixed scene or file and get one per group, not one per generated scene."""
    groups = result.get("groups") or {}
    if not groups:
        return result
    generated = {n for g in groups.values() for n in g["scenes"]}
    scenes = {n: sc for n, sc in result["scenes"].items() if n not in generated}
    for spec, g in groups.items():
        members = [result["scenes"][n] for n in g["scenes"]]
        scenes[spec] = {"links": g["links"], "planners": {
            pl: {"runs": [r for sc in members for r in sc["planners"][pl]["runs"]]} for pl in g["planners"]}}
    return {**result, "scenes": scenes}


def plots(result: dict[str, Any], png_dir: Path) -> list[Path]:
    """Write wjrrt-success.png, wjrrt-time.png (a group of generated scenes: one panel) and, where the
    scenes carry their margins, wjrrt-clearance.png into png_dir."""
    raw, result = result, by_group(result)
    plt = pyplot()
    png_dir.mkdir(parents=True, exist_ok=True)
    out = []
    for name, make in (("wjrrt-success.png", lambda: success_figure(result)),
                       ("wjrrt-time.png", lambda: time_figure(result)),
                       ("wjrrt-clearance.png", lambda: clearance_figure(raw))):
        fig = make()
        if fig is None:
            continue
        p = png_dir / name
        fig.savefig(p, dpi=130)
        plt.close(fig)
        out.append(p)
    return out


def wjrrt_cmd(
    seeds: int = typer.Option(None, "--seeds", min=1, help="Seeds per scene and planner (full run: 100)."),
    scenes: str = typer.Option("two-arm,three-arm,seven-tube,horn", "--scenes",
                               help="Comma-separated: fixed scenes (two-arm, three-arm, seven-tube, horn), scene "
                                    "files (armbridge-chain-env JSON) and generated scenes random:LINKS:KIND:SEEDS "
                                    "(LINKS 2, 3 or 7; KIND corridor, passage or clutter; SEEDS N or A-B, e.g. "
                                    "random:3:corridor:0-9)."),
    save_scenes: Optional[Path] = typer.Option(None, "--save-scenes",
                                               help="Also write every generated scene as a scene file into this "
                                                    "folder (NAME.json; --scenes takes them back)."),
    planners: str = typer.Option("wjrrt,jt-rrt,birrt,wjrrt-connect,RRTConnect,KPIECE1,STRIDE", "--planners",
                                 help="Comma-separated: ours (wjrrt, jt-rrt, birrt, wjrrt-connect) and OMPL's "
                                      "(RRTConnect, KPIECE1, STRIDE)."),
    time_limit: float = typer.Option(None, "--time-limit", min=0.001,
                                     help="Wall-clock budget T per run, every planner (s; full run: 2)."),
    iterations: int = typer.Option(None, "--iterations", min=1,
                                   help="Our planners' iteration budget [default: each scene's, Table 1's Iter.]."),
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 2 seeds, T = 0.5 s."),
    json_out: Path = typer.Option(Path("runs/bench-wjrrt.json"), "--json", help="Where to write the results ('-': stdout)."),
    png: Path = typer.Option(None, "--png", help="Also write the figures (wjrrt-success.png, wjrrt-time.png) "
                                                 "into this folder."),
    ray: Optional[str] = shard_options.ray_option(),
    workers: int = shard_options.workers_option(),
    checkpoint: Optional[Path] = shard_options.checkpoint_option("none: shards are not kept"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show the shards' progress bar."),
) -> None:
    """Table 1 of the WJRRT paper (success, iterations, time, nodes, track / goal / random nodes,
    obstacle checks, H) for WJRRT, JT-RRT, Bi-RRT, WJRRT-Connect and OMPL's RRTConnect, KPIECE1,
    STRIDE on the same scenes and checker, every run with the same time budget; success against the
    budget, and WJRRT-Connect against RRTConnect at every budget from 0.05 s (issue 24 section 3).

    Scenes: fixed ones, scene files and generated ones (random:3:corridor:0-9: ten scenes, summarised
    together as well). Every planner runs once on a tiny scene first, so numba's compilation falls on
    no run's budget.

    One shard per scene and seed, every planner on it in turn (--ray, --workers; docs/cluster.md):
    our planners' runs are the serial run's but their times, where no run ran out of the budget;
    OMPL's are time-bound and not reproducible; times are measured where each shard ran."""
    from dataclasses import replace

    from rich.console import Console

    size = QUICK if quick else FULL
    if seeds is not None:
        size = replace(size, seeds=seeds)
    if time_limit is not None:
        size = replace(size, time_limit=time_limit)
    console = Console()
    items = tuple(s.strip() for s in scenes.split(",") if s.strip())
    if save_scenes is not None:
        from armbridge.bench.wjrrt import resolve_scenes
        from armbridge.planning.soft.scene import save_scene

        loaded, groups = resolve_scenes(items)
        for sc in loaded:
            if any(sc.name in g for g in groups.values()):
                console.print(f"[dim]bench wjrrt: wrote {save_scene(sc, save_scenes / f'{sc.name}.json')}[/]")
    with shard_options.runner(ray, workers, checkpoint, progress) as runner:
        result = run(size, items,
                     tuple(p.strip() for p in planners.split(",") if p.strip()), iterations=iterations,
                     progress=lambda text: console.print(f"[dim]bench wjrrt: {text}[/]"), runner=runner)
    write_json(result, json_out)
    print_result(result, console)
    if png is not None:
        for p in plots(result, png):
            console.print(f"wrote {p}")
    console.print(f"wrote {json_out}")
