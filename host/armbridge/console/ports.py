"""`armbridge ports`: the serial ports that may hold one of our boards (link/ports.py),
as `mpremote devs` and `esptool` list them; `--port auto` takes the one it finds."""
from __future__ import annotations

from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from armbridge.jsonfile import JSON_HELP, emit_json
from armbridge.link.ports import FAMILIES, scan


def ports_cmd(
    everything: bool = typer.Option(False, "--all", "-a", help="List every serial port, not only those with a known "
                                                               "board bridge."),
    json_out: Optional[str] = typer.Option(None, "--json", metavar="FILE|-", help=JSON_HELP.format(what="the list")),
) -> None:
    """Serial ports with a USB bridge our boards use (CP210x, CH340/CH9102, FTDI, the Mega's and the
    ESP32-S3's own USB): device, USB id, bridge, boards usually behind it. `--port auto` picks the
    one listed here; with none or several it says so."""
    found = scan(everything=everything)
    if json_out is not None:
        emit_json([p.to_json() for p in found], json_out, "the list")
        if json_out == "-":
            return
    out = Console()
    if not found:
        out.print("no serial port" + ("" if everything else f" with a known board bridge ({FAMILIES}); "
                                      "--all lists every port"), highlight=False)
        return
    t = Table(title="serial ports" + ("" if everything else " with a board bridge"))
    for col in ("device", "USB id", "bridge", "usually", "description", "serial"):
        t.add_column(col)
    for p in found:
        t.add_row(p.device, p.usb_id or "-", p.bridge or "-", p.boards or "-", p.description or "-",
                  p.serial_number or "-")
    out.print(t)
    if not everything and len(found) == 1:
        out.print(f"--port auto is {found[0].device}", highlight=False)
