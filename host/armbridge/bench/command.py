"""`armbridge bench`: the app that holds the benches, and what their commands share.

Each bench defines its command next to the code it measures (`link.py` holds
`armbridge bench link`, `wjrrt_plots.py`, above `wjrrt.py`, holds `armbridge
bench wjrrt` and its figures); `COMMANDS` maps the command's name to that
module and function, imported only when the bench runs or its help is shown
(`armbridge bench --help` lists them all), so `armbridge --help` imports no
bench (numpy, the executor, the emulator, the IK). A new bench is its module
and one line here, as a demo is in `demos/__init__.py`.
"""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

import typer
from typer.core import TyperGroup

from armbridge.jsonfile import emit_json

#: command name -> "module:function" of its command.
COMMANDS: dict[str, str] = {
    "link": "armbridge.bench.link:link_cmd",
    "masr-ik": "armbridge.bench.masr_ik:masr_ik_cmd",
    "masr-plan": "armbridge.bench.masr_plan:masr_plan_cmd",
    "masr-exec": "armbridge.bench.masr_exec:masr_exec_cmd",
    "soft-exec": "armbridge.bench.soft_exec:soft_exec_cmd",
    "arm3r-servo": "armbridge.bench.arm3r_servo:arm3r_servo_cmd",
    "smm": "armbridge.bench.smm:smm_cmd",
    "smm-data": "armbridge.bench.smm_data:smm_data_cmd",
    "firmware": "armbridge.bench.firmware_cost:firmware_cmd",
    "arm3r": "armbridge.bench.arm3r:arm3r_cmd",
    "board-ik": "armbridge.bench.board_ik:board_ik_cmd",
    "wjrrt": "armbridge.bench.wjrrt_plots:wjrrt_cmd",
    "shards": "armbridge.bench.shards:shards_cmd",
    "load": "armbridge.bench.load:load_cmd",
}


class _Benches(TyperGroup):
    """The `bench` group: a bench's command is built from its module on first use."""

    def list_commands(self, ctx: Any) -> list[str]:  # ctx: click's Context (typer's own copy of click in 0.2x)
        return list(COMMANDS)

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        if cmd_name not in self.commands and cmd_name in COMMANDS:
            module, function = COMMANDS[cmd_name].split(":")
            one = typer.Typer(add_completion=False, rich_markup_mode=self.rich_markup_mode)
            one.command(cmd_name)(getattr(importlib.import_module(module), function))
            self.commands[cmd_name] = typer.main.get_command(one)
        return self.commands.get(cmd_name)


bench_app = typer.Typer(cls=_Benches, help="Measure the numbers in docs/benchmarks.md; each writes JSON.",
                        no_args_is_help=True)


@bench_app.callback()
def _benches() -> None:
    """(a group even when invoked on its own, as the tests do: its commands come from COMMANDS)"""


def write_json(result: dict, path: Path | str) -> None:
    """A bench's results to `--json` (a file, or '-': stdout, jsonfile.emit_json)."""
    emit_json(result, path, "the results")
