"""`armbridge bench firmware`: the firmware's cost per received line and per
control tick under the real MicroPython interpreter, beside CPython.

The measurement itself is `armbridge/emulator/mpbridge/fwcost.py`, which runs
unchanged in both interpreters: under MicroPython (the WebAssembly port, by
Node, through bridge.mjs) and under CPython (the firmware modules loaded as the
emulator loads them). Each item is `reps` calls of `board.poll()` timed inside
the interpreter: one line of each verb (and a line failing its CRC, and one
answered ER SEQ) with the clock held still, and one control tick (idle, RUN,
RUN with a T line every tick) with no line; and the codec's share of a W line
(crc32, decode, parse_command, encoding the reply) called directly.

What this does not show: a real ESP32 runs MicroPython slower again than
WebAssembly on a desktop CPU; and the WebAssembly port collects garbage only
between calls from JS, so no timed poll includes a collection. `alloc_bytes`
(heap allocated per poll) is given for that: on the chip, allocation is what
makes the collector run.
"""
from __future__ import annotations

import gc
import json
import subprocess
import time
from pathlib import Path
from typing import Any

import typer

from armbridge.bench.command import write_json
from armbridge.emulator.micropython import bridge_script, find_micropython, find_node
from armbridge.emulator.mpbridge import fwcost
from armbridge.boards import MicroPythonFirmware, board
from armbridge.emulator.runner import load_firmware
from armbridge.errors import ArmbridgeError
from armbridge.resources import firmware_dir

REPS = 2000
QUICK_REPS = 200
LINES_PER_S = 300        # the waypoint rate the link must sustain (issue 9)
BENCH_HEAP = 64 << 20    # room for a whole item without a collection (see fwcost.py)


def _firmware(device: str) -> tuple[MicroPythonFirmware, list[Path]]:
    spec = board(device)
    fw = spec.firmware
    if not isinstance(fw, MicroPythonFirmware):
        raise ArmbridgeError(f"the {spec.name} board's firmware is not MicroPython")
    return fw, [firmware_dir() / d for d in fw.dirs]


def under_micropython(device: str = "esp32", reps: int = REPS, timeout: float = 900.0) -> dict[str, Any]:
    fw, dirs = _firmware(device)
    argv = [find_node(), str(bridge_script()), str(find_micropython()), str(BENCH_HEAP), fw.board_module,
            fw.config_module, "bench:" + json.dumps({"reps": reps}), *map(str, dirs)]
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise ArmbridgeError(f"the MicroPython bench did not finish within {timeout:g} s") from None
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        raise ArmbridgeError(f"the MicroPython bench failed (status {proc.returncode}): "
                             f"{(proc.stderr or proc.stdout).strip()[-2000:]}")
    result: dict[str, Any] = json.loads(lines[-1])
    check(result)
    return result


def under_cpython(device: str = "esp32", reps: int = REPS) -> dict[str, Any]:
    import platform

    fw, dirs = _firmware(device)
    mods = load_firmware(dirs, (fw.config_module, fw.board_module, "proto", "protodef"))
    items = fwcost.start(mods[fw.board_module].Board, mods[fw.config_module], mods["proto"],
                         mods["protodef"].PROTOCOL_VERSION, lambda: time.perf_counter_ns() / 1000.0, reps)
    for name in items:
        gc.collect()
        fwcost.run(name)
    result = dict(fwcost.result())
    result["interpreter"] = f"CPython {platform.python_version()}"
    check(result)
    return result


def check(r: dict[str, Any]) -> None:
    """Every item got the answer it is meant to measure (fwcost.EXPECT), or the
    numbers would time another path: ArmbridgeError naming the item."""
    for group in ("lines", "ticks", "codec"):
        for name, st in r[group].items():
            want = fwcost.EXPECT[name]
            if st["answers"] != {want: st["n"]}:
                raise ArmbridgeError(f"bench firmware under {r['interpreter']}: the {name} item was answered "
                                     f"{st['answers']}, expected {want} every time; the bench does not match "
                                     "this firmware")


def tick_budget(r: dict[str, Any], period_ms: int, lines_per_s: int = LINES_PER_S) -> dict[str, Any]:
    """The share of one control period that `lines_per_s` W lines take, alone and
    with the control tick (RUN with telemetry), from the medians."""
    per_tick = lines_per_s * period_ms / 1000.0
    w = r["lines"]["W"]["median_us"]
    tick = r["ticks"]["RUN + telemetry"]["median_us"]
    period_us = period_ms * 1000.0
    return {
        "lines_per_s": lines_per_s,
        "period_ms": period_ms,
        "w_lines_per_tick": per_tick,
        "w_us_per_tick": round(per_tick * w, 1),
        "w_share_of_tick": round(per_tick * w / period_us, 4),
        "with_tick_share": round((per_tick * w + tick) / period_us, 4),
    }


def run(device: str = "esp32", reps: int = REPS, progress=lambda text: None) -> dict[str, Any]:
    """Both interpreters -> a JSON-ready dict (docs/benchmarks.md)."""
    fw, dirs = _firmware(device)
    period_ms = int(load_firmware(dirs, (fw.config_module,))[fw.config_module].PERIOD_MS)
    progress(f"MicroPython (WebAssembly), {reps} repetitions per item")
    mp = under_micropython(device, reps)
    progress(f"CPython, {reps} repetitions per item")
    cp = under_cpython(device, reps)
    ratio = {}
    for group in ("lines", "ticks", "codec"):
        for name, st in mp[group].items():
            base = cp[group][name]["median_us"]
            ratio[name] = round(st["median_us"] / base, 1) if base > 0 else None
    return {
        "device": device,
        "reps": reps,
        "micropython": mp,
        "cpython": cp,
        "median_ratio_micropython_over_cpython": ratio,
        "tick_budget": {"micropython": tick_budget(mp, period_ms), "cpython": tick_budget(cp, period_ms)},
    }


def print_result(r: dict[str, Any], console: Any) -> None:
    """The tables of `armbridge bench firmware` (rich console)."""
    from rich.table import Table

    mp, cp = r["micropython"], r["cpython"]
    table = Table(title=f"firmware cost per poll ({r['device']}, {r['reps']} repetitions, microseconds)",
                  caption=f"MicroPython: {mp['interpreter']}; CPython: {cp['interpreter']}; "
                          "alloc: heap bytes allocated per poll under MicroPython")
    for col in ("item", "MicroPython min", "median", "p99", "alloc", "CPython median", "ratio"):
        table.add_column(col, justify="left" if col == "item" else "right")
    for group, label in (("lines", "line"), ("ticks", "tick"), ("codec", "codec")):
        for name, st in mp[group].items():
            table.add_row(f"{label}: {name}", f"{st['min_us']:.1f}", f"{st['median_us']:.1f}", f"{st['p99_us']:.0f}",
                          str(st.get("alloc_bytes", "-")), f"{cp[group][name]['median_us']:.1f}",
                          f"{r['median_ratio_micropython_over_cpython'][name]:.1f}x")
    console.print(table)
    for who in ("micropython", "cpython"):
        b = r["tick_budget"][who]
        console.print(f"{r[who]['interpreter']}: {b['lines_per_s']} W lines/s = {b['w_lines_per_tick']:g} per "
                      f"{b['period_ms']} ms tick: {b['w_us_per_tick']:.0f} us, {b['w_share_of_tick']:.1%} of the "
                      f"tick; with the control tick (RUN + telemetry) {b['with_tick_share']:.1%}")
    console.print(f"live heap under MicroPython after the bench: {mp['heap_live_after_bench']} bytes")


def firmware_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 200 repetitions per item."),
    reps: int = typer.Option(None, "--reps", min=10, help="Repetitions per item (full run: 2000)."),
    device: str = typer.Option("esp32", "--device", help="A MicroPython board of the emulator."),
    json_out: Path = typer.Option(Path("runs/bench-firmware.json"), "--json", help="Where to write the results ('-': stdout)."),
) -> None:
    """The firmware's cost per received line (each verb) and per control tick under
    the real MicroPython interpreter (WebAssembly, by Node) and under CPython."""
    from rich.console import Console

    console = Console()
    n = reps if reps is not None else (QUICK_REPS if quick else REPS)
    result = run(device, n, progress=lambda text: console.print(f"[dim]bench firmware: {text}[/]"))
    write_json(result, json_out)
    print_result(result, console)
    console.print(f"wrote {json_out}")
