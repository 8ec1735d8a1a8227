"""The 7R's learned SMMs in one run on a lent GPU: measure the tracer, build the data with adaptive
refinement, train, pack the model, and write it with its measurements under --out.

Made for the device tool of issue 27 (docs/smm.md, "The 7R on one lent GPU"): a bare machine with
Python 3.12, torch, numpy and scipy, no network, no pip install, at most 10 minutes a command and 8
files of 16 MiB back. So this script

- imports the package from the checkout it sits in (host/ on sys.path), and array_api_compat (which
  armbridge.robots imports) from wherever it is: installed, scipy's vendored copy, or a copy carried
  beside the checkout (`--carry`-ed .venv site-packages);
- needs only torch, numpy and scipy (checked by tests/test_smm7r_device.py, which runs --tiny with every
  other third-party import blocked);
- watches its own clock (--budget seconds, default 420): every phase has a share of it, data building
  stops adding refinement patches at 35 % and margin-sampled points (smm/margin.py) at 50 %, training
  sizes its steps to what is left;
- writes results.json after every phase (a run cut short still brings back what it measured), then the
  model packed by armbridge.smm.packed (int8 regressors, files <= 15 MiB, at most 6 of them).

Run: python3 scripts/smm7r_device.py --out "$OUT"   (CPU smoke test: --tiny --device cpu)
"""
from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import platform
import sys
import time
import traceback
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
MAX_MODEL_FILES = 6  # + results.json + model.json: 8 files at most come back
FILE_BYTES = 15 * 2**20  # a file comes back up to 16 MiB
MODEL_BYTES = 56 * 2**20  # and 64 MiB in all: the model's share


def _array_api_compat() -> str:
    """Make `import array_api_compat` work: installed, else scipy's vendored copy (the lent machine has
    scipy, not array_api_compat: docs/notes/toolchain), else a copy carried in the checkout's .venv."""
    try:
        importlib.import_module("array_api_compat")
        return "installed"
    except ImportError:
        pass
    for name in ("scipy._lib.array_api_compat", "scipy._lib.array_api_compat.array_api_compat"):  # new, old scipy
        try:
            vendored = importlib.import_module(name)
            subs = {sub: importlib.import_module(f"{name}.{sub}") for sub in ("common", "common._helpers", "numpy",
                                                                               "torch")}
        except ImportError:
            continue
        if not hasattr(vendored, "is_torch_array"):
            continue
        sys.modules["array_api_compat"] = vendored
        sys.modules.update({f"array_api_compat.{k}": v for k, v in subs.items()})
        return "scipy's vendored copy"
    for site in sorted(ROOT.glob(".venv/lib/python3*/site-packages")):
        if (site / "array_api_compat").is_dir():
            shim = Path(os.environ.get("TMPDIR", "/tmp")) / f"armbridge-aac-{os.getpid()}"
            shim.mkdir(exist_ok=True)
            link = shim / "array_api_compat"
            if not link.exists():
                link.symlink_to(site / "array_api_compat")
            sys.path.insert(0, str(shim))  # only this package: the venv's compiled ones are another Python's
            importlib.import_module("array_api_compat")
            return f"carried copy {site}"
    raise SystemExit("array_api_compat is missing: install it, or carry .venv/lib/python3.11/site-packages/"
                     "array_api_compat with the checkout")


def _settings(args: argparse.Namespace) -> dict[str, Any]:
    """Every size of the run; --tiny: a few seconds on a CPU (the CI smoke test)."""
    if args.tiny:
        return dict(grid=(1, 1, 2, 4), half=0.025, seeds=12, step=0.05, N=32, K=8, chunk=256, batch=256,
                    bench_locations=(2,), bench_check=1, refine=(1, 1, 1, 2), tile=2, min_cells=1,
                    cls_hidden=(16, 16), reg_hidden=(16, 16), epochs=20, min_steps=20, train_batch=32,
                    random_locations=6, eval_points=16, margin_candidates=3, margin_steps=20, margin_batch=32)
    return dict(grid=tuple(args.grid), half=0.1, seeds=64, step=0.02, N=128, K=args.K, chunk=args.chunk,
                batch=args.chunk, bench_locations=(256, 1024, 4096), bench_check=32, refine=(1, 1, 2, 2),
                tile=8, min_cells=4, cls_hidden=(150,) * 4, reg_hidden=(150,) * 6, epochs=200, min_steps=2000,
                train_batch=256, random_locations=2000, eval_points=64, margin_candidates=20, margin_steps=4000,
                margin_batch=1024)


class Run:
    """The clock, the results and where they go."""

    def __init__(self, out: Path, budget: float) -> None:
        self.out, self.budget, self.t0 = out, budget, time.monotonic()
        self.results: dict[str, Any] = {"phases": {}, "errors": []}
        out.mkdir(parents=True, exist_ok=True)

    def at(self, share: float) -> float:
        """time.monotonic() at this share of the budget."""
        return self.t0 + share * self.budget

    def elapsed(self) -> float:
        return time.monotonic() - self.t0

    def write(self) -> None:
        self.results["elapsed_s"] = round(self.elapsed(), 2)
        tmp = self.out / "results.json.tmp"
        tmp.write_text(json.dumps(self.results, indent=1, default=float) + "\n")
        tmp.replace(self.out / "results.json")

    def phase(self, name: str, fn: Any, *a: Any) -> Any:
        t = time.monotonic()
        print(f"[{self.elapsed():6.1f} s] {name}", flush=True)
        try:
            value = fn(*a)
        except Exception as e:  # noqa: BLE001 - recorded, the later phases still run where they can
            self.results["errors"].append({"phase": name, "error": f"{type(e).__name__}: {e}",
                                           "trace": traceback.format_exc(limit=6)})
            value = None
        self.results["phases"][name] = round(time.monotonic() - t, 2)
        self.write()
        return value


def bench_tracer(run: Run, s: dict[str, Any], arm: Any, grid: Any, dev: Any) -> dict[str, Any]:
    """Per-location tracer time by batch size: fused with CUDA graphs, fused eager, compacting (the
    baseline), and whether they agree (branch counts, singular flags, points)."""
    import numpy as np
    import torch

    from armbridge.smm import fused, nullspace
    from armbridge.smm.grid import region_locations

    opts = dict(seeds=s["seeds"], step=s["step"], sing_tol=0.005, n_points=s["N"], device=dev)
    cuda = dev.type == "cuda"
    out: dict[str, Any] = {"rows": []}

    def timed(x: Any, **kw: Any) -> tuple[Any, float, Any]:
        if cuda:
            torch.cuda.synchronize()
        t = time.perf_counter()
        tracer = kw.pop("tracer", None)
        smm = nullspace.compute(arm, x, chunk=len(x), engine=tracer or kw.pop("engine", "compact"), **opts, **kw)
        if cuda:
            torch.cuda.synchronize()
        return smm, time.perf_counter() - t, tracer

    stop = run.at(0.2)
    x_all = np.asarray(arm.uncanonical(region_locations(grid, max(s["bench_locations"]), seed=11)))
    small = x_all[: s["bench_locations"][0]]
    # equal on the device: fused (graphs where CUDA) against the compacting tracer, and against the CPU
    ref, t_ref, _ = timed(small)
    got, t_got, tr = timed(small, tracer=fused.Tracer(graphs=cuda))
    out["check_fused_vs_compact"] = _agree(ref, got)
    out["capture_error"] = tr.capture_error
    out["block_sync_free"], out["block_sync_error"] = tr.sync_free, tr.sync_error
    cpu_x = small[: s["bench_check"]]
    cpu = nullspace.compute(arm, cpu_x, chunk=len(cpu_x), **{**opts, "device": "cpu"})
    out["check_device_vs_cpu"] = _agree(cpu, _take(got, len(cpu_x)))
    out["rows"].append({"locations": len(small), "engine": "compact", "s_per_location": t_ref / len(small)})
    out["rows"].append({"locations": len(small), "engine": "fused" + ("+graphs" if cuda else ""), "s_per_location":
                        t_got / len(small), "graphs_captured": tr.captured, "blocks": tr.blocks,
                        "note": "includes graph capture" if cuda else ""})
    for n in s["bench_locations"]:
        for graphs in ((True, False) if cuda else (False,)):
            if time.monotonic() > stop:
                out["stopped_at_deadline"] = True
                return out
            smm, took, tr = timed(x_all[:n], tracer=fused.Tracer(graphs=graphs))
            out["rows"].append({"locations": n, "engine": "fused" + ("+graphs" if graphs else " eager"),
                                "s_per_location": took / n, "graphs_captured": tr.captured, "blocks": tr.blocks,
                                "peak_gib": torch.cuda.max_memory_allocated() / 2**30 if cuda else None})
            print(f"  {n} locations, {out['rows'][-1]['engine']}: {1e3 * took / n:.2f} ms each", flush=True)
    return out


def _take(smm: Any, n: int) -> Any:
    from armbridge.smm.manifold import SmmSet

    return SmmSet(smm.points[:n], smm.count[:n], smm.singular[:n])


def _agree(a: Any, b: Any) -> dict[str, Any]:
    import numpy as np

    same_shape = a.points.shape == b.points.shape
    return {"locations": len(a), "same_counts": bool(np.array_equal(a.count, b.count)),
            "same_singular": bool(np.array_equal(a.singular, b.singular)),
            "max_point_diff_rad": float(np.nanmax(np.abs(a.points - b.points))) if same_shape and
            np.isfinite(a.points).any() else None}


def _engine(tracer: dict[str, Any] | None, cuda: bool) -> dict[str, Any]:
    """The tracer the data is built with: fused with CUDA graphs where the check on this device agreed
    with the compacting tracer and the capture worked, fused eager where only that agreed, else compact."""
    check = (tracer or {}).get("check_fused_vs_compact", {})
    if not (check.get("same_counts") and check.get("same_singular")):
        return {"engine": "compact", "graphs": False}
    return {"engine": "fused", "graphs": cuda and not (tracer or {}).get("capture_error")}


def build_data(run: Run, s: dict[str, Any], arm: Any, grid: Any, dev: Any) -> Any:
    """The coarse grid's data set, refined where neighbouring cells disagree until the data deadline."""
    import numpy as np

    from armbridge.smm import refine as rf
    from armbridge.smm.dataset import build_dataset

    opts = dict(seeds=s["seeds"], step=s["step"], sing_tol=0.005, device=str(dev), chunk=s["chunk"],
                **_engine(run.results.get("tracer"), dev.type == "cuda"))
    run.results["data_engine"] = {k: opts[k] for k in ("engine", "graphs")}
    t = time.monotonic()
    coarse = build_dataset(arm, grid, K=s["K"], N=s["N"], batch=s["batch"], per_cell=0, min_cells=s["min_cells"],
                           **opts)
    coarse_s = time.monotonic() - t
    seeds = rf.seeds_for(arm, coarse)
    t = time.monotonic()
    ds, parts = rf.refine(arm, coarse, s["refine"], pad=0, per_cell=0, batch=s["batch"], min_cells=s["min_cells"],
                          tile=s["tile"], deadline=run.at(0.35), **opts)
    all_patches = rf.patches(grid, seeds, s["refine"], 0, s["tile"])
    run.results["data"] = {
        "grid": {"lo": list(grid.lo), "hi": list(grid.hi), "shape": list(grid.shape)},
        "coarse_cells": grid.size, "coarse_seconds": round(coarse_s, 1),
        "coarse_s_per_location": coarse_s / grid.size,
        "cells_where_neighbours_disagree_or_unlabelled": int(seeds.sum()),
        "refine": {"factor": list(s["refine"]), "tile": s["tile"], "patches_planned": len(all_patches),
                   "patches_traced": len(parts), "cells_planned": int(sum(g.size for g in all_patches)),
                   "cells_traced": int(sum(p.grid.size for p in parts)), "seconds": round(time.monotonic() - t, 1)},
        "locations_traced": int(grid.size + sum(p.grid.size for p in parts)),
        "rows": int(len(ds.canon)), "clusters": int(ds.cluster_branches.size),
        "clusters_by_branches": {str(int(b)): int(np.sum(ds.cluster_branches == b))
                                 for b in np.unique(ds.cluster_branches)},
        "coarse_count_histogram": {str(int(b)): int(np.sum(coarse.smms.count == b))
                                   for b in np.unique(coarse.smms.count)},
    }
    ds, run.results["data"]["margin"] = margin_points(run, s, arm, grid, ds, opts, coarse_s / grid.size, dev)
    run.results["data"]["locations_traced"] += run.results["data"]["margin"]["traced"]
    return ds


def margin_points(run: Run, s: dict[str, Any], arm: Any, grid: Any, ds: Any, opts: dict[str, Any],
                  per_location: float, dev: Any) -> tuple[Any, dict[str, Any]]:
    """Classifier-only points where a quick branch-count classifier is least sure (smm/margin.py),
    as many as the time to half the budget allows and traced until then: refining where neighbours
    disagree flags nearly every 7R cell, so it hardly focuses (docs/smm.md, "How much data the 7R needs")."""
    from armbridge.smm import margin
    from armbridge.train.smm_data import add_margin

    n = int(max(0.0, run.at(0.5) - time.monotonic()) / max(per_location, 1e-6))
    n = min(n, margin.MAX_CANDIDATES // s["margin_candidates"])
    return add_margin(arm, ds, grid, n, 0, hidden=s["cls_hidden"], steps=s["margin_steps"], batch=s["margin_batch"],
                      candidates=s["margin_candidates"], deadline=run.at(0.5), classifier_device=dev,
                      trace_batch=s["chunk"], **opts)


def _fit_size(s: dict[str, Any], ds: Any) -> tuple[int, ...]:
    """Regressor hidden layers, narrowed until the packed model fits MODEL_BYTES: int8 weights, float32
    biases, scales and output means (smm/packed.py)."""
    n_out = [int(b) * 7 * int(ds.K) * 2 for b in ds.cluster_branches if b > 0]
    hidden = tuple(s["reg_hidden"])
    while True:
        widths = (4,) + hidden
        inner = sum(a * b + 9 * b for a, b in zip(widths[:-1], widths[1:]))
        need = sum(inner + hidden[-1] * o + 13 * o for o in n_out)
        if need <= 0.9 * MODEL_BYTES or hidden[0] <= 16:
            return hidden
        hidden = tuple(max(16, int(h * 0.85)) for h in hidden)


def train_model(run: Run, s: dict[str, Any], ds: Any, dev: Any) -> Any:
    """The classifier and regressors, their steps scaled so training ends by 85 % of the budget."""
    import torch

    from armbridge.smm import networks as nets
    from armbridge.train.smm_data import split
    from armbridge.train.smm_fit import SmmTrainConfig, steps_for, train

    train_rows, test_rows = split(ds.label, 0.1, 0)
    s = {**s, "reg_hidden": _fit_size(s, ds)}
    # seconds per step of the largest network, measured here (launch-bound on a GPU: about the same for all)
    probe = nets.mlp(4, s["reg_hidden"], 7 * 2 * s["K"] * 3).to(dev)
    opt = torch.optim.AdamW(probe.parameters(), 1e-3)
    x = torch.rand(s["train_batch"], 4, device=dev)
    t = time.perf_counter()
    for i in range(45):  # a step as smm_fit._fit takes it: lr set, forward, backward, step, the loss read back
        if i == 5:
            t = time.perf_counter()
        for g in opt.param_groups:
            g["lr"] = 1e-3
        loss = probe(x).square().sum(-1).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        float(loss.detach())
    per_step = (time.perf_counter() - t) / 40 * 1.2  # and the epochs' own work besides
    left = run.at(0.85) - time.monotonic()
    rows = [int((ds.label[train_rows] >= 0).sum())] + [int((ds.cluster[train_rows] == c).sum())
                                                       for c in range(ds.cluster_branches.size)
                                                       if ds.cluster_branches[c] > 0]
    rows = [r for r in rows if r > 0]
    scale = 1.0
    for _ in range(40):  # the largest share of the paper's epochs and min_steps that fits
        cfg = SmmTrainConfig(s["cls_hidden"], s["reg_hidden"], epochs=max(1, int(s["epochs"] * scale)),
                             min_steps=int(s["min_steps"] * scale), batch=s["train_batch"], seed=0)
        total = sum(math.prod(steps_for(cfg, r)) for r in rows)
        if total * per_step <= left or scale < 1e-3:
            break
        scale *= 0.8
    run.results["training"] = {"networks": len(rows), "steps": total, "estimated_s_per_step": per_step,
                               "share_of_paper_schedule": scale, "epochs": cfg.epochs, "min_steps": cfg.min_steps,
                               "batch": cfg.batch, "cls_hidden": list(cfg.cls_hidden),
                               "reg_hidden": list(cfg.reg_hidden), "train_rows": int(train_rows.size),
                               "held_out_rows": int(test_rows.size)}
    t = time.monotonic()
    trained = train(ds, train_rows, cfg, progress=False, device=dev)
    run.results["training"]["seconds"] = round(time.monotonic() - t, 1)
    return trained, test_rows


def measure_model(run: Run, s: dict[str, Any], arm: Any, grid: Any, ds: Any, trained: Any, test_rows: Any,
                  dev: Any) -> None:
    """Table III's metrics of the packed (int8) model: on held-out grid rows, and on random locations of the
    region traced here for their true branch count."""
    import numpy as np

    from armbridge.smm import nullspace, packed
    from armbridge.smm.grid import region_locations
    from armbridge.train.smm import fk_errors, measure

    files = packed.pack(trained.classifier, trained.regressors,
                        {"robot": arm.name, "lo": trained.classifier.lo.tolist(), "K": int(ds.K), "N": int(ds.N),
                         "cluster_branches": [int(b) for b in ds.cluster_branches],
                         "grid": run.results.get("data", {}).get("grid")}, run.out, max_bytes=FILE_BYTES)
    size = sum(f.stat().st_size for f in files)
    if len(files) - 1 > MAX_MODEL_FILES or size > MODEL_BYTES:
        for f in files:
            f.unlink()
        raise RuntimeError(f"the packed model needs {len(files) - 1} files, {size} bytes (at most {MAX_MODEL_FILES}, "
                           f"{MODEL_BYTES}); not kept")
    run.results["model"] = {"files": {f.name: f.stat().st_size for f in files},
                            "bytes": sum(f.stat().st_size for f in files), "format": packed.FORMAT}
    run.write()
    clf, regs, _ = packed.unpack(run.out)
    smm = packed.learned(arm.name, ds.cluster_branches, ds.K, clf, regs)
    acc: dict[str, Any] = {"held_out_grid_rows": measure(smm, ds, test_rows, s["eval_points"], 3)}
    run.write()
    canon = region_locations(grid, s["random_locations"], seed=101)
    x = np.asarray(arm.uncanonical(canon))
    truth = nullspace.compute(arm, x, seeds=s["seeds"], step=s["step"], sing_tol=0.005, n_points=16,
                              device=str(dev), engine="fused", chunk=len(x))
    pred = smm.compute(x, n_points=s["eval_points"])
    reach = (truth.count > 0) & (pred.count > 0)
    rnd: dict[str, Any] = {"locations": len(x), "branch_count_mismatch_pct":
                           float(np.mean(truth.count != pred.count) * 100),
                           "singular_locations": int(truth.singular.sum())}
    for label, iters in (("before", 0), ("after", 3)):
        got = smm.compute(x[reach], n_points=s["eval_points"], correct_iters=iters) if iters else _take_rows(pred, reach)
        err = fk_errors(arm, got, x[reach]) * 100
        rnd[f"fk_error_pct_{label}"] = {"mean": float(err.mean()), "median": float(np.median(err)),
                                       "max": float(err.max())} if err.size else None
    acc["random_locations"] = rnd
    run.results["accuracy"] = acc


def _take_rows(smm: Any, rows: Any) -> Any:
    from armbridge.smm.manifold import SmmSet

    return SmmSet(smm.points[rows], smm.count[rows], smm.singular[rows])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=os.environ.get("OUT"), help="results folder (default: $OUT)")
    p.add_argument("--budget", type=float, default=420.0, help="seconds for the whole run (default 420)")
    p.add_argument("--tiny", action="store_true", help="a few seconds' settings (the CPU smoke test)")
    p.add_argument("--device", default=None, help="torch device (default: cuda when present, else cpu)")
    p.add_argument("--grid", type=int, nargs=4, default=(3, 3, 24, 48), metavar=("RHO", "Z", "POLAR", "AZIMUTH"))
    p.add_argument("--K", type=int, default=24, help="Fourier components kept (the model's size grows with K)")
    p.add_argument("--chunk", type=int, default=8192, help="locations per tracer batch (and per group of patches)")
    p.add_argument("--bench-locations", type=int, nargs="+", default=None, metavar="N",
                   help="tracer batch sizes to time (default 256 1024 4096)")
    p.add_argument("--random-locations", type=int, default=None, help="random locations measured (default 2000)")
    args = p.parse_args(argv)
    if not args.out:
        p.error("--out (or $OUT) is needed")
    if args.budget <= 0:
        p.error("--budget must be > 0 seconds")
    run = Run(Path(args.out), args.budget)
    sys.path.insert(0, str(ROOT / "host"))
    run.results["array_api_compat"] = _array_api_compat()
    import numpy as np
    import torch

    torch.set_num_threads(1)
    dev = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    s = _settings(args)
    if args.bench_locations:
        s["bench_locations"] = tuple(args.bench_locations)
        s["bench_check"] = min(s["bench_check"], min(args.bench_locations))
    if args.random_locations:
        s["random_locations"] = args.random_locations
    run.results.update({"settings": {k: list(v) if isinstance(v, tuple) else v for k, v in s.items()},
                        "budget_s": args.budget, "device": torch.cuda.get_device_name(dev) if dev.type == "cuda"
                        else f"cpu ({os.cpu_count()} cores)", "versions": {"python": platform.python_version(),
                        "torch": torch.__version__, "numpy": np.__version__}, "started": time.strftime("%FT%TZ", time.gmtime())})
    from armbridge.smm.arms import get_smm_arm
    from armbridge.smm.grid import GridSpec, region_grid

    arm = get_smm_arm("spatial7r")
    rg = region_grid(arm, s["grid"])
    mid = [(a + b) / 2 for a, b in zip(rg.lo[:2], rg.hi[:2])]
    grid = GridSpec((mid[0] - s["half"], mid[1] - s["half"], 0.0, -math.pi),
                    (mid[0] + s["half"], mid[1] + s["half"], math.pi, math.pi), s["grid"])
    run.results["tracer"] = run.phase("tracer", bench_tracer, run, s, arm, grid, dev)
    ds = run.phase("data", build_data, run, s, arm, grid, dev)
    if ds is not None:
        got = run.phase("train", train_model, run, s, ds, dev)
        if got is not None:
            run.phase("measure", measure_model, run, s, arm, grid, ds, *got, dev)
    run.write()
    print(json.dumps({k: run.results.get(k) for k in ("phases", "errors", "accuracy")}, indent=1, default=float))
    return 1 if run.results["errors"] else 0


if __name__ == "__main__":
    sys.exit(main())
