"""The soft-arm demo: WJRRT plans on the three-arm scene, the pump board's firmware executes the plan.

WJRRT (planning/soft/planners.py) plans on the built-in scene "three-arm" (soft3, the
pump board's robot; WJRRT paper, section V-C), the pump waypoints are picked and
timed (planning/soft/waypoints.py: the fewest nodes within the tracking tolerance,
collision-free, the dead band, the inflation/deflation rates with a settle hold),
the plan is written as an armbridge-plan and `armbridge run`'s own run_command
executes it on the syringe-pump board's .elf in simavr (`emu:arduino_pump`). The
recording draws the arm, the obstacles, the planned tip path and poses, and the
executed arm and tip trace in one 2-D view; the demo's summary (demos/soft_report.py)
reports each waypoint's settled angles against its target, the settle times, the
tip errors, the executed path's deviation and clearance, and the executed time
against the planned. The plan keeps the clearance margin (planning/soft/margin.py)
from every obstacle; the report measures the executed arm's least clearance over the
recording beside it, and the demo fails (exit 1, after its report) when the executed
arm touched an obstacle.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from armbridge.demos import Demo, DemoOptions

SCENE = "three-arm"
PLANNER = "wjrrt"


@dataclass
class SoftDemo:
    """One run of the demo: the planning (scene, planner result, waypoints, Plan), the executor's
    Summary and the demo's report (demos/soft_report.py)."""

    planning: Any
    summary: Any
    report: dict[str, Any]


def execute(opts: DemoOptions, console: Any, *, tolerance: float | None = None) -> SoftDemo | None:
    """Plan, write (--write-plan: returns None) or run, and report (module doc)."""
    from armbridge.executor.command import run_command
    from armbridge.planning.base import compile_note
    from armbridge.planning.soft.command import plan_for_pump
    from armbridge.plans.soft import soft_info
    from armbridge.plans.format import save_plan
    from armbridge.telemetry.recording import default_rrd_path
    from armbridge.demos.soft_report import read_trace, soft_report

    console.print(f"demo: {PLANNER.upper()} on {SCENE} (seed {opts.seed})")
    note = compile_note("soft")
    if note is not None:
        console.print(f"demo: {note}")
    sp = plan_for_pump(SCENE, PLANNER, seed=opts.seed, tolerance=tolerance, tool="armbridge demo")
    w, plan = sp.waypoints, sp.plan
    console.print(f"demo: {w.planned_nodes} planned nodes -> {len(w.q)} pump waypoints (tracking tolerance "
                  f"{w.tolerance_m * 1000:.0f} mm, {int(w.snapped.sum())} joint changes held below the dead band), "
                  f"{plan.total_duration:.1f} s planned")
    if opts.write_plan is not None:
        save_plan(plan, opts.write_plan)
        console.print(f"wrote {opts.write_plan} ({plan.k} waypoints, {plan.total_duration:.1f} s)")
        return None
    rrd = opts.rrd if opts.rrd is not None else default_rrd_path(plan.name)
    summary = run_command(plan, opts.port, rrd, 50, opts.json_out, opts.clear, True, goal_exit=False)
    info = soft_info(plan)
    assert info is not None
    names = list(plan.robot.joint_names)
    tol = [summary.settle_tolerance.get(n, 0.0) for n in names]
    report = soft_report(plan, info, read_trace(rrd, names), tol, sp.scene.checker())
    report["rrd"] = str(rrd)
    report["run"] = {"completed": summary.completed, "measured_duration_s": summary.measured_duration_s,
                     "settle": {n: s.__dict__ for n, s in summary.settle.items()}}
    console.print(_table(report))
    return SoftDemo(sp, summary, report)


def _mrad(v: list) -> str:
    return " ".join("-" if x is None else f"{x * 1000:.0f}" for x in v)


def _mm(d: float | None) -> str:
    return "-" if d is None else f"{d * 1000:.1f}"


def _table(r: dict[str, Any]) -> Any:
    from rich.table import Table

    t = Table(title=f"soft-arm demo: {r['planner']} on {r['scene']}", show_header=True, header_style="bold")
    for col in ("waypoint", "node", "target (mrad)", "settled (mrad)", "in band", "settle (s)", "tip error (mm)"):
        t.add_column(col, justify="right")
    for i, p in enumerate(r["poses"]):
        t.add_row(str(i), str(p["node"]), _mrad(p["target"]), _mrad(p["settled"]), "yes" if p["inside_band"] else "NO",
                  "never" if p["settle_s"] is None else f"{p['settle_s']:.2f}",
                  _mm(p["tip_error_m"]))
    t.caption = (f"{r['waypoints']} waypoints of {r['planned_nodes']} planned nodes; every joint settled in its band: "
                 f"{'yes' if r['all_settled'] else 'NO'}; settle mean / max {r['settle_s']['mean']} / "
                 f"{r['settle_s']['max']} s; settled joint error mean / max {r['settled_joint_error_deg']['mean']} / "
                 f"{r['settled_joint_error_deg']['max']} deg; tip error mean / max {_mm(r['tip_error_m']['mean'])} / "
                 f"{_mm(r['tip_error_m']['max'])} mm; executed tip path from the planned: mean / max "
                 f"{_mm(r['path_deviation_m']['mean'])} / {_mm(r['path_deviation_m']['max'])} mm; executed arm's "
                 f"least clearance {r['executed_clearance_min_mm']} mm (planned for a {r['margin_mm']} mm margin: "
                 f"{'kept' if r['keeps_margin'] else 'NOT kept'}); goal {_mm(r['goal_distance_m'])} mm off (tolerance "
                 f"{_mm(r['goal_tol_m'])} mm); executed {r['executed_s']} s to rest at the goal, planned "
                 f"{r['planned_arrival_s']} s to the last move's end ({r['planned_s']} s with the last hold); "
                 f"recording {r['rrd']}")
    return t


def clearance_line(r: dict[str, Any]) -> str | None:
    """What the demo says of the executed arm's clearance (its report `r`): an error line when it touched an
    obstacle, a note when it came inside the plan's margin, else None."""
    if not r["collision_free"]:
        return (f"error: the executed arm touched an obstacle: least clearance {r['executed_clearance_min_mm']} mm "
                f"at t = {r['executed_clearance_t_s']} s ({r['executed_contact']}); the plan kept {r['margin_mm']} mm")
    if r["keeps_margin"] is False:
        return (f"note: the executed arm came within {r['executed_clearance_min_mm']} mm of an obstacle at "
                f"t = {r['executed_clearance_t_s']} s, inside the plan's {r['margin_mm']} mm margin (the margin "
                "covers the joints at rest, not their lag while moving)")
    return None


def run(opts: DemoOptions, console: Any) -> None:
    """The demo, and its exit: 1 when the executed arm touched an obstacle, 3 when it ended outside the
    goal's tolerance (docs/formats.md §7), said after the demo's own report."""
    import typer

    from armbridge.executor.command import GOAL_MISSED, goal_missed_text

    done = execute(opts, console)
    said = None if done is None else clearance_line(done.report)
    if said is not None:
        typer.secho(said, fg="red" if said.startswith("error") else "yellow", err=True)
        if said.startswith("error"):
            raise typer.Exit(1)
    if done is not None and done.summary.goal_missed:
        typer.secho(f"error: {goal_missed_text(done.summary)}", fg="red", err=True)
        raise typer.Exit(GOAL_MISSED)


DEMO = Demo(robot="soft3", summary=f"soft3: plan {SCENE} with WJRRT and run it on the emulated syringe-pump board",
            run=run, aliases=("soft",))
