"""The `armbridge` command line: one program, one subcommand per job.

Each subcommand lives beside the code it drives; this module only wires them
up and turns user-facing errors into one clear line (a traceback only with
--debug).
"""
from __future__ import annotations

import contextlib
import sys

import typer

try:  # typer 0.2x carries its own click (typer._click); older ones use click's
    from typer._click import exceptions as cx
except ImportError:  # pragma: no cover - the pinned typer has it
    from click import exceptions as cx  # type: ignore[no-redef]

from armbridge.errors import ArmbridgeError
from armbridge.jsonfile import json_to_stdout, wants_json_stdout

app = typer.Typer(
    help="Host runtime for research robot arms: emulate boards, run plans, record telemetry.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # Plain help: rich markup would swallow "[default: ...]" in help strings as a
    # style tag and print flags as "<bool>"; this applies to every subcommand.
    rich_markup_mode=None,
)
_debug = False


def version_line() -> str:
    """`armbridge --version`: the package and the protocol it speaks."""
    from armbridge import __version__
    from armbridge.link.protodef import PROTOCOL_VERSION

    return f"armbridge {__version__} (protocol {PROTOCOL_VERSION})"


def _print_version(value: bool) -> None:
    if value:
        typer.echo(version_line())
        raise typer.Exit()


@app.callback()
def _main(
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks on errors."),
    version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                 help="Print the package and protocol versions and exit."),
) -> None:
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
    from armbridge.calibrate.command import calibrate_cmd
    from armbridge.console.command import board_app
    from armbridge.console.ports import ports_cmd
    from armbridge.demo import demo_cmd
    from armbridge.draw.command import draw_cmd
    from armbridge.emulator.command import emulate_cmd
    from armbridge.executor.command import run_cmd
    from armbridge.flash.command import flash_cmd
    from armbridge.planning.command import plan_app
    from armbridge.report.command import report_cmd
    from armbridge.smm.command import smm_cmd
    from armbridge.telemetry.command import view_cmd
    from armbridge.train.command import train_app

    app.command("calibrate")(calibrate_cmd)
    app.command("demo")(demo_cmd)
    app.command("draw")(draw_cmd)
    app.command("emulate")(emulate_cmd)
    app.command("flash")(flash_cmd)
    app.command("ports")(ports_cmd)
    app.command("report")(report_cmd)
    app.command("run")(run_cmd)
    app.command("smm")(smm_cmd)
    app.command("view")(view_cmd)
    app.add_typer(bench_app, name="bench")
    app.add_typer(board_app, name="board")
    app.add_typer(plan_app, name="plan")
    app.add_typer(train_app, name="train")


def _error(line: str) -> None:
    try:
        typer.secho(f"error: {line}", fg="red", err=True)
    except OSError:
        pass  # no terminal left (SIGHUP): the exit code still says it


def usage_line(exc: cx.UsageError) -> str:
    """A usage error as the tool's own errors read: one line, then where the help is
    (click prints four: usage, a hint, a blank line and the error)."""
    path = exc.ctx.command_path if exc.ctx is not None else "armbridge"
    return f"{exc.format_message()} (see '{path} --help')"


def main() -> None:
    """Exit codes (docs/formats.md §7): 0 success; 1 a run or a board request
    failed (BoardFailure: fault, refusal, no answer, busy or lost port); 2 bad
    input or usage (ArmbridgeError, usage errors: one line each); 128 + the
    signal when a stop signal ended the command (130 Ctrl-C)."""
    build_app()
    quiet = json_to_stdout() if wants_json_stdout(sys.argv[1:]) else contextlib.nullcontext()
    try:
        with quiet:  # --json -: stdout carries the JSON alone, the rest goes to stderr
            rv = app(standalone_mode=False)
    except cx.NoArgsIsHelpError as exc:  # a bare group: its help, as click prints it
        typer.echo(exc.ctx.get_help() if exc.ctx is not None else exc.format_message())
        sys.exit(2)
    except cx.UsageError as exc:
        _error(usage_line(exc))
        sys.exit(2)
    except typer.Abort as exc:  # Ctrl-C or end of input at a prompt
        sys.exit(130 if isinstance(exc.__cause__, KeyboardInterrupt) else 1)
    except cx.ClickException as exc:  # click's own file errors and the like
        _error(exc.format_message())
        sys.exit(exc.exit_code)
    except ArmbridgeError as exc:
        if _debug:
            raise
        _error(str(exc))
        sys.exit(getattr(exc, "exit_code", 2))
    sys.exit(rv if isinstance(rv, int) else 0)
