"""`armbridge calibrate BOARD --port URL`: the CLI of calibrate/base.py's flow."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from armbridge.calibrate.base import PROCEDURES, calibrate_board
from armbridge.errors import ArmbridgeError
from armbridge.jsonfile import JSON_HELP, emit_json
from armbridge.link.ports import auto_port


def calibrate_cmd(
    board: str = typer.Argument(..., help=f"The board: {', '.join(sorted(PROCEDURES))}."),
    port: str = typer.Option(..., "--port", "-p", envvar="ARMBRIDGE_PORT", callback=auto_port,
                             help="Serial device, pyserial URL or emu:BOARD (emu:BOARD?plant=random&seed=N: a board "
                                  "of hidden physical truth) (env ARMBRIDGE_PORT)."),
    only: Optional[list[str]] = typer.Option(None, "--only", metavar="STEP",
                                             help="Run only this step (repeatable); the others' settings are kept "
                                                  "from this host's earlier calibration of the board."),
    cal_dir: Optional[Path] = typer.Option(None, "--dir", help="Where the host's calibration files are "
                                                                "[default: $ARMBRIDGE_CALIBRATION_DIR, else "
                                                                "~/.config/armbridge/calibration]."),
    jig: Optional[str] = typer.Option(None, "--jig", metavar="terminal|emu",
                                      help="esp32: who puts the pen on the printed marks of the jig step: terminal "
                                           "(you, jogging with keys), emu (the emulated user of an emu: board). "
                                           "Without it that step is skipped."),
    jig_sheet: Optional[Path] = typer.Option(None, "--jig-sheet", metavar="FILE",
                                             help="esp32: also write the jig's marks as an SVG to print at 1:1."),
    firmware: Optional[Path] = typer.Option(None, "--firmware", metavar="DIR",
                                            help="The firmware tree the board was flashed from (as flash's "
                                                 "--firmware), whose config the procedure reads [default: the "
                                                 "shipped firmware]."),
    json_out: Optional[str] = typer.Option(None, "--json", metavar="FILE|-",
                                           help=JSON_HELP.format(what="what was found")),
) -> None:
    """Measure a board from its own sensors, set and persist what was found (on the board, CALID,
    and in a host file that later runs check the board against). docs/calibration.md.

    Steps: esp32: gains, jig; masr_ma: magnets, wheel, gains; arduino_pump: bend, gains.

    Exit codes: 0 calibrated, 1 the board failed or refused, 2 bad input."""
    console = Console(stderr=json_out == "-")
    if jig_sheet is not None:
        from armbridge.calibrate.jig import sheet_svg

        try:
            jig_sheet.write_text(sheet_svg())
        except OSError as exc:
            raise ArmbridgeError(f"{jig_sheet}: cannot write the jig sheet: {exc.strerror}") from None
    if jig == "terminal":  # the user answers at the keys: no spinner over the prompts
        report = calibrate_board(port, board, only=only, cal_dir=cal_dir, jig=jig, firmware=firmware)
    else:
        with console.status(f"calibrating the {board} board on {port} ..."):
            report = calibrate_board(port, board, only=only, cal_dir=cal_dir, jig=jig, firmware=firmware)
    if json_out is not None:
        emit_json(report.to_json(), json_out, "the calibration report")
    t = Table(title=f"{board} {report.uid}: calibration {report.id}", show_header=False)
    t.add_column("", style="bold")
    t.add_column("")
    for line in report.found.lines:
        what, _, value = line.partition(": ")
        t.add_row(what, value)
    t.add_row("saved on the board", f"CALID {report.id}")
    t.add_row("host file", report.path)
    console.print(t)
