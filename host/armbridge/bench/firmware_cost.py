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
BENCH_HEAP_BASE = 4 << 20   # MicroPython heap: room for a whole item without a collection (see fwcost.py),
BENCH_HEAP_PER_REP = 8 << 10  # and no more (gc.mem_alloc() around each poll walks the whole heap's table)
# What the firmware's live heap is compared with: the Python heap an ESP32 without
# PSRAM gives MicroPython, "around 100KB" on a "simple" esp32 (MicroPython's ESP32
# port documentation, "Controlling the Python heap size"; gc.mem_free() at boot of
# an ESP32_GENERIC build). Since 1.21 the heap can grow into the IDF's free blocks,
# so this is the floor a board can count on, not a chip measured here.
CHIP_FREE_HEAP = 100_000
CHIP_FREE_HEAP_SOURCE = ("ESP32 without PSRAM, MicroPython's ESP32_GENERIC build: gc.mem_free() at boot, "
                         "'around 100KB' (MicroPython docs, esp32 quickref 'Controlling the Python heap size'); "
                         "not measured on a chip here")
#: every MicroPython board and rig the bench runs ("all"): key -> (board, rig, the bridge's rig HAL)
TARGETS = {"esp32": ("esp32", "effort", "arm"), "esp32 pca9685": ("esp32", "pca9685", "pca"),
           "masr_ma": ("masr_ma", "effort", "ma")}


def target(device: str, servos: str | None = None) -> str:
    """The TARGETS key of `--device DEVICE [--servos RIG]`; one ArmbridgeError naming them otherwise."""
    key = device if not servos or (device == "esp32" and servos == "effort") else f"{device} {servos}"
    if key not in TARGETS:
        raise ArmbridgeError(f"bench firmware: no MicroPython board {key!r}; boards: "
                             + ", ".join(f"--device {k.replace(' ', ' --servos ')}" for k in TARGETS) + ", --device all")
    return key


def _firmware(key: str) -> tuple[MicroPythonFirmware, list[Path], str]:
    device, _, rig = TARGETS[key]
    spec = board(device)
    fw = spec.firmware
    if not isinstance(fw, MicroPythonFirmware):
        raise ArmbridgeError(f"the {spec.name} board's firmware is not MicroPython")
    return fw, [firmware_dir() / d for d in fw.dirs], rig


def under_micropython(key: str = "esp32", reps: int = REPS, timeout: float = 900.0) -> dict[str, Any]:
    fw, dirs, rig = _firmware(key)
    argv = [find_node(), str(bridge_script()), str(find_micropython()),
            str(BENCH_HEAP_BASE + BENCH_HEAP_PER_REP * reps), fw.board_module,
            fw.config_module, "bench:" + json.dumps({"reps": reps, "rig": rig}), *map(str, dirs)]
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


def under_cpython(key: str = "esp32", reps: int = REPS) -> dict[str, Any]:
    import platform

    fw, dirs, rig = _firmware(key)
    extra = ("pca9685", "servos") if rig == "pca" else ()
    mods = load_firmware(dirs, (fw.config_module, fw.board_module, "proto", "protodef") + extra)
    items = fwcost.start(mods[fw.board_module].Board, mods[fw.config_module], mods["proto"],
                         mods["protodef"].PROTOCOL_VERSION, lambda: time.perf_counter_ns() / 1000.0, reps, rig, mods)
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


def waypoint_verb(r: dict[str, Any]) -> str:
    """W on the arm's rigs, MV on the MA."""
    return "MV" if "MV" in r["lines"] else "W"


def tick_budget(r: dict[str, Any], period_ms: int, lines_per_s: int = LINES_PER_S) -> dict[str, Any]:
    """The share of one control period that `lines_per_s` waypoint lines (W; the MA's MV)
    take, alone and with the control tick (RUN with telemetry), from the medians."""
    per_tick = lines_per_s * period_ms / 1000.0
    w = r["lines"][waypoint_verb(r)]["median_us"]
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


def memory(mp: dict[str, Any], chip_free: int = CHIP_FREE_HEAP) -> dict[str, Any]:
    """Per board under MicroPython: the heap a control tick allocates (the most of the
    three tick items), the firmware's live heap after boot and after the run (less
    the bridge's own modules), and the headroom against the chip's free heap."""
    alloc_tick = max(int(st.get("alloc_bytes", 0)) for st in mp["ticks"].values())
    live = int(mp["heap"]["after_run"])
    return {"alloc_per_tick_bytes": alloc_tick, "live_heap_after_boot_bytes": int(mp["heap"]["after_boot"]),
            "live_heap_after_run_bytes": live, "chip_free_heap_bytes": chip_free,
            "headroom_bytes": chip_free - live, "chip_free_heap_source": CHIP_FREE_HEAP_SOURCE}


def run_all(keys: list[str], reps: int = REPS, progress=lambda text: None) -> dict[str, Any]:
    """Every board of `keys` (TARGETS) in both interpreters -> a JSON-ready dict (docs/benchmarks.md)."""
    return {"reps": reps, "chip_free_heap_bytes": CHIP_FREE_HEAP, "chip_free_heap_source": CHIP_FREE_HEAP_SOURCE,
            "boards": {k: run(k, reps, progress) for k in keys}}


def run(key: str = "esp32", reps: int = REPS, progress=lambda text: None) -> dict[str, Any]:
    """One board (a TARGETS key) in both interpreters -> a JSON-ready dict."""
    fw, dirs, _ = _firmware(key)
    period_ms = int(load_firmware(dirs, (fw.config_module,))[fw.config_module].PERIOD_MS)
    progress(f"{key}: MicroPython (WebAssembly), {reps} repetitions per item")
    mp = under_micropython(key, reps)
    progress(f"{key}: CPython, {reps} repetitions per item")
    cp = under_cpython(key, reps)
    ratio = {}
    for group in ("lines", "ticks", "codec"):
        for name, st in mp[group].items():
            base = cp[group][name]["median_us"]
            ratio[name] = round(st["median_us"] / base, 1) if base > 0 else None
    return {
        "device": key,
        "reps": reps,
        "memory": memory(mp),
        "micropython": mp,
        "cpython": cp,
        "median_ratio_micropython_over_cpython": ratio,
        "tick_budget": {"micropython": tick_budget(mp, period_ms), "cpython": tick_budget(cp, period_ms)},
    }


def print_result(r: dict[str, Any], console: Any) -> None:
    """The tables of one board (rich console)."""
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
    verb = waypoint_verb(mp)
    for who in ("micropython", "cpython"):
        b = r["tick_budget"][who]
        console.print(f"{r[who]['interpreter']}: {b['lines_per_s']} {verb} lines/s = {b['w_lines_per_tick']:g} per "
                      f"{b['period_ms']} ms tick: {b['w_us_per_tick']:.0f} us, {b['w_share_of_tick']:.1%} of the "
                      f"tick; with the control tick (RUN + telemetry) {b['with_tick_share']:.1%}")


def print_summary(r: dict[str, Any], console: Any) -> None:
    """One row per board: time per line and tick, allocation per tick, live heap, headroom."""
    from rich.table import Table

    table = Table(title=f"the firmware under MicroPython, per board ({r['reps']} repetitions)",
                  caption=f"headroom: against {r['chip_free_heap_bytes']:,} bytes free, {r['chip_free_heap_source']}")
    for col in ("board", "waypoint line us", "RUN + telemetry tick us", "alloc per tick B", "live heap after boot B",
                "live heap after run B", "headroom B"):
        table.add_column(col, justify="left" if col == "board" else "right")
    for key, b in r["boards"].items():
        mp, m = b["micropython"], b["memory"]
        verb = waypoint_verb(mp)
        table.add_row(key, f"{verb} {mp['lines'][verb]['median_us']:.1f}",
                      f"{mp['ticks']['RUN + telemetry']['median_us']:.1f}", f"{m['alloc_per_tick_bytes']:,}",
                      f"{m['live_heap_after_boot_bytes']:,}", f"{m['live_heap_after_run_bytes']:,}",
                      f"{m['headroom_bytes']:,}")
    console.print(table)


def firmware_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 200 repetitions per item."),
    reps: int = typer.Option(None, "--reps", min=10, help="Repetitions per item (full run: 2000)."),
    device: str = typer.Option("all", "--device",
                               help="A MicroPython board of the emulator (esp32, masr_ma), or all of them, "
                                    "the esp32's PCA9685 rig included (default)."),
    servos: str = typer.Option(None, "--servos", metavar="RIG", help="The esp32's rig: effort (default) or pca9685."),
    json_out: Path = typer.Option(Path("runs/bench-firmware.json"), "--json", help="Where to write the results ('-': stdout)."),
) -> None:
    """The firmware's cost per received line (each verb) and per control tick under
    the real MicroPython interpreter (WebAssembly, by Node) and under CPython, per
    board: heap allocated per poll, the live heap after a run and its headroom
    against an ESP32's free MicroPython heap."""
    from rich.console import Console

    if device == "all" and servos:
        raise ArmbridgeError("bench firmware: --servos needs --device esp32")
    keys = list(TARGETS) if device == "all" else [target(device, servos)]
    console = Console()
    n = reps if reps is not None else (QUICK_REPS if quick else REPS)
    result = run_all(keys, n, progress=lambda text: console.print(f"[dim]bench firmware: {text}[/]"))
    write_json(result, json_out)
    for b in result["boards"].values():
        print_result(b, console)
    print_summary(result, console)
    if str(json_out) != "-":
        console.print(f"wrote {json_out}")
