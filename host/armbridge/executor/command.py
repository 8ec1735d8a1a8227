"""`armbridge run PLAN --port PORT`: run a plan file on a board and summarise the run.

Exit codes (docs/formats.md §7): 0 the plan completed; 1 the run failed (a
board fault or refusal, no answer, a busy or lost port); 2 bad input or usage
(nothing was sent); 128 + the signal when stopped by one (130 Ctrl-C, 143
SIGTERM, 129 SIGHUP), after the e-stop byte. The summary (table, and the
`--json` file) is written for every run that got as far as trying the port.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console

from armbridge.executor.estop import estop_note
from armbridge.executor.penpos import pen_pos_options
from armbridge.executor.run import RATE_MAX, RATE_MIN, RunFailed, Summary, run_plan
from armbridge.executor.signals import Stopped, holding, stop_on_signals
from armbridge.jsonfile import JSON_HELP, detach, emit_json
from armbridge.link.ports import auto_port


CARTESIAN_HELP = ("Send Cartesian waypoints (X x y theta, from the plan by FK) and let the board solve its own IK "
                  "(the 3R arm's int8 net + FABRIK).")
KEYS_HELP = ("At a terminal, space or p holds the arm where it is (the protocol's HOLD) and resumes it (RESUME); "
             "the plan's timeout does not count while held, and Ctrl-C still e-stops. --no-keys: the keyboard is "
             "left alone.")
PEN_HELP = ("Plans with pen flags: 'auto' drives the board's pen-lift servo when it has one, 'on' requires one, "
            "'off' never sends PEN (pen-up moves only marked).")
PEN_UP_HELP = "The pen servo's pulse width for pen up, us (500..2500) [default: the firmware's, 1200]."
PEN_DOWN_HELP = ("The pen servo's pulse width for pen down, us (500..2500) [default: the firmware's, 1700]; "
                 "one that does not reach the paper draws nothing.")
PEN_WAIT_HELP = "The board's dwell after every pen change, ms (0..2000) [default: the firmware's, 150]."
PEN_POS_NOTE = " Sent as one PENPOS before the first waypoint; over a drawing plan's own."


def run_cmd(
    plan: Path = typer.Argument(..., help="Plan file: armbridge-plan JSON, or an armbridge-masr-plan (its actions "
                                          "run on the MASR actuator), see docs/formats.md."),
    port: str = typer.Option(..., "--port", "-p", envvar="ARMBRIDGE_PORT", callback=auto_port,
                             help="Serial device, pyserial URL (socket://, rfc2217://, loop://), emu:DEVICE or auto "
                                  "(the one board plugged in: armbridge ports) (env ARMBRIDGE_PORT)."),
    rrd: Optional[Path] = typer.Option(None, "--rrd", help="Recording to write [default: runs/<time>-<plan>.rrd]."),
    rate: int = typer.Option(50, "--rate", help=f"Telemetry rate in Hz ({RATE_MIN}..{RATE_MAX})."),
    json_out: Optional[str] = typer.Option(None, "--json", metavar="FILE|-",
                                           help=JSON_HELP.format(what="the summary")),
    clear: bool = typer.Option(False, "--clear", help="Clear a latched ESTOP/WDOG/FAULT on the board first."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show a progress bar."),
    cartesian: bool = typer.Option(False, "--cartesian", help=CARTESIAN_HELP),
    pen: str = typer.Option("auto", "--pen", metavar="auto|on|off", help=PEN_HELP),
    home: bool = typer.Option(False, "--home", help="MASR plans: HOME first (the mobile actuator drives to the base "
                                                    "and zeroes d; a board just powered on does not know where it is), "
                                                    "then every joint and d to the plan's start; the executed time "
                                                    "counts from there."),
    no_cal_check: bool = typer.Option(False, "--no-calibration-check",
                                      help="Run on a board whose calibration is not the one this host made for it "
                                           "(docs/calibration.md)."),
    keys: bool = typer.Option(True, "--keys/--no-keys", help=KEYS_HELP),
    pen_up: Optional[int] = typer.Option(None, "--pen-up", metavar="US", help=PEN_UP_HELP + PEN_POS_NOTE),
    pen_down: Optional[int] = typer.Option(None, "--pen-down", metavar="US", help=PEN_DOWN_HELP),
    pen_wait: Optional[int] = typer.Option(None, "--pen-wait", metavar="MS", help=PEN_WAIT_HELP),
) -> None:
    """Validate a plan, stream it to the board, record telemetry to Rerun, print a summary.

    Exit codes: 0 completed, 1 run failed, 2 bad input, 128+signal when stopped (130 Ctrl-C).
    """
    pen_pos = pen_pos_options(pen_up, pen_down, pen_wait)  # bad values: one line, before any port opens
    run_command(plan, port, rrd, rate, json_out, clear, progress, cartesian=cartesian, pen=pen, home=home,
                calibration="ignore" if no_cal_check else "check", keys=keys, pen_pos=pen_pos)


def run_command(plan, port, rrd, rate, json_out, clear, progress, *, cartesian=False, pen="auto",
                home=False, goal_exit=True, calibration="check", keys=True, pen_pos=None) -> Summary:
    """What `armbridge run` does with its options (also `armbridge draw --port`, the demos); the
    Summary of a completed run (any other outcome exits with its code). `keys`: space or p
    holds and resumes the arm while the plan streams, when stdin is a terminal."""
    # With --json - stdout carries the JSON alone; the table and the bar go to stderr.
    console = Console(stderr=json_out == "-")
    try:
        with stop_on_signals():
            return run_and_report(plan, port, rrd, rate, json_out, clear, progress, console, cartesian=cartesian,
                                  pen=pen, home=home, goal_exit=goal_exit, calibration=calibration, keys=keys,
                                  pen_pos=pen_pos)
    except Stopped as stop:  # before the run started, or while its files were written
        raise typer.Exit(stop.exit_code) from None


def run_and_report(plan, port, rrd, rate, json_out, clear, progress, console, *, cartesian=False,
                   pen="auto", home=False, goal_exit=True, calibration="check", keys=False,
                   pen_pos=None) -> Summary:
    """run_plan, then what `armbridge run` reports: the JSON summary, the table
    and the exit code (1: the run failed, 3: it completed with the arm outside the
    plan's goal, unless `goal_exit` is False (the caller reports it), 128 + n: stopped
    by signal n); returns the Summary of a completed run."""
    failed: RunFailed | None = None
    try:
        summary = run_plan(plan, port, rrd, rate_hz=rate, progress=progress, clear=clear, console=console,
                           cartesian=cartesian, pen=pen, home=home, calibration=calibration, pause_keys=keys,
                           pen_pos=pen_pos)
    except RunFailed as exc:
        failed, summary = exc, exc.summary
    with holding():
        if json_out is not None:
            write_summary(summary, json_out)
        if failed is None or summary.reached_board:  # a run that never reached a board: its error line alone
            _print(console, summary.table())
        if failed is not None:
            _say(f"error: {failed}", "red")
            raise typer.Exit(1)
        if summary.stopped_by_user:
            _say(f"stopped by {summary.stopped_by or 'SIGINT'}, {estop_note(summary)}", "yellow")
            raise typer.Exit(128 + _signum(summary.stopped_by))
        if not summary.completed:
            raise typer.Exit(1)
        if summary.goal_missed and goal_exit:
            _say(f"error: {goal_missed_text(summary)}", "red")
            raise typer.Exit(GOAL_MISSED)
    return summary


GOAL_MISSED = 3  # the exit code of a run that completed with the arm outside the plan's goal (formats.md §7)


def goal_missed_text(summary: Summary) -> str:
    g = summary.goal or {}
    return (f"the plan ran to its end but the {g.get('what', 'arm')} ended {g.get('distance_mm', float('nan')):.1f} mm "
            f"from the goal (tolerance {g.get('tolerance_mm', float('nan')):.1f} mm)")


def write_summary(summary: Summary, target: str) -> None:
    """The JSON summary to a file ('-': stdout), written whole (a temporary file renamed)."""
    emit_json(summary.to_dict(), target, "the summary")


def _signum(name: str | None) -> int:
    import signal

    try:
        return int(signal.Signals[name or "SIGINT"])
    except KeyError:
        return int(signal.SIGINT)


def _print(console: Console, renderable) -> None:
    """Print, unless the terminal is gone (SIGHUP): the files are what counts then."""
    try:
        console.print(renderable)
    except OSError:
        detach(sys.stdout)


def _say(text: str, colour: str) -> None:
    try:
        typer.secho(text, fg=colour, err=True)
    except OSError:
        pass

