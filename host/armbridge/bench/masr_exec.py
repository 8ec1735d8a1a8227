"""`armbridge bench masr-exec`: MASR plans executed on the emulated mobile actuator (issue 11 §5).

Over `environments` random solvable environments (planning.masr.random_env.
random_environment, seeds 0, 1, ...: random obstacles, start and goal, each
with a known solution) and, unless --quick, E1-E3: MASR-RRT* (p_c 0.6, the
shipped IK-NN as the goal IK, `iterations` iterations, seeded by the
environment) plans; an environment the planner does not solve is skipped and
the next seed taken. The plan's actions then run on the MA's own firmware in
the emulator (`emu:masr_ma?speed=0`, seeded by the environment), driven by the
executor's BoardClient exactly as `armbridge run --home` drives it (HOME, the
setup to the plan's start, then one MV/ROT per step; executor/masr.py).

What is measured, against the truth the host cannot see (the plant):
  * time: the executed time, from the setup's last DONE to the plan's last
    DONE, against the planned time (the plan's steps with the board's ramps,
    executor/masr.py planned_time: the issue's 10 % target) and against tau
    (eq. 7, the sum of eq. (8) over the actions, which has no ramps);
  * the final TRUE pose: the plant's q through MasrArm.fk against the goal
    (dp, dphi; the goal's e_p, e_phi);
  * localisation: |board estimate - true d| at every telemetry sample of the
    plan (50 Hz; the estimate loc.py makes of the wheel's count at that
    instant, so that a period's staleness is not counted), with the board's
    own bound e (loc.py); and right after each magnet, where the board
    re-anchors its estimate at the latched count (loc.py: where the edge fires,
    r_j less the hall window on the side it came from): the error at the first
    sample after each edge of the plant's hall log;
  * what the ramps and the loops add over eq. (8), per action: executed minus
    planned (DONE to DONE), by kind (MV onto a joint, other MV, ROT), beside the
    time a trapezoidal ramp alone adds (|x|/v + v/a, or 2 sqrt(|x|/a) for a
    short move, minus |x|/v): the rest is the approach onto the magnet, the
    stop, the settling and the loops' lag.
The paper's Table II (E1: 46.16 s planned, 48.78 +- 1.81 s executed; final
error 11 +- 3.1 mm, 1.2 +- 0.8 deg on the real robot) is reported beside it.
With --plants N, E1's plan also runs on N boards of hidden truth
(`emu:masr_ma?plant=random&seed=K`, K = 0..N-1: emulator/truth.py), the
spread across boards that Table II measured on the real robot; so do the
short single-action plans (SINGLES: one MV, one action turning a joint, one
turning two, from the arm straight at rest; the per-action overheads weigh most
there). With --calibrated each of those boards is also calibrated first
(calibrate/masr.py from the board's own sensors: MAG per magnet, WHEEL; the
gains stay the shipped ones) and the same plans run again on it, reported
beside the uncalibrated runs.
"""
from __future__ import annotations

import math
import platform
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import typer

from armbridge.bench.command import write_json

PAPER_TABLE_II: dict[str, Any] = {"environment": "E1", "planned_s": 46.16, "executed_mean_s": 48.78, "executed_std_s": 1.81,
                                  "dp_mean_mm": 11.0, "dp_std_mm": 3.1, "dphi_mean_deg": 1.2, "dphi_std_deg": 0.8}
FIXED = ("E1", "E2", "E3")
TIME_TARGET = 0.10  # the issue: executed within 10 % of the planned time
#: the short single-action plans (name, start q, goal q; angles rad, d m): from rest, one action each
SINGLES = (("MV 50 -> 350 mm", (0, 0, 0, 0, 0, 0.05), (0, 0, 0, 0, 0, 0.35)),
           ("turn joint 3, back to d", (0, 0, 0, 0, 0, 0.35), (0, 0, 0.4, 0, 0, 0.35)),
           ("turn joints 2 and 4, to the tip", (0, 0, 0, 0, 0, 0.05), (0, -0.3, 0, 0.3, 0, 0.75)))


@dataclass(frozen=True)
class MasrExecBenchSize:
    environments: int  # random solvable environments
    iterations: int  # MASR-RRT* iterations per plan
    fixed: bool  # also E1-E3
    max_seeds: int  # give up after this many random seeds
    plants: int = 0  # E1's plan also on this many random plants (hidden truth)
    calibrated: bool = False  # ... and again on each of them calibrated (calibrate/masr.py)


FULL = MasrExecBenchSize(environments=50, iterations=1000, fixed=True, max_seeds=200)
QUICK = MasrExecBenchSize(environments=3, iterations=300, fixed=False, max_seeds=20)


def after_edges(t: Any, err: Any, anchor: Any, hall: list) -> list[float]:
    """The error at the first sample after each hall edge (t, joint, latched count, true d) that
    the board has anchored at (its anchor count is the edge's: the board reads the latch in its
    next period, so a sample taken in between is still the dead reckoning before it). Pure."""
    t = np.asarray(t, float)
    out = []
    for te, _j, c, _d in hall:
        if not t.size or te < t[0]:
            continue
        for i in range(int(np.searchsorted(t, te)), min(len(t), int(np.searchsorted(t, te)) + 5)):
            if int(anchor[i]) == int(c):
                out.append(float(err[i]))
                break
    return out


def ramp_extra(x: float, v: float, a: float) -> float:
    """Time a trapezoidal profile (speed v, acceleration a) takes over |x|/v for a move of x. Pure."""
    from armbridge.plans.masr import trapezoid_time

    return trapezoid_time(x, v, a) - abs(x) / v


def plan_masr(env: Any, iterations: int, seed: int, goal_ik: Callable) -> Any:
    """A MasrPlan of MASR-RRT* in env (in memory, as `armbridge plan masr` writes it), or None."""
    from armbridge.planning.masr.plan_file import masr_plan_document, plan_from_document
    from armbridge.planning.masr.rrt_star import plan as plan_rrt

    r = plan_rrt(env, iterations=iterations, goal_ik=goal_ik, seed=seed)
    if r.path is None:
        return None
    doc = masr_plan_document(env, r.path, {"tool": "armbridge bench masr-exec", "iterations": iterations,
                                           "seed": seed})
    return plan_from_document(doc, f"<{env.name} seed {seed}>")


def single_plans(arm: Any) -> list[Any]:
    """SINGLES as MasrPlans (no obstacles; the goal pose is the goal q's)."""
    from armbridge.planning.masr.environment import Environment
    from armbridge.planning.masr.plan_file import masr_plan_document, plan_from_document

    out = []
    for name, start, end in SINGLES:
        q0, q1 = np.asarray(start, float), np.asarray(end, float)
        env = Environment(name=name, arm=arm, obstacles=[], start=q0, goal_pose=np.asarray(arm.fk(q1), float),
                          goal_q=q1)
        doc = masr_plan_document(env, np.stack([q0, q1]), {"tool": "armbridge bench masr-exec", "single": name})
        out.append(plan_from_document(doc, f"<{name}>"))
    return out


def calibrate_board(seed: int, fs: Path) -> dict[str, Any]:
    """`armbridge calibrate masr_ma --only magnets --only wheel` (calibrate/base.py's flow: the
    procedure from the board's own sensors, the settings, CALID, the host file) on the board of
    hidden truth `seed`, its filesystem kept in `fs` so the runs after boot with the calibration
    it saved -> its settings, what was found and (the bench may look) the truth."""
    from armbridge.calibrate.base import calibrate_board as flow
    from armbridge.link.transport import open_port

    t0 = time.perf_counter()
    url = f"emu:masr_ma?speed=0&seed={seed}&plant=random&fs={fs}"
    report = flow(url, "masr_ma", only=("magnets", "wheel"), cal_dir=fs / "host-calibration")
    port = open_port(url)        # the same board again, only to read its truth
    try:
        pl = port.emulator.plant
        truth = {"centre_mm": [m * 1000.0 for m in pl.magnets], "half_window_mm": pl.window * 1000.0,
                 "wheel_nm_per_count": pl.wheel_q * 1e9}
    finally:
        port.close()
    return {"settings": [[v, list(a)] for v, a in report.settings], "found": report.found.values, "truth": truth,
            "wall_s": time.perf_counter() - t0}


def execute(mp: Any, seed: int, plant: str = "nominal", fs: Path | None = None) -> dict[str, Any]:
    """Run one MasrPlan on emu:masr_ma (setup, then its steps; `plant`: nominal or random,
    drawn with `seed`) -> the measured numbers of one run. `fs`: the board's filesystem,
    where a calibration saved it (the board boots with it)."""
    from armbridge.executor.client import BoardClient
    from armbridge.executor.masr import masr_commands, planned_time
    from armbridge.geometry import wrap_angle
    from armbridge.link.transport import open_port

    plan, commands = masr_commands(mp, home=True)
    setup = int(plan.provenance["masr_plan"]["setup"])
    durs = [max(1, int(round(d * 1000))) for d in plan.durations]
    port = open_port(f"emu:masr_ma?speed=0&seed={seed}&plant={plant}" + (f"&fs={fs}" if fs is not None else ""))
    samples: list[tuple[float, float, float, int, float, int]] = []  # true d, estimate, bound (mm), done index, t,
    #                                                                   the count the estimate is anchored at
    try:
        emu = port.emulator
        client: BoardClient | None = None

        def on_telemetry(t: float, m: Any) -> None:
            b, pl = emu.board, emu.plant
            if b is not None and client is not None and b.loc.known:  # the estimate at the wheel's count now
                samples.append((pl.d * 1000.0, b.loc.at(pl.wheel_count()), b.loc.err(), client.done_index, pl.t,
                                b.loc.c_a))

        client = BoardClient(port, plan.robot, on_telemetry=on_telemetry)
        client.connect()
        client.set_rate(50)
        client.execute(durs, [], commands=commands)
        client.drain(0.1)
        done = dict(client.done_times)
        q_true = np.asarray(emu.plant.q, float)
        hall = list(emu.hal.hall_log)
        cfg = emu.cfg
        log_ok = [(w, tuple(a)) for _, w, a in emu.executed] == [(i, tuple(a)) for i, (_, a) in
                                                                 enumerate(commands)]
    finally:
        port.close()
    planned = planned_time(mp)
    t0 = done[setup - 1]
    executed = done[len(commands) - 1] - t0
    arm = mp.arm
    pose = arm.fk(q_true)
    goal = np.asarray(mp.env.goal_pose, float)
    dp = float(np.hypot(*(pose[:2] - goal[:2])))
    dphi = float(abs(wrap_angle(pose[2] - goal[2])))
    # per action: executed (DONE to DONE) against eq. (8), and what a ramp alone would add
    v, w = arm.ma_speed, arm.joint_speed
    a_d, a_th = cfg.LOCO_ACCEL_MM_S2 / 1000.0, cfg.ROT_ACCEL_MRAD_S2 / 1000.0
    r = np.asarray(arm.r, float)
    kinds: dict[str, list[tuple[float, float]]] = {"MV onto a joint": [], "MV": [], "ROT": []}
    for i, step in enumerate(mp.steps()):
        k = setup + i
        over = done[k] - done[k - 1] - float(step["duration"])
        if step["op"] == "move":
            x = step["d_to"] - step["d_from"]
            kind = "MV onto a joint" if np.min(np.abs(r - step["d_to"])) < 1e-6 else "MV"
            kinds[kind].append((over, ramp_extra(x, v, a_d)))
        else:
            kinds["ROT"].append((over, ramp_extra(step["theta_to"] - step["theta_from"], w, a_th)))
    # localisation: every sample of the plan proper, and the re-anchoring error at each magnet
    s = np.array([x for x in samples if x[3] >= setup - 1], float).reshape(-1, 6)
    err = np.abs(s[:, 1] - s[:, 0])
    after = [abs(x) for x in after_edges(s[:, 4], s[:, 1] - s[:, 0], s[:, 5], hall)]
    return {"environment": mp.env.name, "seed": seed, "plant": plant, "calibrated": fs is not None,
            "actions": len(commands) - setup, "tau_s": mp.total_time, "planned_s": planned,
            "executed_s": executed, "time_ratio": executed / planned, "tau_ratio": executed / mp.total_time, "dp_mm": dp * 1000.0,
            "dphi_deg": math.degrees(dphi), "e_p_mm": mp.env.e_p * 1000.0, "e_phi_deg": math.degrees(mp.env.e_phi),
            "log_exactly_once": log_ok,
            "loc": {"mean_mm": float(err.mean()), "max_mm": float(err.max()),
                    "max_over_bound": float(np.max(err / s[:, 2])), "bound_max_mm": float(s[:, 2].max()),
                    "after_magnet_mean_mm": float(np.mean(after)) if after else None,
                    "after_magnet_max_mm": float(np.max(after)) if after else None, "magnets": len(after)},
            "overhead": {kd: {"n": len(xs), "measured_s": float(sum(o for o, _ in xs)),
                              "ramp_s": float(sum(m for _, m in xs))} for kd, xs in kinds.items()}}


def _stats(x: list[float]) -> dict[str, float]:
    a = np.asarray(x, float)
    return {"mean": float(a.mean()), "std": float(a.std(ddof=1)) if a.size > 1 else 0.0,
            "min": float(a.min()), "max": float(a.max())}


def summarize(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The table's numbers over a set of runs (those that completed)."""
    ok = [r for r in runs if "error" not in r]
    if not ok:
        return {"runs": len(runs), "completed": 0}
    tau = sum(r["tau_s"] for r in ok)
    over: dict[str, dict[str, Any]] = {}
    for kd in ok[0]["overhead"]:
        n = sum(r["overhead"][kd]["n"] for r in ok)
        meas = sum(r["overhead"][kd]["measured_s"] for r in ok)
        ramp = sum(r["overhead"][kd]["ramp_s"] for r in ok)
        over[kd] = {"actions": n, "per_action_s": meas / n if n else None, "ramp_per_action_s": ramp / n if n else None,
                    "share_of_tau": meas / tau}
    return {
        "runs": len(runs), "completed": len(ok),
        "tau_s": _stats([r["tau_s"] for r in ok]), "executed_s": _stats([r["executed_s"] for r in ok]),
        "planned_s": _stats([r["planned_s"] for r in ok]),
        "time_ratio": _stats([r["time_ratio"] for r in ok]), "tau_ratio": _stats([r["tau_ratio"] for r in ok]),
        "within_10_percent": float(np.mean([r["time_ratio"] <= 1.0 + TIME_TARGET for r in ok])),
        "dp_mm": _stats([r["dp_mm"] for r in ok]), "dphi_deg": _stats([r["dphi_deg"] for r in ok]),
        "at_goal": float(np.mean([r["dp_mm"] <= r["e_p_mm"] and r["dphi_deg"] <= r["e_phi_deg"] for r in ok])),
        "log_exactly_once": all(r["log_exactly_once"] for r in ok),
        "loc_mean_mm": float(np.mean([r["loc"]["mean_mm"] for r in ok])),
        "loc_max_mm": float(max(r["loc"]["max_mm"] for r in ok)),
        "loc_max_over_bound": float(max(r["loc"]["max_over_bound"] for r in ok)),
        "after_magnet_mean_mm": float(np.mean([r["loc"]["after_magnet_mean_mm"] for r in ok
                                               if r["loc"]["after_magnet_mean_mm"] is not None])),
        "after_magnet_max_mm": float(max(r["loc"]["after_magnet_max_mm"] or 0.0 for r in ok)),
        "overhead": over,
        "overhead_share_of_tau": sum(o["share_of_tau"] for o in over.values()),
    }


def calibration_summary(cals: list[dict[str, Any]]) -> dict[str, Any]:
    """What the calibrations found against the truth: magnet centres (2..n-1), half windows, the wheel."""
    ok = [c for c in cals if "error" not in c]
    if not ok:
        return {"boards": len(cals), "completed": 0}
    ce = np.array([np.asarray(c["found"]["magnets"]["centre_mm"][1:]) - np.asarray(c["truth"]["centre_mm"][1:])
                   for c in ok])
    he = np.array([np.asarray(c["found"]["magnets"]["half_window_mm"][1:]) - c["truth"]["half_window_mm"] for c in ok])
    we = np.array([c["found"]["wheel_nm_per_count"] / c["truth"]["wheel_nm_per_count"] - 1.0 for c in ok])
    return {"boards": len(cals), "completed": len(ok),
            "centre_err_mm": {"rms": float(np.sqrt(np.mean(ce ** 2))), "max": float(np.abs(ce).max())},
            "half_window_err_mm": {"rms": float(np.sqrt(np.mean(he ** 2))), "max": float(np.abs(he).max())},
            "wheel_err": {"rms": float(np.sqrt(np.mean(we ** 2))), "max": float(np.abs(we).max())},
            "wall_s_mean": float(np.mean([c["wall_s"] for c in ok]))}


def run(size: MasrExecBenchSize, progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    from armbridge.errors import ArmbridgeError
    from armbridge.planning.command import resolve_goal_ik
    from armbridge.planning.masr.environment import fixed_environment
    from armbridge.planning.masr.random_env import random_environment
    from armbridge.robots import get_masr

    arm = get_masr("masr5")
    t0 = time.perf_counter()
    result: dict[str, Any] = {"benchmark": "masr-exec (issue 11 section 5; masr paper Table II)",
                              "size": asdict(size), "paper_table_ii": PAPER_TABLE_II,
                              "machine": {"python": platform.python_version(),
                                          "cpu": platform.processor() or platform.machine()}}

    def run_on(mp: Any, seed: int, plant: str = "nominal", fs: Path | None = None) -> dict[str, Any]:
        try:
            return execute(mp, seed, plant, fs)
        except ArmbridgeError as exc:  # a run that failed is reported, not hidden
            return {"environment": mp.env.name, "seed": seed, "plant": plant, "tau_s": mp.total_time,
                    "error": str(exc)}

    def one(env: Any, seed: int) -> dict[str, Any] | None:
        goal_ik, ik = resolve_goal_ik(env)
        result["goal_ik"] = ik
        mp = plan_masr(env, size.iterations, seed, goal_ik)
        return None if mp is None else run_on(mp, seed)

    runs: list[dict[str, Any]] = []
    unsolved = []
    seed = 0
    while len(runs) < size.environments and seed < size.max_seeds:
        env = random_environment(arm, seed=seed)
        r = one(env, seed)
        if r is None:
            unsolved.append(seed)
        else:
            runs.append(r)
            progress(f"{len(runs)}/{size.environments} environments (seed {seed}: "
                     + (f"failed: {r['error']}" if "error" in r else
                        f"tau {r['tau_s']:.1f} s, executed {r['executed_s']:.1f} s, dp {r['dp_mm']:.1f} mm")
                     + f"; {time.perf_counter() - t0:.0f} s)")
        seed += 1
    result["random"] = {"runs": runs, "unsolved_seeds": unsolved, "summary": summarize(runs)}
    if size.fixed:
        fixed = []
        for name in FIXED:
            r = None
            for s in range(10):  # the first seed the planner solves
                r = one(fixed_environment(name), s)
                if r is not None:
                    break
            if r is not None:
                fixed.append(r)
                progress(f"{name}: tau {r['tau_s']:.1f} s, executed {r.get('executed_s', float('nan')):.1f} s")
        result["fixed"] = {"runs": fixed, "summary": summarize(fixed)}
    if size.plants:
        env = fixed_environment("E1")
        goal_ik, _ = resolve_goal_ik(env)
        mp = next((m for m in (plan_masr(env, size.iterations, s, goal_ik) for s in range(10)) if m is not None), None)
        singles = single_plans(arm)
        sets: dict[str, list[dict[str, Any]]] = {"e1_random_plants": [], "singles_random_plants": []}
        if size.calibrated:
            sets.update({"e1_calibrated": [], "singles_calibrated": [], "calibrations": []})

        def note(label: str, r: dict[str, Any]) -> None:
            progress(f"{label}: " + (f"failed: {r['error']}" if "error" in r else
                                     f"executed {r['executed_s']:.2f} s (tau {r['tau_s']:.2f}), dp {r['dp_mm']:.1f} mm, "
                                     f"dphi {r['dphi_deg']:.2f} deg"))

        boards = Path(tempfile.mkdtemp(prefix="armbridge-masr-exec-"))   # each calibrated board's filesystem
        for k in range(size.plants if mp is not None else 0):
            variants: list[tuple[str, Path | None]] = [("", None)]
            if size.calibrated:
                try:
                    cal = calibrate_board(k, boards / f"ma-{k}")
                except ArmbridgeError as exc:
                    cal = {"seed": k, "error": str(exc)}
                cal["seed"] = k
                sets["calibrations"].append(cal)
                progress(f"random plant {k}: calibrated in {cal.get('wall_s', 0):.0f} s"
                         + (f", failed: {cal['error']}" if "error" in cal else ""))
                if "error" not in cal:
                    variants.append((" calibrated", boards / f"ma-{k}"))
            for tag, fs in variants:
                key = "_calibrated" if tag else "_random_plants"
                r = run_on(mp, k, "random", fs)
                sets["e1" + key].append(r)
                note(f"E1 on random plant {k}{tag}", r)
                for sp in singles:
                    r = run_on(sp, k, "random", fs)
                    sets["singles" + key].append(r)
                    note(f"{sp.env.name} on random plant {k}{tag}", r)
        for key, runs in sets.items():
            result[key] = {"runs": runs} if key == "calibrations" else {"runs": runs, "summary": summarize(runs)}
        if size.calibrated:
            result["calibrations"]["summary"] = calibration_summary(sets["calibrations"])
        shutil.rmtree(boards, ignore_errors=True)
    result["wall_s"] = time.perf_counter() - t0
    return result


def masr_exec_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 3 random environments, 300 iterations, "
                                                      "no E1-E3."),
    environments: int = typer.Option(None, "--environments", help="Random solvable environments (full run: 50)."),
    iterations: int = typer.Option(None, "--iterations", help="MASR-RRT* iterations per plan (full run: 1000)."),
    plants: int = typer.Option(0, "--plants", min=0, help="Also run E1's plan and the single-action plans on this many "
                                                          "random plants (emu:masr_ma?plant=random&seed=0..N-1: "
                                                          "hidden truth)."),
    calibrated: bool = typer.Option(False, "--calibrated", help="With --plants: also calibrate each board "
                                                                "(armbridge calibrate masr_ma's procedure) and run "
                                                                "the same plans on it, beside the uncalibrated runs."),
    json_out: Path = typer.Option(Path("runs/bench-masr-exec.json"), "--json", help="Where to write the results ('-': stdout)."),
) -> None:
    """MASR plans executed on the emulated MA (emu:masr_ma): planned tau against executed time, the true final
    pose errors, localisation errors, and what the ramps and loops add over eq. (8), beside the paper's Table II."""
    from dataclasses import replace

    from rich.console import Console
    from rich.table import Table

    size = QUICK if quick else FULL
    if environments is not None:
        size = replace(size, environments=environments)
    if iterations is not None:
        size = replace(size, iterations=iterations)
    size = replace(size, plants=plants, calibrated=calibrated)
    console = Console()
    result = run(size, progress=lambda text: console.print(f"[dim]bench masr-exec: {text}[/]"))
    write_json(result, json_out)
    t = Table(title="MASR plans executed on the emulated MA (true pose from the plant)")
    for col in ("set", "runs", "tau, planned (s)", "executed (s)", "executed / planned (/ tau)", "within 10 %",
                "dp mm (mean +- std / max)",
                "dphi deg (mean +- std / max)", "at goal"):
        t.add_column(col, justify="left" if col == "set" else "right")
    paper = PAPER_TABLE_II
    t.add_row("paper, Table II (E1)", "-", f"{paper['planned_s']:.2f}",
              f"{paper['executed_mean_s']:.2f} +- {paper['executed_std_s']:.2f}",
              f"{paper['executed_mean_s'] / paper['planned_s']:.3f}", "-", "-", "-", "-")
    t.add_row("paper, Table II (E1), final error", "-", "-", "-", "-", "-",
              f"{paper['dp_mean_mm']:.1f} +- {paper['dp_std_mm']:.1f}",
              f"{paper['dphi_mean_deg']:.1f} +- {paper['dphi_std_deg']:.1f}", "-")
    for key, label in (("random", f"{size.environments} random"), ("fixed", "E1-E3"),
                       ("e1_random_plants", f"E1, {size.plants} random plants"),
                       ("e1_calibrated", f"E1, {size.plants} random plants, calibrated"),
                       ("singles_random_plants", f"single actions, {size.plants} random plants"),
                       ("singles_calibrated", f"single actions, {size.plants} random plants, calibrated")):
        s = result.get(key, {}).get("summary")
        if not s or not s.get("completed"):
            continue
        t.add_row(label, f"{s['completed']}/{s['runs']}",
                  f"{s['tau_s']['mean']:.2f} +- {s['tau_s']['std']:.2f}, {s['planned_s']['mean']:.2f}",
                  f"{s['executed_s']['mean']:.2f} +- {s['executed_s']['std']:.2f}",
                  f"{s['time_ratio']['mean']:.3f} (max {s['time_ratio']['max']:.3f}; / tau "
                  f"{s['tau_ratio']['mean']:.3f})", f"{s['within_10_percent']:.0%}",
                  f"{s['dp_mm']['mean']:.2f} +- {s['dp_mm']['std']:.2f} / {s['dp_mm']['max']:.2f}",
                  f"{s['dphi_deg']['mean']:.2f} +- {s['dphi_deg']['std']:.2f} / {s['dphi_deg']['max']:.2f}",
                  f"{s['at_goal']:.0%}")
    console.print(t)
    for key, label in (("e1_random_plants", "E1, uncalibrated"), ("e1_calibrated", "E1, calibrated"),
                       ("singles_random_plants", "single actions, uncalibrated"),
                       ("singles_calibrated", "single actions, calibrated")):
        s = result.get(key, {}).get("summary")
        if s and s.get("completed"):
            console.print(f"{label}: localisation right after a magnet: mean {s['after_magnet_mean_mm']:.2f} mm, "
                          f"max {s['after_magnet_max_mm']:.2f} mm; |estimate - true d| mean {s['loc_mean_mm']:.2f} "
                          f"mm, max {s['loc_max_mm']:.2f} mm")
    cs = result.get("calibrations", {}).get("summary")
    if cs and cs.get("completed"):
        console.print(f"calibration against the truth ({cs['completed']}/{cs['boards']} boards): magnet centre rms "
                      f"{cs['centre_err_mm']['rms']:.2f} mm (max {cs['centre_err_mm']['max']:.2f}), half window rms "
                      f"{cs['half_window_err_mm']['rms']:.3f} mm (max {cs['half_window_err_mm']['max']:.3f}), wheel "
                      f"rms {cs['wheel_err']['rms']:.3%} (max {cs['wheel_err']['max']:.3%}), "
                      f"{cs['wall_s_mean']:.0f} s each")
    s = result["random"]["summary"]
    if s.get("completed"):  # the loops' share and the localisation, over the random environments
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
