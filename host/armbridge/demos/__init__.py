"""The demos, one per robot, behind `armbridge demo --robot NAME`.

Each demo is one module that defines `DEMO = Demo(...)`; `MODULES` maps the
robot's registry name to that module, imported only when its demo runs (so
`armbridge demo --help` imports no demo). A new robot's demo (the MASR, the
soft arm) is one new file and one line here.

Every demo that moves a board opens its session through
`armbridge.executor.session.open_session` (directly, or through `run_plan`):
a board latched from before is refused unless the user passed `--clear`.
"""
from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from armbridge.errors import ArmbridgeError

#: robot name -> the module whose DEMO runs it.
MODULES: dict[str, str] = {
    "arm3r": "armbridge.demos.arm3r",
    "masr5": "armbridge.demos.masr",
    "masr": "armbridge.demos.masr",  # the MASR's demo by its kind
    "soft3": "armbridge.demos.soft",
    "soft": "armbridge.demos.soft",  # the soft arm's demo by its kind
}

#: robot name -> the port its demo runs on by default (its emulated board).
PORTS: dict[str, str] = {"arm3r": "emu:esp32", "masr5": "emu:masr_ma", "masr": "emu:masr_ma",
                         "soft3": "emu:arduino_pump", "soft": "emu:arduino_pump"}


def default_port(robot: str) -> str:
    """The emulated board a robot's demo runs on unless --port names another."""
    return PORTS.get(str(robot).lower(), "emu:esp32")


@dataclass(frozen=True)
class DemoOptions:
    """What the user asked for on the command line."""

    port: str = "emu:esp32"
    rrd: Path | None = None
    write_plan: Path | None = None  # only write the demo's plan file
    fault_tolerant: bool = False
    seed: int = 0
    smm: str = "learned"
    clear: bool = False  # clear a board latched from before (else it is refused)
    json_out: str | None = None  # the run's JSON summary: a file, or "-" for stdout (as `armbridge run --json`)


@dataclass(frozen=True)
class Demo:
    """One robot's demo: `run(options, console)` raises ArmbridgeError (or typer.Exit) on failure."""

    robot: str
    summary: str  # one line for `armbridge demo --help`
    run: Callable[[DemoOptions, Any], None]
    fault_tolerant: bool = False  # has a --fault-tolerant variant
    aliases: tuple[str, ...] = ()  # other --robot names for it (the MASR's "masr")


def names() -> list[str]:
    """The robots that have a demo."""
    return sorted(MODULES)


def get_demo(robot: str) -> Demo:
    """The demo of the robot called `robot` (case-insensitive)."""
    module = MODULES.get(robot.lower()) if isinstance(robot, str) else None
    if module is None:
        raise ArmbridgeError(f"--robot {robot!r}: no demo for that robot; demos: {', '.join(names())}")
    demo = importlib.import_module(module).DEMO
    assert isinstance(demo, Demo) and robot.lower() in (demo.robot, *demo.aliases), module
    return demo


def run_demo(options: DemoOptions, robot: str = "arm3r", console: Any = None) -> None:
    """Run the demo of `robot` with `options` (the CLI's entry point)."""
    demo = get_demo(robot)
    if options.fault_tolerant and not demo.fault_tolerant:
        raise ArmbridgeError(f"--fault-tolerant: the {demo.robot} demo has no fault-tolerant variant")
    if options.fault_tolerant and options.json_out is not None:
        raise ArmbridgeError("--json: the fault-tolerant demo has no run summary to write")
    if console is None:
        from rich.console import Console

        console = Console(stderr=options.json_out == "-")  # with --json - stdout carries the JSON alone
    demo.run(options, console)
