"""`armbridge plan masr --env ENV --out PLAN.json`: plan a MASR motion with MASR-RRT* or RRT*."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, Optional

import typer
from rich.console import Console
from rich.table import Table

from armbridge import resources
from armbridge.errors import ArmbridgeError
from armbridge.jsonfile import JSON_HELP, emit_json
from armbridge.planning.base import compile_note
from armbridge.planning.soft.command import soft_cmd

plan_app = typer.Typer(help="Plan robot motions and write plan files.", no_args_is_help=True,
                       add_completion=False, pretty_exceptions_enable=False)


def shipped_ik_card(arm_name: str = "masr5", models_dir: Path | None = None) -> Optional[Path]:
    """The shipped IK-NN model card for arm_name (in resources.models_dir()), or None.

    Prefers <arm>-iknn.json, then <arm>-iknn-card.json, then any
    <arm>-iknn*.json card trained with the action-time regulariser (12)
    (card training.reg == "action"), then any card.
    """
    d = models_dir or resources.models_dir()
    for name in (f"{arm_name}-iknn.json", f"{arm_name}-iknn-card.json"):
        if (d / name).is_file():
            return d / name
    cards = sorted(p for p in d.glob(f"{arm_name}-iknn*.json") if p.is_file())
    for p in cards:
        try:
            if json.loads(p.read_text()).get("training", {}).get("reg") == "action":
                return p
        except (OSError, ValueError, AttributeError):
            continue
    return cards[0] if cards else None


def resolve_goal_ik(env: Any, ik: str = "auto") -> tuple[Callable, str]:
    """The goal IK for env: ("auto" | "dls" | a model card path) -> (goal_ik(x_goal, q_c), description).

    An IK-NN answer is refined without the sparsify step (MasrIK.solve(refine=True,
    sparsify=False)): refinement reaches the goal region more often; a sparser
    goal configuration is cheaper to reach but more often blocked in clutter
    (E2: 14 of 20 runs found a path with it, 20 of 20 without).
    """
    from armbridge.ik import masr_dls

    if ik == "dls":
        return masr_dls.goal_ik(env.arm, e_p=env.e_p, e_phi=env.e_phi), "dls (numeric damped least squares)"
    card = shipped_ik_card(env.arm.name) if ik == "auto" else Path(ik)
    if card is None:
        return (masr_dls.goal_ik(env.arm, e_p=env.e_p, e_phi=env.e_phi),
                f"dls (no shipped IK-NN model card {resources.models_dir()}/{env.arm.name}-iknn*.json)")
    if not card.is_file():
        raise ArmbridgeError(f"{card}: no such IK-NN model card")
    from armbridge.ik.masr_ik import MasrIK

    model = MasrIK.load(card)
    model.session  # noqa: B018 - start onnxruntime now, not inside the timed planning loop
    if model.arm != env.arm:
        raise ArmbridgeError(f"{card}: the IK-NN is for robot {model.arm.name!r}, the environment uses {env.arm.name!r}"
                             " with different parameters")

    def goal_ik(x_goal: Any, q_c: Any) -> Any:
        return model.solve(x_goal, q_c, refine=True, sparsify=False)

    return goal_ik, f"IK-NN {card} + refinement (no sparsify)"


@plan_app.callback()
def _plan() -> None:
    """Plan robot motions and write plan files."""


@plan_app.command("masr")
def masr_cmd(
    env: str = typer.Option(..., "--env", help="Environment JSON file, or a fixed environment E1, E2, E3."),
    out: Path = typer.Option(..., "--out", help="Plan file to write (armbridge-masr-plan JSON)."),
    planner: str = typer.Option("masr-rrt*", "--planner", help="masr-rrt* (with the goal IK) or rrt* (baseline)."),
    iterations: int = typer.Option(1000, "--iterations", "-n", help="Planning iterations N_c."),
    pc: float = typer.Option(0.6, "--pc", help="Probability p_c of steering with the goal IK (masr-rrt*)."),
    goal_bias: Optional[float] = typer.Option(
        None, "--goal-bias",
        help="Probability of sampling the goal configuration (default 0.1 for rrt*, 0 for masr-rrt*)."),
    seed: int = typer.Option(0, "--seed", help="Random seed."),
    n_near: int = typer.Option(7, "--neighbours", help="N_n, neighbours for Connect and RewireTree."),
    step: float = typer.Option(16.0, "--step", help="Steer's maximum step delta, in s of eq. (8)."),
    ik: str = typer.Option("auto", "--ik", help="Goal IK: auto (shipped IK-NN, else dls), dls, or a model card."),
    margin: Optional[float] = typer.Option(
        None, "--margin", metavar="MM",
        help="Clearance (mm) every link keeps from every obstacle beyond half its width [default: the "
             "environment's \"margin\" (0 for E1-E3, the paper's check), else the MA's execution bound, "
             "5.25 mm for masr5]; the bound is reported beside the plan's least clearance."),
    png: Optional[Path] = typer.Option(None, "--png", help="Also draw the environment and path to this PNG."),
    json_out: Optional[str] = typer.Option(None, "--json", metavar="FILE|-",
                                           help=JSON_HELP.format(what="the planning summary")),
) -> None:
    """Plan a MASR path (masr paper, Alg. 1-2), write it as a plan file with the MA's actions.

    The summary and the plan report the clearance planned for (margin_mm) and the path's least
    clearance along the motion convention (clearance_min_mm) beside how far the arm can stray from it
    with every joint at the firmware's tolerance (execution_bound_mm; planning/masr/margin.py)."""
    from armbridge.planning.margin import check_margin
    from armbridge.planning.masr import rrt_star
    from armbridge.planning.masr.environment import load_environment
    from armbridge.planning.masr.margin import execution_margin, path_clearance
    from armbridge.planning.masr.plan_file import save_masr_plan

    console = Console()
    if planner not in rrt_star.PLANNERS:
        raise ArmbridgeError(f"unknown planner {planner!r} (known: {', '.join(rrt_star.PLANNERS)})")
    note = compile_note("masr")
    if note is not None:
        console.print(note, style="dim")
    extra = None if margin is None else check_margin(margin / 1000.0, "--margin")
    environment = load_environment(env)
    extra = environment.planning_margin if extra is None else extra
    checker = environment.planning_checker(margin=extra)
    if not bool(checker.free(environment.start)):
        raise ArmbridgeError(f"{environment.name}: the start comes within {extra * 1000:g} mm of an obstacle (the "
                             "clearance margin); plan with a smaller --margin; no plan written")
    p_c = pc if planner == "masr-rrt*" else 0.0
    goal_ik, ik_desc = (None, "none") if p_c == 0 else resolve_goal_ik(environment, ik)
    with console.status(f"{planner}: {iterations} iterations on {environment.name} ..."):
        result = rrt_star.plan(environment, planner=planner, iterations=iterations, goal_ik=goal_ik, p_c=p_c,
                               goal_bias=goal_bias, n_near=n_near, step=step, seed=seed, checker=checker)
    summary = result.summary()
    bound = execution_margin(environment.arm)
    least = path_clearance(environment, result.path) if result.path is not None else None
    summary.update({"environment": environment.name, "ik": ik_desc, "iterations_per_s": iterations / result.time_s,
                    "margin_mm": extra * 1000.0, "clearance_min_mm": None if least is None else least * 1000.0,
                    "execution_bound_mm": bound * 1000.0})
    table = Table(title=f"{planner} on {environment.name}", show_header=False)
    for key in ("success", "cost_s", "waypoints", "first_solution_iteration", "iterations", "time_s",
                "iterations_per_s", "tree_size", "goal_nodes", "ik_calls", "ik", "margin_mm", "clearance_min_mm",
                "execution_bound_mm"):
        v = summary[key]
        table.add_row(key, f"{v:.3f}" if isinstance(v, float) else str(v))
    console.print(table)
    if png is not None:
        from armbridge.planning.figure import draw

        draw(environment, result.path, png, title=f"{environment.name} ({planner})")
        console.print(f"figure: {png}")
    if json_out is not None:
        emit_json(summary, json_out, "the planning summary")
    if result.path is None:
        hint = "more --iterations or another --seed" + (", or a smaller --margin" if extra > 0 else "")
        raise ArmbridgeError(f"{planner} found no path to the goal of {environment.name} in {iterations} iterations "
                             f"(try {hint}); no plan written")
    prov = {"tool": "armbridge plan masr", "planner": planner, "environment": environment.name,
            "environment_file": str(environment.source) if environment.source else None,
            "iterations": iterations, "seed": seed, "p_c": p_c, "goal_bias": result.settings["goal_bias"],
            "n_near": n_near, "step_s": step, "ik": ik_desc, "planning_time_s": round(result.time_s, 4),
            "margin_mm": extra * 1000.0, "clearance_min_mm": round(least * 1000.0, 3) if least is not None else None}
    save_masr_plan(environment, result.path, out, provenance=prov)
    console.print(f"plan: {out} ({result.path.shape[0]} waypoints, tau = {result.cost:.2f} s)")
    if least is not None and least < bound:
        console.print(f"note: the path passes {least * 1000:.1f} mm from an obstacle; with every joint at the "
                      f"firmware's tolerance the arm can stray {bound * 1000:.2f} mm (--margin "
                      f"{bound * 1000:.2f} keeps that clearance)", style="yellow")


plan_app.command("soft")(soft_cmd)  # the soft arm's: planning/soft/command.py
