"""`armbridge demo`: the CLI front of the demo registry (armbridge.demos), one demo per robot.

Defaults: the arm3r square on the emulated ESP32 (`emu:esp32`); each robot's
demo runs on its own emulated board unless --port names another.
"""
from __future__ import annotations

from pathlib import Path

import typer

from armbridge.demos import DemoOptions, default_port, names, run_demo
from armbridge.jsonfile import JSON_HELP
from armbridge.link.ports import auto_port


def demo_cmd(
    robot: str = typer.Option("arm3r", help=f"Robot whose demo runs: {', '.join(names())}."),
    port: str = typer.Option(None, "--port", "-p", envvar="ARMBRIDGE_PORT", callback=auto_port,
                             help="Board to run on [default: the robot's emulated board: emu:esp32 for arm3r, "
                                  "emu:masr_ma for masr5, emu:arduino_pump for soft3], a serial device, a pyserial "
                                  "URL or auto (the one board plugged in) (env ARMBRIDGE_PORT)."),
    rrd: Path = typer.Option(None, help="Rerun recording to write [default: runs/<time>-<plan>.rrd]."),
    write_plan: Path = typer.Option(None, "--write-plan", help="Only write the demo's plan to this file and exit."),
    fault_tolerant: bool = typer.Option(
        False, "--fault-tolerant",
        help="arm3r: instead of the square, a target appears, a joint stalls on the way, and the arm still "
             "reaches it (SMM bounding boxes, Clark and Xie Fig. 15). Needs an emu: port.",
    ),
    seed: int = typer.Option(0, help="Seed of the planner (masr5, soft3) or of the fault-tolerant scenario "
                                     "(target, stalled joint)."),
    smm: str = typer.Option("learned", help="SMMs for --fault-tolerant: learned (ms, the shipped model) or "
                                            "nullspace (the slow ground truth; the arm waits longer)."),
    clear: bool = typer.Option(False, "--clear", help="Clear a board latched (ESTOP/WDOG/FAULT) from before; "
                                                      "without it a latched board is refused."),
    json_out: str = typer.Option(None, "--json", metavar="FILE|-",
                                 help=JSON_HELP.format(what="the run's summary") + " (as armbridge run; docs/formats.md)"),
) -> None:
    """Run a robot's demo on the emulated board and record it to Rerun (arm3r: draw a square, or with
    --fault-tolerant reach a target despite a joint that stalls on the way)."""
    opts = DemoOptions(port=port or default_port(robot), rrd=rrd, write_plan=write_plan, fault_tolerant=fault_tolerant, seed=seed,
                       smm=smm, clear=clear, json_out=json_out)
    run_demo(opts, robot)
