"""`armbridge bench wjrrt`: Table 1 of the WJRRT paper, with OMPL's planners on the same scenes and checker.

Protocol (docs/benchmarks.md, "Soft arm"):

* scenes: the shipped fixed scenes (planning.soft.scene.FIXED: the paper's
  two-arm, three-arm and seven-arm cases, and OMPL's horn), scene files
  (armbridge-chain-env) and generated scenes (planning.soft.random_scene:
  random:LINKS:KIND:SEEDS, e.g. random:3:corridor:0-9, ten scenes, a
  "group"); seeds 0..seeds-1. A group is summarised over all its scenes'
  runs as well (result["groups"]); the paper's targets are checked on the
  other scenes only.
* warm-up: before any run, every planner runs once on a tiny scene
  (wjrrt_run.warm_up; again once in each worker process), so numba's
  compilation (or its cache's loading) and OMPL's set-up fall on no run.
* planners: ours (planning.soft.planners: WJRRT, JT-RRT, Bi-RRT) with the
  scene's parameters and its iteration budget N (Table 1's "Iter.": a run
  ends at the goal or after N iterations), and OMPL's RRTConnect, KPIECE1,
  STRIDE (planning.soft.ompl_planners) on the same scene.problem(): the same
  joint box, ChainChecker (edge resolution `res`) and tip goal.
* equal time: every run of every planner has the same wall-clock budget T
  (`time_limit`); OMPL's planners have no iteration budget (their iterations
  are another unit). A run succeeds when it returns a path that our checker
  accepts again (path_problem: valid start, every edge free at `res`) and
  whose last state is in the goal. A budget only stops a planner, so a run
  that succeeded after s seconds succeeds with any budget >= s: success at
  budget t <= T is the share of runs whose time to success is <= t, read off
  the same runs (`success_at`). Our planners' iteration budget can only lower
  their curve.
* Table 1's columns per scene and planner: success x/seeds, iterations
  (budget, and the median done), total time (median over successful runs,
  s), nodes, track nodes (path nodes but the start), goal nodes, random
  nodes, obstacle checks (the checker's counter), objective H (WJRRT's eq. 9
  at the last path node): counts are means over the successful runs. Plus
  the time to success over all runs (median, p90; a failure counts as
  infinitely slow, so these are None when fewer than half / 90 % succeed).

Runs go scene by scene, seed by seed, every planner on that seed in turn:
one shard per (scene, seed) (bench.wjrrt_shards), so a load change falls on
all planners alike. Serially (the default) they run in this process in that
order; on Ray (`--workers N`, `--ray`) each shard runs on a worker, and the
table is summarised here from the gathered runs. Our planners' records but
their times are the serial run's when no run ran out of T; OMPL's are not
reproducible even serially (its seed is per process: ompl_bridge.seed_once),
and every time is measured where its shard ran (wjrrt_shards module doc).
"""
from __future__ import annotations

import math
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Optional

import numpy as np

from armbridge.bench.wjrrt_run import OMPL, OURS, PLANNERS
from armbridge.errors import ArmbridgeError

if TYPE_CHECKING:
    from armbridge.shards import Runner

LABELS = {"wjrrt": "WJRRT", "jt-rrt": "JT-RRT", "birrt": "Bi-RRT", "wjrrt-connect": "WJRRT-Connect", "RRTConnect": "OMPL RRTConnect",
          "KPIECE1": "OMPL KPIECE1", "STRIDE": "OMPL STRIDE"}
#: Table 1's count columns (means over the successful runs) and H.
COUNTS = ("nodes", "track_nodes", "goal_nodes", "random_nodes", "obstacle_checks", "final_H")
#: Table 1's columns as the keys of a planner's summary on a scene.
COLUMNS = ("success", "iterations_budget", "iterations_median", "time_median_s") + COUNTS
PAPER_COLUMNS = ("success", "iterations", "time_s") + COUNTS
#: Table 1 of the paper: (success of 10, Iter., time s, nodes, track, goal, random, obstacle checks, H).
PAPER = {
    "two-arm": {"jt-rrt": (8, 500, 7.63, 376, 43, 23, 20, 121, None), "birrt": (8, 500, 7.10, 398, 57, None, 57, 102,
                                                                                None),
                "TB-RRT": (9, 500, 6.23, 352, 90, None, 90, 113, None), "wjrrt": (10, 500, 5.63, 345, 93, 70, 23, 98,
                                                                                  0.001)},
    "three-arm": {"jt-rrt": (7, 1000, 10.43, 753, 181, 138, 43, 234, None),
                  "birrt": (9, 1000, 11.02, 749, 190, None, 190, 274, None),
                  "TB-RRT": (10, 1000, 10.27, 645, 213, None, 213, 334, None),
                  "wjrrt": (9, 1000, 9.43, 674, 209, 163, 46, 359, 0.005)},
    "seven-tube": {"jt-rrt": (6, 2000, 18.43, 1290, 932, 503, 429, 1023, None),
                   "birrt": (7, 2000, 17.63, 1323, 1078, None, 1078, 1092, None),
                   "TB-RRT": (7, 2000, 12.23, 1054, 870, None, 870, 1287, None),
                   "wjrrt": (8, 2000, 13.21, 1583, 1231, 903, 328, 1340, 0.002)},
}
#: The targets: WJRRT's success at least the paper's (share), median time per plan under this (s).
TARGET_SUCCESS = {"two-arm": 1.0, "three-arm": 0.9, "seven-tube": 0.8}
TARGET_MEDIAN_S = 0.5
#: Issue 24 section 3 compares at every budget from this one up to T (s).
VERSUS_FROM_S = 0.05


@dataclass(frozen=True)
class WjrrtBenchSize:
    seeds: int
    time_limit: float  # T, s per run, every planner


FULL = WjrrtBenchSize(seeds=100, time_limit=2.0)
QUICK = WjrrtBenchSize(seeds=2, time_limit=0.5)


def budgets(time_limit: float) -> list[float]:
    """Budgets t to report success at: 1-2-5 steps from 10 ms up to T, and T."""
    out = [m * 10.0 ** e for e in range(-2, 3) for m in (1, 2, 5) if m * 10.0 ** e < time_limit - 1e-9]
    return out + [float(time_limit)]


def _mean(runs: Sequence[dict], key: str) -> Optional[float]:
    vals = [r[key] for r in runs if r["success"] and r[key] is not None]
    return float(np.mean(vals)) if vals else None


def time_to_success(runs: Sequence[dict]) -> np.ndarray:
    """Per run its time if it succeeded, else inf."""
    return np.array([r["time_s"] if r["success"] else math.inf for r in runs], float)


def summarise(runs: Sequence[dict], time_limit: float, budget: Optional[int]) -> dict[str, Any]:
    """Table 1's columns and the equal-time numbers of one planner on one scene (module doc)."""
    ok = [r for r in runs if r["success"]]
    tts = time_to_success(runs)
    n = len(runs)

    def q(p: float) -> Optional[float]:
        v = float(np.quantile(tts, p, method="higher")) if n else math.inf
        return v if math.isfinite(v) else None

    return {
        "runs": n, "success": len(ok), "success_rate": len(ok) / n if n else 0.0,
        "iterations_budget": budget, "iterations_median": float(np.median([r["iterations"] for r in runs])) if n
        else None,
        "time_median_s": float(np.median([r["time_s"] for r in ok])) if ok else None,
        "time_to_success_median_s": q(0.5), "time_to_success_p90_s": q(0.9),
        **{key: _mean(runs, key) for key in COUNTS},
        "tip_error_m_mean": _mean(runs, "tip_error_m"),
        "rejected_by_recheck": sum(1 for r in runs if r["planner_success"] and not r["success"]),
        "success_at": {f"{t:g}": float(np.mean(tts <= t)) if n else 0.0 for t in budgets(time_limit)},
    }


def success_within(runs: Sequence[dict], t: float) -> float:
    """Share of runs with a time to success <= t (the equal-time success at budget t)."""
    return float(np.mean(time_to_success(runs) <= t)) if runs else 0.0


def targets(result: dict[str, Any]) -> dict[str, Any]:
    """WJRRT against the issue's targets: met / missed (bools), with the numbers beside them.

    Equal time is read at two budgets: T itself, and WJRRT's own p95 time
    to success on that scene (T where fewer than 95 % succeed), both from
    the same runs. Where WJRRT is behind an OMPL planner at any reported
    budget, those budgets are listed too (information, not a target).
    """
    out: dict[str, Any] = {}
    T = float(result["size"]["time_limit"])
    for name, sc in result["scenes"].items():
        wd = sc["planners"].get("wjrrt")
        if not wd:
            continue
        w = wd["summary"]
        if name in TARGET_SUCCESS:
            out[f"{name}: WJRRT success >= {TARGET_SUCCESS[name]:.0%}"] = w["success_rate"] >= TARGET_SUCCESS[name]
        med = w["time_median_s"]
        out[f"{name}: WJRRT median time < {TARGET_MEDIAN_S} s"] = med is not None and med < TARGET_MEDIAN_S
        p95 = float(np.quantile(time_to_success(wd["runs"]), 0.95, method="higher"))
        t95 = p95 if math.isfinite(p95) else T
        for pl in OMPL:
            od = sc["planners"].get(pl)
            if not od:
                continue
            for label, t in (("T", T), ("WJRRT's p95", t95)):
                ws, os_ = success_within(wd["runs"], t), success_within(od["runs"], t)
                out[f"{name}: WJRRT success >= {LABELS[pl]} at {label} = {t:.3g} s"] = ws >= os_
                out[f"{name}: WJRRT / {LABELS[pl]} success at {label} = {t:.3g} s"] = [ws, os_]
            behind = [t for t, v in w["success_at"].items() if v < od["summary"]["success_at"][t]]
            if behind:
                out[f"{name}: WJRRT behind {LABELS[pl]} at budgets (s)"] = behind
    return out


def resolve_scenes(items: Sequence[Any]) -> tuple[list[Any], dict[str, list[str]]]:
    """(scenes, groups) of --scenes' items: a fixed scene's name, a scene file, a generated spec
    (random:LINKS:KIND:SEEDS -> one scene per seed, a group: spec -> its scene names) or a Scene.
    Names stay unique (a repeated one gets "-2", "-3", ...); anything else is one ArmbridgeError."""
    from dataclasses import replace
    from pathlib import Path

    from armbridge.planning.soft.random_scene import is_spec, open_scene, parse_spec, random_scene
    from armbridge.planning.soft.scene import Scene

    out: list[Any] = []
    groups: dict[str, list[str]] = {}
    used: set[str] = set()

    def named(scene: Scene) -> Scene:
        name, k = scene.name, 1
        while name in used:
            k += 1
            name = f"{scene.name}-{k}"
        used.add(name)
        return scene if name == scene.name else replace(scene, name=name)

    for item in items:
        if isinstance(item, Scene):
            out.append(named(item))
        elif isinstance(item, (str, Path)) and is_spec(str(item)) and not Path(item).exists():
            made = [named(random_scene(*t)) for t in parse_spec(str(item))]
            key = str(item).strip()
            groups[key] = groups.get(key, []) + [s.name for s in made]
            out += made
        elif isinstance(item, (str, Path)):
            out.append(named(open_scene(str(item))))
        else:
            raise ArmbridgeError(f"--scenes: {item!r} is not a scene name, file or random:LINKS:KIND:SEEDS spec")
    return out, groups


def run(size: WjrrtBenchSize, scenes: Sequence[Any] = (), planners: Sequence[str] = PLANNERS,
        iterations: Optional[int] = None, res: Optional[float] = None,
        progress: Callable[[str], None] = lambda s: None, runner: Optional[Runner] = None) -> dict[str, Any]:
    """Every planner on every scene and seed (module doc) -> the JSON document of `armbridge bench wjrrt`.

    scenes: fixed-scene names (default: all of FIXED), scene files, generated specs (resolve_scenes) or
    Scene objects;
    runner: where the (scene, seed) shards run (None: here, serially).
    """
    from armbridge.bench.wjrrt_shards import sweep
    from armbridge.planning.soft import ompl_planners
    from armbridge.planning.soft.scene import FIXED
    from armbridge.planning.soft.space import EDGE_RES

    from armbridge.bench.wjrrt_run import warm_up

    names = tuple(scenes) or FIXED
    for pl in planners:
        if pl not in PLANNERS:
            raise ArmbridgeError(f"--planners: {pl!r} unknown; use some of {', '.join(PLANNERS)}")
    if size.seeds < 1 or not size.time_limit > 0:
        raise ArmbridgeError(f"--seeds must be >= 1 and --time-limit > 0 s, got {size.seeds}, {size.time_limit}")
    res = EDGE_RES if res is None else float(res)
    loaded, groups = resolve_scenes(names)  # a bad name, file or spec fails before any work
    skipped = {pl: why for pl in planners if pl in OMPL and (why := ompl_planners.missing(pl))}
    active = [pl for pl in planners if pl not in skipped]
    progress("warming up every planner on a tiny scene (numba compiles on first use, up to a minute) ...")
    warm_s = warm_up(active, res)
    result: dict[str, Any] = {
        "benchmark": "wjrrt (Table 1 of the WJRRT paper, with OMPL)", "size": asdict(size), "res_m": res,
        "iterations_override": iterations, "planners": list(planners), "not_run": skipped,
        "budgets_s": budgets(size.time_limit),
        "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
        "paper_table1": {k: {pl: dict(zip(PAPER_COLUMNS, v)) for pl, v in rows.items()} for k, rows in PAPER.items()},
        "shards": runner.backend if runner is not None else "serial", "warm_up_s": warm_s, "scenes": {},
    }
    t0 = time.perf_counter()
    wins: list[dict[str, int]] = [dict.fromkeys(active, 0) for _ in loaded]

    def seed_done(k: int, seed: int, recs: list[dict[str, Any]]) -> None:
        for pl, r in zip(active, recs):
            wins[k][pl] += bool(r["success"])
        if (seed + 1) % 10 == 0 or seed + 1 == size.seeds:
            done = ", ".join(f"{LABELS[p]} {wins[k][p]}" for p in active)
            progress(f"{loaded[k].name}: {seed + 1}/{size.seeds} seeds ({time.perf_counter() - t0:.0f} s): {done}")

    per_seed = sweep(loaded, size.seeds, active, size.time_limit, iterations, res, runner, seed_done)
    for scene, seeds_runs in zip(loaded, per_seed):
        budget = iterations if iterations is not None else int(scene.params.get("iterations", 1000))
        runs = {pl: [recs[i] for recs in seeds_runs] for i, pl in enumerate(active)}
        result["scenes"][scene.name] = {
            "robot": scene.robot.name, "links": scene.robot.n, "goal_tol_m": scene.goal_tol,
            "margin_m": scene.planning_margin,
            "goal_states": int(scene.find_goal_states().shape[0]), "iterations_budget": budget,
            "planners": {pl: {"summary": summarise(runs[pl], size.time_limit, budget if pl in OURS else None),
                              "runs": runs[pl]} for pl in active},
        }
    result["groups"] = {}
    for spec, members in groups.items():
        its = {result["scenes"][n]["iterations_budget"] for n in members}
        group_budget = its.pop() if len(its) == 1 else None
        result["groups"][spec] = {
            "scenes": members, "links": result["scenes"][members[0]]["links"],
            "planners": {pl: {"summary": summarise([r for n in members for r in result["scenes"][n]["planners"][pl]
                                                    ["runs"]], size.time_limit, group_budget if pl in OURS else None)}
                         for pl in active}}
    generated = {n for members in groups.values() for n in members}
    result["targets"] = targets({**result, "scenes": {k: v for k, v in result["scenes"].items()
                                                      if k not in generated}})
    result["versus"] = versus(result)
    result["wall_s"] = time.perf_counter() - t0
    return result


def versus(result: dict[str, Any], ours: str = "wjrrt-connect", peer: str = "RRTConnect") -> dict[str, Any]:
    """Issue 24 section 3's comparison: per group of generated scenes, per other scene and over all of them,
    `ours` against `peer` at every budget from VERSUS_FROM_S to T (success share) and in median time to
    success (over all runs: a failure is infinitely slow), and whether every successful path of every
    planner kept its scene's margin (clearance_min_m >= margin_m). {} when either planner did not run."""
    if any(pl not in result["planners"] or pl in result["not_run"] for pl in (ours, peer)):
        return {}
    generated = _generated(result)
    parts = {spec: g["scenes"] for spec, g in result.get("groups", {}).items()}
    parts.update({n: [n] for n in result["scenes"] if n not in generated})
    parts["all"] = list(result["scenes"])
    shown = [b for b in result["budgets_s"] if b >= VERSUS_FROM_S - 1e-12]
    out: dict[str, Any] = {"ours": ours, "peer": peer, "budgets_s": shown, "parts": {}}
    for key, names in parts.items():
        runs = {pl: [r for n in names for r in result["scenes"][n]["planners"][pl]["runs"]] for pl in (ours, peer)}
        share = {pl: [success_within(runs[pl], b) for b in shown] for pl in runs}
        med = {pl: float(np.median(time_to_success(runs[pl]))) for pl in runs}
        out["parts"][key] = {
            "success_at": share, "time_to_success_median_s": {pl: v if math.isfinite(v) else None
                                                             for pl, v in med.items()},
            "success_met": all(a >= b for a, b in zip(share[ours], share[peer])),
            "median_met": med[ours] <= med[peer]}
    thin = [f"{n}: {pl} seed {r['seed']}" for n, sc in result["scenes"].items() for pl, d in sc["planners"].items()
            for r in d["runs"] if r["success"] and (r.get("clearance_min_m") or 0.0) < sc["margin_m"] - 1e-9]
    out["clearance_below_margin"] = thin
    out["met"] = not thin and all(p["success_met"] and p["median_met"] for p in out["parts"].values())
    return out


def _generated(result: dict[str, Any]) -> set[str]:
    return {n for g in result.get("groups", {}).values() for n in g["scenes"]}
