"""`armbridge report RUN.rrd [--png FILE] [--html FILE] [--json FILE|-]`: a run's picture and numbers,
made from its recording alone (docs/report.md)."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from armbridge.errors import ArmbridgeError
from armbridge.jsonfile import JSON_HELP, emit_json


def _write(path: Path, data: bytes | str, what: str) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, str):
            path.write_text(data, encoding="utf-8")
        else:
            path.write_bytes(data)
    except OSError as exc:
        raise ArmbridgeError(f"{path}: cannot write the {what}: {exc.strerror}") from None


def make_report(rrd: Path, png: Path | None = None, html: Path | None = None,
                json_out: str | None = None) -> dict:
    """Read the recording, write what was asked for; -> the report's numbers (report/numbers.py)."""
    from armbridge.report.data import load
    from armbridge.report.numbers import numbers

    data = load(rrd)
    doc = numbers(data)
    if png is not None or html is not None:
        from armbridge.report.figure import figure, png_bytes

        fig = figure(data, doc)
        try:
            image = png_bytes(fig)
        finally:
            import matplotlib.pyplot as plt

            plt.close(fig)
        if png is not None:
            _write(png, image, "picture")
        if html is not None:
            from armbridge.report.page import page

            _write(html, page(data, doc, image), "page")
    if json_out is not None:
        emit_json(doc, json_out, "the report's numbers")
    return doc


def report_cmd(
    file: Path = typer.Argument(..., help="A recording (.rrd) written by `armbridge run` or `armbridge demo`."),
    png: Optional[Path] = typer.Option(None, "--png", metavar="FILE",
                                       help="Write the report's picture (plan vs executed, joints, numbers, "
                                            "events) as a PNG."),
    html: Optional[Path] = typer.Option(None, "--html", metavar="FILE",
                                        help="Write the report as one self-contained HTML page (the picture "
                                             "inlined, the numbers, every event)."),
    json_out: Optional[str] = typer.Option(None, "--json", metavar="FILE|-",
                                           help=JSON_HELP.format(what="the report's numbers (the run's summary "
                                                                      "among them)")),
) -> None:
    """Show a run from its recording alone: the plan against what was executed, the joints'
    set points and measured values, link statistics, events and faults, and the run's summary."""
    doc = make_report(file, png, html, json_out)
    from rich.console import Console
    from rich.table import Table

    from armbridge.report.numbers import summary_rows

    console = Console()
    table = Table(title=f"report of {file}", show_header=False)
    table.add_column("", style="bold")
    table.add_column("value", justify="right")
    for a, b in summary_rows(doc):
        table.add_row(a, b)
    console.print(table)
    for m in doc["missing"]:
        console.print(f"[yellow]not in this recording:[/yellow] {m}", highlight=False)
    for what, path in (("picture", png), ("page", html)):
        if path is not None:
            console.print(f"{what}: {path}", highlight=False)
    if png is None and html is None and json_out is None:
        console.print("(--png FILE, --html FILE or --json FILE|- write the report)", highlight=False)
