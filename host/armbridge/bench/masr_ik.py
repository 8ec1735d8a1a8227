"""`armbridge bench masr-ik`: Table I of the masr paper (section V-B).

Protocol: `trials` random trials (armbridge.ik.masr_ik.random_trials): q0
uniform in C_f and a reachable goal pose x_goal = f(q) of an independent
uniform q. A trial succeeds when the answer passes the goal check
(MasrArm.reaches): its d at least the arm's d_margin (5 mm: the MA's
localisation bound) from every joint, and the MA pose within e_p = 8 mm and
e_phi = 4 deg of the goal (eq. 9) for every d within that margin. Every
solver's answers hold the margin (the NR baseline's too). Rows:

* IK-NN (11): the network trained with the joint regulariser eq. (11);
* IK-NN (12): the shipped network, action-time regulariser eq. (12);
* IK-NN (12) + refinement: then a few DLS steps (MasrIK.solve(refine=True,
  use_fallback=False));
* IK-NN (12) + refinement + fallback: the queries that still miss go to the
  multi-start fallback (masr_ik.fallback); the row reports how many did, how
  many it solved, and the time it adds (batched, against the row above);
* int8 IK-NN (12): the weight-only int8 ONNX of the same card;
* NR m = 10^3: the numeric baseline (armbridge.ik.masr_nr.MasrNR), on the
  first `nr_trials` trials (it is ~10^4 times slower); the IK-NN rows are
  also evaluated on that same subset so the action times compare like for like.

Timing: "single" is one query per call (x_goal (3,), q_c (n+1,)), the median
over `single_queries` calls; "batched" is every trial in one call, best of
`batch_repeats`, in queries/s. onnxruntime runs on one thread.
"""
from __future__ import annotations

import platform
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import typer

from armbridge import resources
from armbridge.bench.command import write_json

MODELS = resources.models_dir()
CARD_12 = MODELS / "masr5-iknn-card.json"
CARD_11 = MODELS / "masr5-iknn-reg11-card.json"


@dataclass(frozen=True)
class MasrIKBenchSize:
    trials: int  # Table I trials for the IK-NN rows
    nr_trials: int  # of them, how many the NR baseline solves
    nr_restarts: int  # m
    single_queries: int  # single-query timing calls per row
    batch_repeats: int


FULL = MasrIKBenchSize(trials=5000, nr_trials=5000, nr_restarts=1000, single_queries=1000, batch_repeats=3)
QUICK = MasrIKBenchSize(trials=40, nr_trials=4, nr_restarts=50, single_queries=20, batch_repeats=1)


def _time_single(fn: Callable[[np.ndarray, np.ndarray], Any], xg: np.ndarray, q0: np.ndarray, count: int) -> dict:
    fn(xg[0], q0[0])  # warm-up (session creation)
    ts = []
    for i in range(min(count, xg.shape[0])):
        t0 = time.perf_counter()
        fn(xg[i], q0[i])
        ts.append(time.perf_counter() - t0)
    a = np.array(ts) * 1e3
    return {"n": int(a.size), "median_ms": float(np.median(a)), "mean_ms": float(a.mean()),
            "p95_ms": float(np.percentile(a, 95))}


def _time_batch(fn: Callable[[np.ndarray, np.ndarray], np.ndarray], xg: np.ndarray, q0: np.ndarray,
                repeats: int) -> tuple[np.ndarray, float]:
    fn(xg, q0)  # warm-up: session creation and first-touch of the batch-sized arrays
    best = np.inf
    q = None
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        q = fn(xg, q0)
        best = min(best, time.perf_counter() - t0)
    assert q is not None
    return q, xg.shape[0] / best


def run(size: MasrIKBenchSize, card12: Path = CARD_12, card11: Path | None = CARD_11, seed: int = 2024,
        nr_backend: str = "auto", progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    from armbridge.ik.masr_ik import E_P, E_PHI, MasrIK, evaluate, random_trials
    from armbridge.ik.masr_nr import MasrNR

    ik12 = MasrIK.load(card12)
    arm = ik12.arm
    xg, q0 = random_trials(arm, size.trials, seed)
    n_nr = min(size.nr_trials, size.trials)
    rows: list[dict[str, Any]] = []

    def add(label: str, model: str, fn_batch: Callable, fn_single: Callable, extra: dict | None = None) -> None:
        progress(f"{label}: {size.trials} trials")
        q, qps = _time_batch(fn_batch, xg, q0, size.batch_repeats)
        row = {"row": label, "model": model, **evaluate(arm, xg, q0, q),
               "single": _time_single(fn_single, xg, q0, size.single_queries), "batched_queries_per_s": qps}
        if n_nr:
            sub = evaluate(arm, xg[:n_nr], q0[:n_nr], q[:n_nr])
            row["on_nr_subset"] = {k: sub[k] for k in ("trials", "mean_dp_mm", "success_rate", "mean_action_time_s")}
        row.update(extra or {})
        rows.append(row)

    if card11 is not None and Path(card11).is_file():
        ik11 = MasrIK.load(card11)
        add("IK-NN (11)", Path(card11).name, ik11.solve, ik11.solve)
    else:
        rows.append({"row": "IK-NN (11)", "missing": f"no model card at {card11}"})
    add("IK-NN (12)", card12.name, ik12.solve, ik12.solve)

    def refined(x: np.ndarray, q: np.ndarray) -> np.ndarray:
        return ik12.solve(x, q, refine=True, use_fallback=False)

    def with_fallback(x: np.ndarray, q: np.ndarray) -> np.ndarray:
        return ik12.solve(x, q, refine=True)

    add("IK-NN (12) + refinement", card12.name, refined, refined)
    ik12.fallbacks = ik12.fallbacks_solved = 0
    ik12.solve(xg, q0, refine=True)
    used, solved = ik12.fallbacks, ik12.fallbacks_solved
    add("IK-NN (12) + refinement + fallback", card12.name, with_fallback, with_fallback)
    plain, fb = rows[-2], rows[-1]
    fb["fallback"] = {"queries": used, "share_pct": used / size.trials * 100, "solved": solved,
                      "added_ms_per_query_batched": (1 / fb["batched_queries_per_s"] - 1 / plain["batched_queries_per_s"])
                      * 1e3,
                      "added_ms_per_fallback_query": ((size.trials / fb["batched_queries_per_s"]
                                                       - size.trials / plain["batched_queries_per_s"]) / max(used, 1)
                                                      * 1e3)}
    ik8 = MasrIK.load(card12, int8=True)
    add("int8 IK-NN (12)", ik8.onnx_path.name, ik8.solve, ik8.solve)

    nr_row: dict[str, Any]
    if n_nr:
        nr = MasrNR(arm, restarts=size.nr_restarts, seed=seed, backend=nr_backend)
        progress(f"NR m={size.nr_restarts} ({nr.method}): {n_nr} trials")
        t0 = time.perf_counter()
        qn = nr.solve(xg[:n_nr], q0[:n_nr])
        elapsed = time.perf_counter() - t0
        per_ms = elapsed / n_nr * 1e3
        nr_row = {"row": f"NR m={size.nr_restarts}", "model": nr.method, **nr.describe(),
                  **evaluate(arm, xg[:n_nr], q0[:n_nr], qn),
                  "single": {"n": n_nr, "median_ms": per_ms, "mean_ms": per_ms, "p95_ms": None},
                  "batched_queries_per_s": n_nr / elapsed}
        rows.append(nr_row)

    by = {r["row"]: r for r in rows}
    f12, r12, i12 = by["IK-NN (12)"], by["IK-NN (12) + refinement + fallback"], by["int8 IK-NN (12)"]
    targets = {
        "iknn12_success_ge_87": f12["success_rate"] >= 87.0,
        "iknn12_mean_dp_le_3.5mm": f12["mean_dp_mm"] <= 3.5,
        "refined_success_ge_99.5": r12["success_rate"] >= 99.5,
        "refined_single_lt_1ms": r12["single"]["median_ms"] < 1.0,
        "refined_batched_ge_50k_qps": r12["batched_queries_per_s"] >= 50_000,
        # the quantisation's effect on the network: eq. (9) at d, as the model card measures it
        "int8_within_1pt": abs(i12["success_at_d"] - f12["success_at_d"]) <= 1.0,
    }
    if n_nr:
        targets["refined_action_time_le_nr"] = (r12["on_nr_subset"]["mean_action_time_s"]
                                                <= rows[-1]["mean_action_time_s"])
    return {
        "benchmark": "masr-ik (Table I, section V-B)",
        "size": asdict(size), "seed": seed, "robot": arm.name, "e_p_m": E_P, "e_phi_deg": float(np.degrees(E_PHI)),
        "d_margin_m": arm.d_margin,
        "nr_trials": n_nr, "rows": rows, "targets": targets,
        "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
    }


def masr_ik_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 40 trials, NR on 4 of them with m = 50."),
    trials: int = typer.Option(None, "--trials", help="Table I trials (full run: 5000)."),
    nr_trials: int = typer.Option(None, "--nr-trials", help="How many of the trials the NR baseline solves (full: all)."),
    nr_restarts: int = typer.Option(None, "--nr-restarts", help="NR restarts m (full run: 1000)."),
    card12: Path = typer.Option(None, "--card", help="IK-NN (12) model card [default: models/onnx/masr5-iknn-card.json]."),
    card11: Path = typer.Option(None, "--card11", help="IK-NN (11) model card [default: models/onnx/masr5-iknn-reg11-card.json]."),
    seed: int = typer.Option(2024, "--seed", help="Seed of the random trials."),
    json_out: Path = typer.Option(Path("runs/bench-masr-ik.json"), "--json", help="Where to write the results ('-': stdout)."),
) -> None:
    """Table I of the masr paper (section V-B): IK-NN (11), IK-NN (12), + refinement, + fallback,
    int8, and the numeric NR baseline; accuracy, action time and time per query. Success is the
    goal check over the robot's joint margin d_margin (every answer holds it)."""
    from dataclasses import replace

    from rich.console import Console
    from rich.table import Table

    size = QUICK if quick else FULL
    for name, v in (("trials", trials), ("nr_trials", nr_trials), ("nr_restarts", nr_restarts)):
        if v is not None:
            size = replace(size, **{name: v})
    console = Console()
    result = run(size, card12=card12 or CARD_12, card11=card11 or CARD_11,
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
