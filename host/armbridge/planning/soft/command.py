"""`armbridge plan soft --env ENV --out PLAN.json`: plan a soft-arm motion and write it for the pump board.

Plan with WJRRT (or JT-RRT, Bi-RRT) on a scene, pick the pump waypoints
(planning/soft/waypoints.py: the fewest nodes within the tracking tolerance,
collision-free, dead band, timed by the inflation/deflation rates) and write an
armbridge-plan that `armbridge run` executes (planning/soft/plan_file.py).
Planning, the goal state and the waypoints keep the clearance margin
(planning/soft/margin.py: the pump controller's joint tolerance through the
chain, or the scene's "margin", or --margin MM) from every obstacle; the
summary and the plan report it (`margin_mm`) and the least clearance of the
waypoints' straight segments the board is sent (`clearance_min_mm`) and of
the planner's path (`planned_clearance_min_mm`).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Optional

import numpy as np
import typer

from armbridge.errors import ArmbridgeError
from armbridge.jsonfile import JSON_HELP, emit_json


@dataclass
class SoftPlanning:
    """What planning a scene for the pump gave: the scene, the planner's result, the waypoints, the Plan."""

    scene: Any
    result: Any
    waypoints: Any
    timing: Any
    plan: Any
    clearance: dict[str, float]

    def summary(self) -> dict[str, Any]:
        r, w = self.result, self.waypoints
        return {"scene": self.scene.name, "planner": r.planner, "seed": r.seed, "success": True, **self.clearance,
                "iterations": r.iterations, "planning_time_s": round(r.time_s, 4), "tree_size": r.tree_size,
                "planned_nodes": w.planned_nodes, "waypoints": int(len(w.q)), "plan_rows": self.plan.k,
                "tolerance_m": w.tolerance_m, "max_tracking_error_m": float(w.error_m.max(initial=0.0)),
                "snapped_joints": int(w.snapped.sum()), "planned_duration_s": round(self.plan.total_duration, 3),
                **{k: v for k, v in r.stats.items() if k not in ("tip_error_m", "clearance_min_m")},
                "planner_tip_error_m": r.stats.get("tip_error_m"),
                # the last pump waypoint's tip (after ik.onto_goal and the dead-band snap): what the board is sent
                "tip_error_m": float(np.linalg.norm(self.scene.checker().tip(w.q[-1]) - self.scene.goal_point))}


def plan_for_pump(env: Any, planner: str = "wjrrt", *, seed: int = 0, iterations: Optional[int] = None,
                  tolerance: Optional[float] = None, tool: str = "armbridge plan soft",
                  margin: Optional[float] = None) -> SoftPlanning:
    """Load the scene (a file, a fixed scene's name or random:LINKS:KIND:SEED), plan keeping the clearance
    margin (m; default: the scene's planning margin), pick and time the pump waypoints."""
    from armbridge.planning.soft import waypoints as W
    from armbridge.planning.margin import check_margin
    from armbridge.planning.soft.margin import ClearanceObjective
    from armbridge.planning.soft.ik import onto_goal
    from armbridge.planning.soft.planners import PLANNERS, plan
    from armbridge.planning.soft.plan_file import soft_plan
    from armbridge.planning.soft.pump_timing import board_timing
    from armbridge.planning.soft.random_scene import open_scene
    from armbridge.planning.soft.scene import Scene

    if planner not in PLANNERS:
        raise ArmbridgeError(f"--planner {planner!r}: unknown planner (known: {', '.join(PLANNERS)})")
    if iterations is not None and iterations < 1:
        raise ArmbridgeError(f"--iterations {iterations}: must be at least 1")
    tol = W.TOLERANCE_M if tolerance is None else float(tolerance)
    if not 0 < tol <= 1.0:
        raise ArmbridgeError(f"--tolerance {tol:g} m is outside (0, 1]")
    if margin is not None:
        check_margin(margin, "--margin")
    scene = env if isinstance(env, Scene) else open_scene(str(env))
    margin = scene.planning_margin if margin is None else float(margin)
    checker = scene.planning_checker(margin=margin)
    if not checker.is_valid(scene.start):
        raise ArmbridgeError(f"{scene.name}: the start keeps {checker.clearance(scene.start) * 1000:.1f} mm from the "
                             f"obstacles, less than the {margin * 1000:g} mm clearance margin; plan with a smaller "
                             "--margin; no plan written")
    result = plan(scene, planner, seed=seed, iterations=iterations, margin=margin)
    if result.path is None:
        raise ArmbridgeError(f"{planner} found no path to the goal of {scene.name} in {result.iterations} iterations "
                             f"(seed {seed}); try more --iterations or another --seed; no plan written")
    result = replace(result, path=onto_goal(result.path, checker, scene.goal_point, scene.goal_tol))
    timing = board_timing(scene.robot)
    wp = W.subsample(result.path, checker, timing, tol)
    least = ClearanceObjective(scene.checker())
    clearance = {"margin_mm": round(margin * 1000, 3), "clearance_min_mm": round(least.path(wp.q) * 1000, 3),
                 "planned_clearance_min_mm": round(least.path(result.path) * 1000, 3)}
    return SoftPlanning(scene, result, wp, timing, soft_plan(scene, result, wp, timing, planner=planner, seed=seed,
                                                             tool=tool, clearance=clearance), clearance)


def soft_cmd(
    env: str = typer.Option(..., "--env", help="Scene JSON file (armbridge-chain-env), a fixed scene: two-arm, "
                                               "three-arm, seven-tube, horn, or a generated one: "
                                               "random:LINKS:KIND:SEED (e.g. random:3:corridor:7)."),
    out: Path = typer.Option(..., "--out", help="Plan file to write (armbridge-plan JSON; `armbridge run` runs it)."),
    planner: str = typer.Option("wjrrt", "--planner", help="wjrrt, jt-rrt, birrt or wjrrt-connect."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same plan)."),
    iterations: Optional[int] = typer.Option(None, "--iterations", "-n",
                                             help="Planner iterations [default: the scene's params.iterations]."),
    tolerance: float = typer.Option(0.01, "--tolerance",
                                    help="Tracking tolerance of the pump waypoints, m: the largest distance of any "
                                         "arm point between the straight segments and the planned path."),
    margin: Optional[float] = typer.Option(None, "--margin", metavar="MM",
                                           help="Clearance every link keeps from every obstacle, mm, in [0, 50] "
                                                "[default: the scene's margin, else the pump controller's joint "
                                                "tolerance through the chain: 4.8 mm for soft3]."),
    png: Optional[Path] = typer.Option(None, "--png", help="Also draw the scene, the path and the waypoints to this PNG."),
    json_out: Optional[str] = typer.Option(None, "--json", metavar="FILE|-",
                                           help=JSON_HELP.format(what="the planning summary")),
) -> None:
    """Plan a soft-arm motion and write it as a plan for the pump board.

    WJRRT (the WJRRT paper's Algorithms 2-3) or a baseline plans on the scene; the plan keeps the fewest
    planned nodes whose straight segments stay within --tolerance of the path and are collision-free,
    holds joint changes below the dead band, and times each move by the pump's inflation and deflation
    rates with a settle hold. Every link keeps --margin from every obstacle along the whole path.
    `armbridge run PLAN --port emu:arduino_pump` executes it."""
    from rich.console import Console
    from rich.table import Table

    from armbridge.planning.base import compile_note
    from armbridge.plans.format import save_plan

    console = Console()
    note = compile_note("soft")
    if note is not None:
        console.print(note, style="dim")
    with console.status(f"{planner} on {env} ..."):
        sp = plan_for_pump(env, planner, seed=seed, iterations=iterations, tolerance=tolerance,
                           margin=None if margin is None else margin / 1000.0)
    summary = sp.summary()
    table = Table(title=f"{planner} on {sp.scene.name}", show_header=False)
    for key in ("iterations", "planning_time_s", "tree_size", "planned_nodes", "waypoints", "plan_rows",
                "max_tracking_error_m", "snapped_joints", "planned_duration_s", "tip_error_m", "margin_mm",
                "clearance_min_mm", "planned_clearance_min_mm"):
        v = summary.get(key)
        table.add_row(key, f"{v:.4f}" if isinstance(v, float) else str(v))
    console.print(table)
    if png is not None:
        from armbridge.planning.soft.figure import soft_figure

        soft_figure(sp.scene, sp.result.path, sp.waypoints.q, png, title=f"{sp.scene.name} ({planner}, seed {seed})",
                    margin=sp.clearance["margin_mm"] / 1000.0)
        console.print(f"figure: {png}")
    if json_out is not None:
        emit_json(summary, json_out, "the planning summary")
    try:
        save_plan(sp.plan, out)
    except OSError as exc:
        raise ArmbridgeError(f"{out}: cannot write the plan: {exc.strerror}") from None
    console.print(f"plan: {out} ({len(sp.waypoints.q)} pump waypoints of {sp.waypoints.planned_nodes} planned "
                  f"nodes, {sp.plan.total_duration:.1f} s)")
