"""`armbridge bench`: one subcommand per measured capability."""
from __future__ import annotations

import json
from pathlib import Path

import typer

bench_app = typer.Typer(help="Measure the numbers in docs/benchmarks.md; each writes JSON.", no_args_is_help=True)


def write_json(result: dict, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1) + "\n")


@bench_app.command("link")
def link_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 300 waypoints, 50 pings, 5 e-stops, 15 s soak."),
    soak_s: float = typer.Option(None, "--soak", help="Soak length in seconds (full run: 600)."),
    json_out: Path = typer.Option(Path("runs/bench-link.json"), "--json", help="Where to write the results."),
) -> None:
    """The line protocol over a pty paced at 115200 baud: throughput, round trip,
    e-stop latency, and a soak under link faults and board resets."""
    from dataclasses import replace

    from rich.console import Console
    from rich.table import Table

    from armbridge.bench import link

    size = link.QUICK if quick else link.FULL
    if soak_s is not None:
        size = replace(size, soak_s=soak_s, reset_every_s=min(size.reset_every_s, soak_s / 2))
    console = Console()
    result = link.run(size, progress=lambda text: console.print(f"[dim]bench link: {text}[/]"))
    write_json(result, json_out)

    tp, rt, es, so = result["throughput"], result["round_trip"], result["estop"], result["soak"]
    table = Table(title="armbridge bench link (115200 baud 8N1, 3-joint waypoints)")
    table.add_column("measure")
    table.add_column("value", justify="right")
    table.add_column("target", justify="right")
    table.add_row("sustained waypoints/s", f"{tp['waypoints_per_s']:.0f}", ">= 200")
    table.add_row("line capacity used (host->board)", f"{tp['line_capacity_used']:.1%}", "")
    table.add_row("bytes per waypoint line", f"{tp['bytes_per_waypoint']:.1f}", "")
    table.add_row("ack round trip median / p95 (ms)", f"{rt['median_ms']:.2f} / {rt['p95_ms']:.2f}", "")
    table.add_row("e-stop byte -> outputs off median / max (ms)",
                  f"{es['byte_to_outputs_off']['median_ms']:.2f} / {es['byte_to_outputs_off']['max_ms']:.2f}", "< 20")
    table.add_row("e-stop byte -> ESTOP event at host median (ms)",
                  f"{es['byte_to_event_at_host']['median_ms']:.2f}", "")
    table.add_row(f"soak {so['seconds']:.0f} s: waypoints executed", f"{so['executed']} / {so['waypoints']}", "")
    table.add_row("soak: lost / duplicated / in order", f"{so['lost']} / {so['duplicated']} / {so['in_order']}",
                  "0 / 0 / True")
    table.add_row("soak: resets / resyncs / retransmitted", f"{so['resets']} / {so['resyncs']} / {so['retransmitted']}", "")
    console.print(table)
    console.print(f"wrote {json_out}")
