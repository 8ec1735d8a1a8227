"""`armbridge bench shards`: how a fixed SMM data job scales with Ray workers, and what the
paper's 7R grid would take on N workers.

The job: nullspace SMMs (smm.trace.trace_smms, the data sets' sharded
tracer) of `locations` 7R locations (another robot: tips of random
configurations, the CI size) uniform over the region grid's positions
and tool directions (smm.dataset.region_locations, seed 0), `shard`
locations a shard, sing_tol 0.005 as `train smm-7r` is run (docs/smm.md).
For each worker count: the wall time of the job (from the first shard sent
to the last result; the workers' start-up, a local Ray's or the process
pool's, is not the job's: Runner.start before the clock), the sum of the
shards' nullspace seconds, the speed-up over one worker and the efficiency
T_1 / (w T_w), the parallel efficiency of the issue 27 target (0.8 on every
core) when w is the machine's core count. Workers are a local Ray
(--pool ray) or spawned processes (--pool process), each shard on one torch
thread. The 1-minute load average before and after each run stands beside
it: on a shared machine other work takes cores, and an efficiency measured
beside it says as much about the neighbours as about the tracer. Every run
must give the same SMMs (checked, reported as identical).

Projection: the paper grids 80 x 160 positions times 12,000 tool
orientations of its 7R (1.536e8 SMMs, section VI-A). From the one-worker
run's nullspace seconds per location c, N workers at the measured two-worker
efficiency e take 1.536e8 c / (N e).
"""
from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import typer

from armbridge.bench.command import write_json

PAPER_7R_SMMS = 80 * 160 * 12_000
PROJECT_WORKERS = (1, 2, 16, 64, 256, 1024)


def job_locations(robot: str, count: int) -> tuple[Any, np.ndarray]:
    """The job's locations: over the region grid for the 7R (as its data set), else tips of random
    configurations (smaller arms: the CI size of this bench)."""
    from armbridge.smm.arms import get_smm_arm
    from armbridge.smm.grid import random_locations, region_grid, region_locations

    arm = get_smm_arm(robot)
    if arm.tool_roll:
        return arm, np.asarray(arm.uncanonical(region_locations(region_grid(arm), count, seed=0)))
    return arm, random_locations(arm, count, seed=0)


def run(locations: int = 1024, shard: int = 256, workers: Sequence[int] = (1, 2), robot: str = "spatial7r",
        progress: Callable[[str], None] = lambda s: None, pool: str = "ray") -> dict[str, Any]:
    from armbridge.shards import Runner
    from armbridge.smm.trace import trace_smms

    arm, x = job_locations(robot, locations)
    rows: list[dict[str, Any]] = []
    first = None
    for w in workers:
        progress(f"{w} worker{'s' if w > 1 else ''}: {locations} locations in shards of {shard}")
        with Runner(workers=w, pool=pool) as runner:
            runner.start()  # the workers' start-up is not the job's
            if runner.backend == "serial":  # nor torch's import and first calls in this process
                trace_smms(arm, x[:1], 128, shard, runner=runner, job="bench-shards-warm-up", sing_tol=0.005)
            took: list[float] = []
            load_before = os.getloadavg()[0]
            t0 = time.perf_counter()
            smms = trace_smms(arm, x, 128, shard, runner=runner, job="bench-shards", seconds=took, sing_tol=0.005)
            wall = time.perf_counter() - t0
        same = True
        if first is None:
            first = smms
        else:
            same = bool(np.array_equal(smms.points, first.points, equal_nan=True)
                        and np.array_equal(smms.count, first.count) and np.array_equal(smms.singular, first.singular))
        rows.append({"workers": w, "backend": runner.backend, "wall_s": wall,
                     "load_average_1min_before": load_before, "load_average_1min": os.getloadavg()[0], "shard_seconds_sum": sum(took),
                     "shard_seconds": took, "identical_to_first": same})
    t1 = rows[0]["wall_s"] if rows[0]["workers"] == 1 else None
    for r in rows:
        r["speedup"] = t1 / r["wall_s"] if t1 else None
        r["efficiency"] = t1 / (r["workers"] * r["wall_s"]) if t1 else None
    per_location = rows[0]["shard_seconds_sum"] / locations
    eff = next((r["efficiency"] for r in rows if r["workers"] == 2 and r["efficiency"]), 1.0)
    projection = {str(n): PAPER_7R_SMMS * per_location / (n * (eff if n > 1 else 1.0)) / 86400 for n in PROJECT_WORKERS
                  } if arm.name == "spatial7r" else None
    cores = os.cpu_count() or 1
    on_all = next((r for r in rows if r["workers"] == cores and r["efficiency"] is not None), None)
    return {"benchmark": "shards (SMM data job scaling)", "robot": arm.name, "locations": locations,
            "pool": pool, "parallel_efficiency_all_cores": on_all["efficiency"] if on_all else None,
            "locations_per_shard": shard, "shards": -(-locations // shard), "sing_tol": 0.005,
            "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
                        "cores": os.cpu_count()},
            "rows": rows, "seconds_per_location_1_worker": per_location,
            "projection_paper_7r_grid": {"smms": PAPER_7R_SMMS, "efficiency_assumed": eff, "days_on_n_workers": projection}
            if projection else None}


def shards_cmd(
    locations: int = typer.Option(1024, "--locations", min=1, help="Locations of the fixed SMM data job."),
    robot: str = typer.Option("spatial7r", "--robot", help="SMM arm of the job (the projection is the 7R's only)."),
    shard: int = typer.Option(256, "--shard", min=1, help="Locations per shard."),
    workers: str = typer.Option("1,all", "--workers", help="Worker counts to time, comma-separated (1: serial here; "
                                                           "N > 1: N local workers; all: the machine's cores)."),
    pool: str = typer.Option("ray", "--pool", help="Local workers: ray (a local Ray of N CPUs) or process "
                                                   "(N spawned processes, no Ray needed)."),
    json_out: Path = typer.Option(Path("runs/bench-shards.json"), "--json", help="Where to write the results ('-': stdout)."),
) -> None:
    """Scaling of a fixed SMM data job (7R nullspace SMMs in shards) with the worker count: wall
    time, speed-up, efficiency; and the projected time of the paper's 7R grid on N workers."""
    from rich.console import Console

    from armbridge.errors import ArmbridgeError

    try:
        counts = tuple((os.cpu_count() or 1) if w.strip() == "all" else int(w) for w in workers.split(",") if w.strip())
    except ValueError:
        raise ArmbridgeError(f"--workers must be counts like 1,2, got {workers!r}") from None
    if not counts or min(counts) < 1:
        raise ArmbridgeError(f"--workers must be counts >= 1 like 1,2, got {workers!r}")
    console = Console()
    if pool not in ("ray", "process"):
        raise ArmbridgeError(f"--pool must be ray or process, got {pool!r}")
    result = run(locations, shard, counts, robot,
                 progress=lambda text: console.print(f"[dim]bench shards: {text}[/]"), pool=pool)
    write_json(result, json_out)
    for r in result["rows"]:
        eff = "-" if r["efficiency"] is None else f"{r['efficiency']:.2f}"
        console.print(f"{r['workers']} worker(s): {r['wall_s']:.1f} s wall, shards' nullspace {r['shard_seconds_sum']:.1f} s, "
                      f"efficiency {eff}, load {r['load_average_1min_before']:.1f} -> {r['load_average_1min']:.1f}, "
                      f"identical {r['identical_to_first']}")
    if result["parallel_efficiency_all_cores"] is not None:
        console.print(f"parallel efficiency on all {result['machine']['cores']} cores (speed-up / cores): "
                      f"{result['parallel_efficiency_all_cores']:.2f}")
    projection = result["projection_paper_7r_grid"]
    if projection:
        days = projection["days_on_n_workers"]
        console.print("paper's 7R grid (1.536e8 SMMs): " + ", ".join(f"{n} workers {d:.3g} days" for n, d in days.items()))
    console.print(f"wrote {json_out}")
