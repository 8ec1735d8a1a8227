"""The MASR demo: plan in a built-in environment, execute the plan on the emulated MA.

MASR-RRT* (`planning.masr.rrt_star`, the shipped IK-NN as its goal IK) plans in E1 of
the masr paper (Fig. 6), the plan is written as an armbridge-masr-plan file,
and `armbridge run`'s own run_command executes its actions (MV / ROT) on the
MA's firmware in the emulator (`emu:masr_ma`): the recording draws the arm,
the MA and the obstacles, and the summary reports the MA's final pose error
against the goal and the executed action time against the planned tau.
"""
from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from armbridge.demos import Demo, DemoOptions

ENV = "E1"
ITERATIONS = 600


def run(opts: DemoOptions, console: Any) -> None:
    from armbridge.executor.command import run_command
    from armbridge.planning.command import resolve_goal_ik
    from armbridge.planning.masr.environment import load_environment
    from armbridge.planning.masr.plan_file import save_masr_plan
    from armbridge.planning.base import compile_note
    from armbridge.planning.masr.rrt_star import plan as plan_rrt

    note = compile_note("masr")
    if note is not None:
        console.print(f"demo: {note}")
    env = load_environment(ENV)
    goal_ik, ik = resolve_goal_ik(env)
    console.print(f"demo: MASR-RRT* in {ENV} ({ITERATIONS} iterations, seed {opts.seed}, goal IK: {ik})")
    result = plan_rrt(env, iterations=ITERATIONS, goal_ik=goal_ik, seed=opts.seed)
    path = result.path
    if path is None:
        from armbridge.errors import ArmbridgeError

        raise ArmbridgeError(f"MASR-RRT* found no path in {ENV} in {ITERATIONS} iterations (seed {opts.seed}); "
                             "try another --seed")
    provenance = {"tool": "armbridge demo", "planner": "masr-rrt*", "seed": opts.seed, "iterations": ITERATIONS}
    if opts.write_plan is not None:
        save_masr_plan(env, path, opts.write_plan, provenance)
        console.print(f"wrote {opts.write_plan}")
        return
    with tempfile.TemporaryDirectory() as tmp:
        out = save_masr_plan(env, path, Path(tmp) / f"demo-masr-{ENV}.json", provenance)
        console.print(f"demo: {len(path)} waypoints, tau = {result.cost:.1f} s planned; running on {opts.port}")
        run_command(out, opts.port, opts.rrd, 50, opts.json_out, opts.clear, True, home=True)  # a fresh MA is unhomed


DEMO = Demo(robot="masr5", summary=f"masr5: plan in {ENV} with MASR-RRT* and run it on the emulated mobile actuator",
            run=run, aliases=("masr",))
