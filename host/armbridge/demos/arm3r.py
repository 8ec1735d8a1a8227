"""The arm3r demo: draw a square with the emulated ESP32 3R arm (`--fault-tolerant`: arm3r_ft).

Plan (closed-form IK along a square) -> plan file -> executor (`run_plan`,
which opens the session with `open_session`: a latched board is refused
unless `--clear`) -> the real firmware in the emulator over a pty -> Rerun
recording and a run summary, with the exit codes of `armbridge run`.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from armbridge.demos import Demo, DemoOptions
from armbridge.errors import ArmbridgeError
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


def run(opts: DemoOptions, console: Any) -> None:
    """The square, or (opts.fault_tolerant) the locked-joint scenario of arm3r_ft."""
    if opts.fault_tolerant:
        from armbridge.demos.arm3r_ft import run_cli

        if opts.write_plan is not None:
            raise ArmbridgeError("--write-plan writes the square plan; it does not go with --fault-tolerant")
        run_cli(opts, console)
        return
    plan = square_plan(get_robot("arm3r"))
    if opts.write_plan is not None:
        save_plan(plan, opts.write_plan)
        console.print(f"wrote {opts.write_plan} ({plan.k} waypoints, {plan.total_duration:.1f} s)")
        return
    from armbridge.executor.command import run_command

    console.print(f"demo: drawing a {SQUARE_SIDE * 100:.0f} cm square, {plan.k} waypoints, "
                  f"{plan.total_duration:.1f} s planned, on {opts.port}")
    # `armbridge run`'s own reporting: the table, the e-stop on every signal, its exit codes.
    run_command(plan, opts.port, opts.rrd, 50, opts.json_out, opts.clear, True)


DEMO = Demo(robot="arm3r", summary="arm3r: draw a 10 cm square (--fault-tolerant: reach a target despite a "
                                   "joint that stalls on the way)", run=run, fault_tolerant=True)
