"""`armbridge demo`: draw a square with the emulated ESP32 3R arm.

Plan (closed-form IK along a square) -> plan file -> executor -> the real
firmware in the emulator over a pty -> Rerun recording and a run summary.
`--fault-tolerant` runs the locked-joint scenario of armbridge.smm.ft_demo instead.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from armbridge.ik.analytic3r import solve_path
from armbridge.plans.format import Plan, make_plan, save_plan
from armbridge.plans.shapes import segment_durations, square
from armbridge.robots.catalog import get_robot
from armbridge.robots.planar import PlanarChain

# A 10 cm square well inside the arm3r workspace: every pose keeps at least
# 0.87 rad from every joint limit with the pen held at 15 degrees.
SQUARE_CENTER = (0.15, 0.20)
SQUARE_SIDE = 0.10
PEN_ANGLE = np.pi / 12
APPROACH_S = 2.0  # the first waypoint starts wherever the arm is


def square_plan(robot: PlanarChain, center=SQUARE_CENTER, side=SQUARE_SIDE, phi=PEN_ANGLE,
                step=0.005, speed=0.04) -> Plan:
    """Joint waypoints every `step` m along a square, traced at `speed` m/s."""
    points = square(center, side, step)
    poses = np.column_stack([points, np.full(len(points), phi)])
    q = solve_path(robot, poses, q0=(robot.q_min + robot.q_max) / 2)
    durations = np.concatenate([[APPROACH_S], segment_durations(points, speed)])
    provenance = {"tool": "armbridge demo", "name": "demo-square", "shape": "square", "center_m": list(center),
                  "side_m": side, "pen_angle_rad": phi, "tip_speed_m_s": speed, "ik": "analytic3r"}
    return make_plan(robot, q, durations, provenance)


def demo_cmd(
    port: str = typer.Option("emu:esp32", help="Board to run on: emu:esp32 (built-in emulator), a serial device or a pyserial URL."),
    rrd: Path = typer.Option(None, help="Rerun recording to write (default: runs/<time>-demo-square.rrd)."),
    write_plan: Path = typer.Option(None, "--write-plan", help="Only write the square plan to this file and exit."),
    robot: str = typer.Option("arm3r", help="Robot to run: arm3r (the only one so far)."),
    fault_tolerant: bool = typer.Option(
        False, "--fault-tolerant",
        help="Instead of the square: a target appears, a joint stalls on the way, and the arm still reaches it "
             "(SMM bounding boxes, Clark and Xie Fig. 15). Needs an emu: port.",
    ),
    seed: int = typer.Option(0, help="Seed of the fault-tolerant scenario (target, stalled joint)."),
    smm: str = typer.Option("learned", help="SMMs for --fault-tolerant: learned (ms, the shipped model) or "
                                            "nullspace (the slow ground truth; the arm waits longer)."),
) -> None:
    """Draw a square with the 3R arm on the emulated ESP32 (or, with --fault-tolerant, reach a target
    despite a joint that stalls on the way) and record it to Rerun."""
    from rich.console import Console

    from armbridge.errors import ArmbridgeError
    from armbridge.executor.run import run_plan

    if robot.lower() != "arm3r":
        raise ArmbridgeError(f"--robot {robot!r}: the demo runs on arm3r only so far")
    console = Console()
    if fault_tolerant:
        from armbridge.smm.ft_demo import run_ft_demo, smm_method

        if write_plan is not None:
            raise ArmbridgeError("--write-plan writes the square plan; it does not go with --fault-tolerant")
        result = run_ft_demo(port, rrd, seed, smm_method(smm), console=console)
        console.print(result.table())
        console.print(f"recording: {result.rrd}   view it with: armbridge view {result.rrd}")
        if not result.reached:
            raise ArmbridgeError("the fault-tolerant demo did not reach its target (see the table above)")
        return
    plan = square_plan(get_robot("arm3r"))
    if write_plan is not None:
        save_plan(plan, write_plan)
        console.print(f"wrote {write_plan} ({plan.k} waypoints, {plan.total_duration:.1f} s)")
        return
    console.print(f"demo: drawing a {SQUARE_SIDE * 100:.0f} cm square, {plan.k} waypoints, "
                  f"{plan.total_duration:.1f} s planned, on {port}")
    summary = run_plan(plan, port, rrd)
    console.print(summary.table())
    console.print(f"recording: {summary.rrd}   view it with: armbridge view {summary.rrd}")
