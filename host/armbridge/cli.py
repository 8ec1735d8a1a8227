"""The `armbridge` command line: one program, one subcommand per job.

Each subcommand lives beside the code it drives; this module only wires them
up and turns user-facing errors into one clear line (a traceback only with
--debug).
"""
from __future__ import annotations

import sys

import typer

from armbridge.errors import ArmbridgeError

app = typer.Typer(
    help="Host runtime for research robot arms: emulate boards, run plans, record telemetry.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
_debug = False


@app.callback()
def _main(debug: bool = typer.Option(False, "--debug", help="Show tracebacks on errors.")) -> None:
    global _debug
    _debug = debug


_registered = False


def build_app() -> typer.Typer:
    """The app with every subcommand (imported on first use: keeps start-up fast)."""
    global _registered
    if not _registered:
        _register()
        _registered = True
    return app


def _register() -> None:
    from armbridge.bench.command import bench_app
    from armbridge.demo import demo_cmd
    from armbridge.emulator.command import emulate_cmd
    from armbridge.executor.command import run_cmd
    from armbridge.planning.command import plan_app
    from armbridge.smm.command import smm_cmd
    from armbridge.telemetry.command import view_cmd
    from armbridge.train.command import train_app

    app.command("demo")(demo_cmd)
    app.command("emulate")(emulate_cmd)
    app.command("run")(run_cmd)
    app.command("smm")(smm_cmd)
    app.command("view")(view_cmd)
    app.add_typer(bench_app, name="bench")
    app.add_typer(plan_app, name="plan")
    app.add_typer(train_app, name="train")


def main() -> None:
    build_app()
    try:
        app()  # standalone: typer reports usage errors itself and exits
    except ArmbridgeError as exc:
        if _debug:
            raise
        typer.secho(f"error: {exc}", fg="red", err=True)
        sys.exit(2)
