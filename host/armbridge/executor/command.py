"""`armbridge run PLAN --port PORT`: run a plan file on a board and summarise the run."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console

from armbridge.errors import ArmbridgeError
from armbridge.executor.run import RATE_MAX, RATE_MIN, run_plan


def run_cmd(
    plan: Path = typer.Argument(..., help="Plan file (armbridge-plan JSON, see docs/formats.md)."),
    port: str = typer.Option(..., "--port", help="Serial device, pyserial URL (socket://, loop://) or emu:DEVICE."),
    rrd: Optional[Path] = typer.Option(None, "--rrd", help="Recording to write [default: runs/<time>-<plan>.rrd]."),
    rate: int = typer.Option(50, "--rate", help=f"Telemetry rate in Hz ({RATE_MIN}..{RATE_MAX})."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Also write the summary as JSON to this file."),
    clear: bool = typer.Option(False, "--clear", help="Clear a latched ESTOP/WDOG/FAULT on the board first."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show a progress bar."),
) -> None:
    """Validate a plan, stream it to the board, record telemetry to Rerun, print a summary."""
    console = Console()
    summary = run_plan(plan, port, rrd, rate_hz=rate, progress=progress, clear=clear, console=console)
    console.print(summary.table())
    if json_out is not None:
        try:
            json_out.parent.mkdir(parents=True, exist_ok=True)
            json_out.write_text(json.dumps(summary.to_dict(), indent=2) + "\n")
        except OSError as exc:
            raise ArmbridgeError(f"{json_out}: cannot write the summary: {exc.strerror}") from None
    if summary.stopped_by_user:
        typer.secho("stopped by user, e-stop sent", fg="yellow", err=True)
        raise typer.Exit(130)
