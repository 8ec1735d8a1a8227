"""`armbridge bench smm-data`: how the 7R's branch-count mismatch falls with the locations traced,
and what choosing them buys (issue 27, section 2).

Why: the 7R's gap to the paper is the data (docs/smm.md, "The 7R: one
region"), so the question a lent GPU run has to answer first is how many
locations a target takes. This bench measures it on the one region:

1. Uniform: `max(sizes) + test` locations uniform over the region's
   positions and tool directions (grid.region_locations), their branch counts
   traced by the data sets' own sharded tracer (smm.trace.trace_smms,
   sing_tol 0.005, the 7R build's settings; counts only, 16 points a branch).
   The first `test` are held out.
2. For every size n: the paper's 7R classifier (4 x 150, AdamW 1e-3; the
   pipeline's own training loop, train.smm_fit.fit_classifier) trained on
   the first n to predict the branch count, and its mismatch on the held-out
   locations. At the largest size it is trained a second time on the raw
   azimuth (no (cos, sin), networks._Scaled) to measure that choice.
3. Margin sampling (`--active n`, n one of the sizes): from `candidates` x n
   untraced uniform locations, the n where the size-n classifier is least
   sure (smm.margin.pick) are traced and added; trained on those 2n, it
   is compared with the uniform 2n (when 2n is one of the sizes).
4. A power law mismatch = a n^-b fitted to the uniform sizes (log-log least
   squares) and the n it gives for the paper's 6.02 %: an extrapolation, so
   it is reported with the sizes it comes from.

The classifier here predicts the branch count itself, where the pipeline's
predicts a cluster (whose branch count is then read off): the same network
and loop on the same inputs, without the clustering of the data set, so the
curve measures the data alone.
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import typer

from armbridge.bench.command import write_json

PAPER_MISMATCH_PCT = 6.02  # Table III, 7R
SING_TOL = 0.005  # the 7R build's (docs/smm.md)


def _mismatch(clf: Any, canon: np.ndarray, count: np.ndarray) -> float:
    import torch

    with torch.no_grad():
        pred = clf(torch.as_tensor(canon, dtype=torch.float32)).argmax(dim=1).numpy()
    return float(np.mean(pred != count) * 100)


def power_law(sizes: Sequence[int], mismatch: Sequence[float]) -> dict[str, Any] | None:
    """mismatch = a n^-b by least squares in log-log; None under two sizes or with a zero mismatch."""
    n, m = np.asarray(sizes, dtype=float), np.asarray(mismatch, dtype=float)
    if n.size < 2 or (m <= 0).any() or np.unique(n).size < 2:
        return None
    slope, intercept = np.polyfit(np.log(n), np.log(m), 1)
    b = -float(slope)
    out: dict[str, Any] = {"a": float(math.exp(intercept)), "b": b, "sizes": [int(v) for v in n]}
    out["locations_for_paper_pct"] = float((math.exp(intercept) / PAPER_MISMATCH_PCT) ** (1 / b)) if b > 0 else None
    return out


def run(sizes: Sequence[int] = (5500, 11000, 22000), test: int = 2000, active: int | None = 11000,
        candidates: int = 20, epochs: int = 600, workers: int = 1, pool: str = "process", seed: int = 0,
        progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    from armbridge.errors import ArmbridgeError
    from armbridge.shards import Runner
    from armbridge.smm.arms import get_smm_arm
    from armbridge.smm.grid import PERIODIC, region_grid, region_locations
    from armbridge.smm.networks import default_architecture
    from armbridge.smm.margin import pick
    from armbridge.smm.trace import trace_smms
    from armbridge.train.smm_fit import SmmTrainConfig, fit_classifier

    sizes = sorted({int(s) for s in sizes})
    if not sizes or sizes[0] < 1 or test < 1:
        raise ArmbridgeError(f"--sizes and --test must be counts >= 1, got {sizes} and {test}")
    if active is not None and active not in sizes:
        raise ArmbridgeError(f"--active must be one of --sizes ({', '.join(map(str, sizes))}), got {active}")
    if candidates < 1 or epochs < 1:
        raise ArmbridgeError(f"--candidates and --epochs must be >= 1, got {candidates} and {epochs}")
    arm = get_smm_arm("spatial7r")
    grid = region_grid(arm)
    periodic = PERIODIC[4]
    cfg = SmmTrainConfig(cls_hidden=default_architecture(arm.n).classifier, reg_hidden=(1,), epochs=epochs,
                         min_steps=0, seed=seed)
    timings: dict[str, float] = {}

    with Runner(workers=workers, pool=pool) as runner:
        def counts(canon: np.ndarray, job: str) -> np.ndarray:
            t = time.perf_counter()
            s = trace_smms(arm, np.asarray(arm.uncanonical(canon)), 16, 512, runner=runner, job=job,
                           sing_tol=SING_TOL, seed=seed)
            timings[job] = timings.get(job, 0.0) + time.perf_counter() - t
            return s.count

        progress(f"tracing {sizes[-1] + test} uniform locations of the 7R region on {workers} worker(s)")
        canon = region_locations(grid, sizes[-1] + test, seed=seed)
        count = counts(canon, "smm-data-uniform")
        classes = int(count.max()) + 2  # room for one more count than seen (margin-sampled locations)
        held_c, held_n = canon[:test], count[:test]
        pool_c, pool_n = canon[test:], count[test:]

        def fit(c: np.ndarray, n: np.ndarray, wraps: tuple[bool, ...] | None, label: str) -> Any:
            progress(f"training the 4 x 150 classifier on {label}")
            t = time.perf_counter()
            clf = fit_classifier(c, np.minimum(n, classes - 1), classes, cfg, wraps)
            timings[f"train {label}"] = time.perf_counter() - t
            return clf

        rows: list[dict[str, Any]] = []
        models: dict[int, Any] = {}

        def row(sampling: str, n: int, azimuth: str, clf: Any, c: np.ndarray, m: np.ndarray) -> dict[str, Any]:
            rows.append({"sampling": sampling, "locations": n, "azimuth": azimuth,
                         "train_mismatch_pct": _mismatch(clf, c, m),
                         "held_out_mismatch_pct": _mismatch(clf, held_c, held_n)})
            return rows[-1]

        for n in sizes:
            models[n] = fit(pool_c[:n], pool_n[:n], periodic, f"{n} uniform")
            row("uniform", n, "cos, sin", models[n], pool_c[:n], pool_n[:n])
        n = sizes[-1]
        raw = fit(pool_c[:n], pool_n[:n], None, f"{n} uniform, raw azimuth")
        row("uniform", n, "raw", raw, pool_c[:n], pool_n[:n])
        if active is not None:
            import torch

            progress(f"margin sampling: {active} of {candidates * active} candidates")

            def logits(c: np.ndarray) -> np.ndarray:
                with torch.no_grad():
                    return models[active](torch.as_tensor(c, dtype=torch.float32)).numpy()

            picked = pick(grid, logits, active, candidates, seed + 1)
            picked_n = counts(picked, "smm-data-margin")
            c = np.concatenate([pool_c[:active], picked])
            m = np.concatenate([pool_n[:active], picked_n])
            clf = fit(c, m, periodic, f"{active} uniform + {active} margin-sampled")
            row(f"uniform {active} + margin {active}", 2 * active, "cos, sin", clf, c, m)["picked_count_histogram"] = {
                str(int(b)): int(np.sum(picked_n == b)) for b in np.unique(picked_n)}
    uniform = [r for r in rows if r["sampling"] == "uniform" and r["azimuth"] != "raw"]
    return {"benchmark": "smm-data (7R branch-count mismatch against locations traced)", "robot": arm.name,
            "region": {"lo": list(grid.lo), "hi": list(grid.hi)}, "held_out_locations": test,
            "classifier": list(cfg.cls_hidden), "epochs": epochs, "seed": seed, "workers": workers, "pool": pool,
            "cores": os.cpu_count(), "sing_tol": SING_TOL, "held_out_count_histogram":
            {str(int(b)): int(np.sum(held_n == b)) for b in np.unique(held_n)},
            "rows": rows, "power_law_uniform": power_law([r["locations"] for r in uniform],
                                                         [r["held_out_mismatch_pct"] for r in uniform]),
            "paper_mismatch_pct": PAPER_MISMATCH_PCT, "seconds": timings}


def smm_data_cmd(
    sizes: str = typer.Option("5500,11000,22000", "--sizes", help="Uniform training sizes (locations), comma-separated."),
    test: int = typer.Option(2000, "--test", min=1, help="Held-out uniform locations."),
    active: int = typer.Option(11000, "--active", min=0, help="Margin-sample this many more onto the uniform set of this "
                                                                "size (one of --sizes; 0: no margin sampling)."),
    candidates: int = typer.Option(20, "--candidates", min=1, help="Candidates per margin-sampled location."),
    epochs: int = typer.Option(600, "--epochs", min=1, help="Passes over each training set."),
    workers: int = typer.Option(1, "--workers", min=1, help="Tracer workers (processes, or a local Ray with --pool ray)."),
    pool: str = typer.Option("process", "--pool", help="Local workers: process or ray."),
    seed: int = typer.Option(0, "--seed", help="Locations, IK starts and training."),
    json_out: Path = typer.Option(Path("runs/bench-smm-data.json"), "--json", help="Where to write the results ('-': stdout)."),
) -> None:
    """The 7R's held-out branch-count mismatch against the number of traced locations (uniform,
    and with margin sampling), and the power law's locations for the paper's 6.02 %."""
    from rich.console import Console

    from armbridge.errors import ArmbridgeError

    try:
        size_list = [int(s) for s in sizes.split(",") if s.strip()]
    except ValueError:
        raise ArmbridgeError(f"--sizes must be counts like 5500,11000, got {sizes!r}") from None
    console = Console()
    result = run(size_list, test, active or None, candidates, epochs, workers, pool, seed,
                 progress=lambda text: console.print(f"[dim]bench smm-data: {text}[/]"))
    write_json(result, json_out)
    for r in result["rows"]:
        console.print(f"{r['sampling']:>24} {r['locations']:>7} locations, azimuth {r['azimuth']:>8}: "
                      f"held-out mismatch {r['held_out_mismatch_pct']:.1f} % (train {r['train_mismatch_pct']:.1f} %)")
    law = result["power_law_uniform"]
    if law:
        need = law["locations_for_paper_pct"]
        console.print(f"uniform: mismatch ~ {law['a']:.3g} n^-{law['b']:.2f}; the paper's {PAPER_MISMATCH_PCT} % at "
                      + (f"about {need:.3g} locations (extrapolated)" if need else "no size (the fit does not fall)"))
    console.print(f"wrote {json_out}")
