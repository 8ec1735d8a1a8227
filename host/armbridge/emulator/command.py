"""`armbridge emulate DEVICE`: an emulated board on a pseudo-terminal until Ctrl-C."""
from __future__ import annotations

import signal
import sys
import threading
import time
from pathlib import Path
from typing import List, Optional

import typer

from armbridge.emulator.board import EmulatedBoard
from armbridge.emulator.faults import (Faults, parse_delay, parse_lanes, parse_missed, parse_rate, parse_seconds,
                                       parse_slip, parse_stall)
from armbridge.emulator.registry import BOARDS, board_spec, rig_spec
from armbridge.emulator.truth import check_plant
from armbridge.errors import ArmbridgeError


def _say(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


_DEVICES = "; ".join(f"{name} ({BOARDS[name].description})" for name in sorted(BOARDS))
_RIGS = "; ".join(f"{name}: {', '.join(sorted(BOARDS[name].rigs))}" for name in sorted(BOARDS) if BOARDS[name].rigs)


def format_counters(counters: dict) -> str:
    def lane(c: dict) -> str:
        return (f"{c['bytes']} bytes, dropped {c['drop']}, corrupted {c['corrupt']}, "
                f"duplicated {c['dup']}, delayed {c['delay']}")

    return (f"host->board: {lane(counters['rx'])}\n"
            f"board->host: {lane(counters['tx'])}\n"
            f"resets: {counters['resets']}, bytes lost in resets: {counters['lost_in_reset']}, "
            f"bytes nobody read: {counters['pty_dropped']}, clock overruns: {counters['overruns']}\n"
            f"longest gap between host lines at the board: {counters.get('host_line_gap_s', 0.0):.3f} s")


def emulate_cmd(
    device: str = typer.Argument(..., help=f"Board to emulate: {_DEVICES}."),
    link: Optional[str] = typer.Option(None, "--link", metavar="PATH", help="Also make PATH a symlink to the pty, owned while this runs (refused if another emulator owns it)."),
    speed: float = typer.Option(1.0, "--speed", help="Sim time per wall time: 1 real time, K faster, 0 as fast as it goes."),
    interpreter: Optional[str] = typer.Option(None, "--interpreter", metavar="NAME",
                                              help="Run the firmware under cpython (default) or micropython "
                                                   "(the real MicroPython interpreter, WebAssembly, slower); "
                                                   "arduino_pump: simavr (its only one: the real .elf, cycle-exact)."),
    servos: Optional[str] = typer.Option(None, "--servos", metavar="RIG",
                                         help="The board's rig (its config SERVOS): " + _RIGS + ". effort: continuous "
                                              "servos driven by effort (default); pca9685: positional servos behind "
                                              "a PCA9685 on I2C, the paper's rig."),
    drop: str = typer.Option("0", "--drop", metavar="R", help="Fraction of bytes dropped, [0, 1]."),
    corrupt: str = typer.Option("0", "--corrupt", metavar="R", help="Fraction of bytes with one bit flipped, [0, 1]."),
    dup: str = typer.Option("0", "--dup", metavar="R", help="Fraction of bytes sent twice, [0, 1]."),
    delay: Optional[str] = typer.Option(None, "--delay", metavar="R:MS", help="Fraction R of bytes held MS ms longer."),
    lanes: str = typer.Option("rx,tx", "--lanes", help="Directions with link faults: rx (host->board), tx, or rx,tx."),
    reset_at: List[float] = typer.Option([], "--reset-at", metavar="SECONDS", help="Reset the board at this sim time (repeatable)."),
    stall: List[str] = typer.Option([], "--stall", metavar="J@SECONDS", help="Stall joint J (1..n) at this sim time (repeatable). masr_ma: joint J's worm drive seizes (the rotation motor stalls on it), J = n: the wheel."),
    missed: List[str] = typer.Option([], "--missed-magnet", metavar="J", help="masr_ma: joint J's magnet never fires (repeatable)."),
    slip: List[str] = typer.Option([], "--slip-burst", metavar="S:D:F", help="masr_ma: from sim second S for D seconds the wheel slips by the fraction F in [0, 1]: the MA advances by its travel times 1 - F (repeatable)."),
    seed: int = typer.Option(0, "--seed", help="Seed of sensor noise and link faults (and of the plant's truth)."),
    plant: str = typer.Option("nominal", "--plant", metavar="P",
                              help="nominal: the model the firmware assumes; random: the plant's physical "
                                   "parameters drawn with --seed from their documented spreads "
                                   "(docs/emulator.md, 'Hidden truth'), which host and firmware never read."),
    fs: Optional[Path] = typer.Option(None, "--fs", metavar="DIR",
                                      help="Keep the board's non-volatile memory in DIR, as the chip keeps it across "
                                           "power cycles: a MicroPython board's filesystem (what a flash wrote, its "
                                           "calibration), the pump board's EEPROM (docs/emulator.md)."),
    verbose: int = typer.Option(0, "--verbose", "-v", count=True,
                                help="-v: also the board's BOOT and EV lines with their sim time; -vv: every line "
                                     "the board sends (answers, telemetry). Default: the port line, warnings and, "
                                     "at exit, the fault counters."),
    quiet: bool = typer.Option(False, "--quiet", "-q", hidden=True, help="The default (kept for old scripts)."),
    run_for: Optional[float] = typer.Option(None, "--for", metavar="SECONDS", help="Stop after this many wall seconds."),
    realtime: bool = typer.Option(False, "--realtime", help="Run the board at real-time priority (SCHED_FIFO, as "
                                  "Klipper's Linux MCU with -r), so a busy machine does not slow it; needs root or "
                                  "CAP_SYS_NICE, else it says so and runs as usual."),
) -> None:
    """Put an emulated board on a pseudo-terminal and print its path; Ctrl-C stops it."""
    spec = rig_spec(board_spec(device), servos)
    if interpreter is not None and interpreter not in spec.interpreters:
        on = f" on the {spec.rig} rig" if spec.rigs else ""
        raise ArmbridgeError(f"--interpreter {interpreter!r}: the {device} firmware{on} runs under "
                             f"{', '.join(spec.interpreters)}")
    if not speed >= 0:
        raise ArmbridgeError(f"--speed {speed} must be >= 0 (0 = as fast as it goes)")
    try:
        check_plant(plant)
    except ArmbridgeError as exc:
        raise ArmbridgeError(f"--plant: {exc}") from None
    delay_rate, delay_ms = parse_delay(delay, "--delay") if delay else (0.0, 0.0)
    faults = Faults(
        drop=parse_rate("--drop", drop),
        corrupt=parse_rate("--corrupt", corrupt),
        dup=parse_rate("--dup", dup),
        delay=delay_rate,
        delay_ms=delay_ms,
        lanes=parse_lanes(lanes, "--lanes"),
        reset_at=tuple(parse_seconds(t, "--reset-at") for t in reset_at),
        stall=tuple(parse_stall(s, "--stall") for s in stall),
        missed=tuple(parse_missed(j, "--missed-magnet") for j in missed),
        slip=tuple(parse_slip(x, "--slip-burst") for x in slip),
    )

    held: list[str] | None = []  # lines from before the first line of output

    quiet = quiet or verbose == 0

    def echo(t: float, line: bytes) -> None:
        parts = line.split(b" ", 2)
        if verbose >= 2 or (len(parts) >= 2 and parts[1] in (b"BOOT", b"EV")):
            text = f"{t:10.3f}  {line.decode('latin-1')}"
            if held is not None:
                held.append(text)
            else:
                _say(text)

    def warn(text: str) -> None:  # even with -q: a board that cannot keep the wall clock says so
        sys.stderr.write(f"warning: {text}\n")
        sys.stderr.flush()

    emu = EmulatedBoard(spec, speed=speed, faults=faults, seed=seed, link=link, interpreter=interpreter, plant=plant,
                        on_line=None if quiet else echo, on_note=warn, realtime=realtime, fs_dir=fs)
    try:
        emu.start()  # a link another emulator owns: ArmbridgeError naming the owner
    except BaseException:
        emu.stop()
        raise
    first = f"{device} emulator on {emu.port}"
    if link:
        first += f" (link {link})"
    _say(first)
    if emu.link_note:
        _say(f"note: {emu.link_note}")
    rig = f"rig {spec.rig}, " if spec.rigs else ""
    _say(f"speed {speed:g}, seed {seed}, {plant} plant, {rig}firmware under {emu.interpreter}, "
         f"faults: {faults.describe()}; "
         "Ctrl-C stops")
    for text in held or []:
        _say(text)
    held = None

    stop = threading.Event()
    old = None
    if threading.current_thread() is threading.main_thread():
        old = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    t_end = None if run_for is None else time.monotonic() + run_for
    try:
        while not stop.is_set() and emu.running and emu.crash is None:
            if t_end is not None and time.monotonic() >= t_end:
                break
            time.sleep(0.05)
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    _say(f"stopped at sim time {emu.now():.3f} s, board state {emu.state}")
    _say(format_counters(emu.counters))
    if speed > 0:
        pace = emu.pace()
        achieved = "-" if pace["achieved"] is None else f"{pace['achieved']:.3f}x"
        _say(f"pace: {achieved} of real time (asked {speed:g}x), largest lag {pace['max_lag_s']:.3f} s, "
             f"{pace['overruns']} backlogs given up ({pace['given_up_s']:.2f} s)")
    if emu.crash:
        sys.stderr.write(emu.crash)
        raise ArmbridgeError(f"the {device} firmware raised an exception (traceback above)")
