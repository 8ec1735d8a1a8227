"""`armbridge flash BOARD --port P`: the command line of armbridge.flash (docs/flash.md).

    armbridge flash esp32 --port /dev/ttyUSB0                  compile, copy what changed, verify, reset, HELLO
    armbridge flash esp32 --port /dev/ttyUSB0 --dry-run        what would change
    armbridge flash esp32 --port /dev/ttyUSB0 --micropython ESP32_GENERIC-v1.29.0.bin
    armbridge flash masr_ma --port emu:masr_ma?fs=/tmp/ma      the emulated board (its filesystem kept in /tmp/ma)

Exit codes as `armbridge run`: 0 flashed (or up to date), 1 the board failed
(no raw REPL, wrong board, a file failed its hash, no HELLO after the reset;
a board left half-flashed says so), 2 bad input, 128 + the signal when
stopped by one (the board is then half-flashed, and says so).
"""
from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import Any, Optional

import typer
from rich.console import Console

from armbridge.errors import ArmbridgeError, BoardFailure
from armbridge.executor.signals import Stopped, stop_on_signals
from armbridge.link.ports import auto_port

BOARD_HELP = "The board: esp32 (the 3R arm), masr_ma (the MASR mobile actuator) or arduino_pump (avrdude)."
PORT_HELP = ("The board's MicroPython REPL: a serial device (/dev/ttyUSB0), a pyserial URL, or emu:DEVICE "
             "(emu:esp32?fs=DIR keeps the emulated filesystem in DIR), or auto (the one board plugged in: "
             "armbridge ports) (env ARMBRIDGE_PORT).")


def _flasher(board: str) -> tuple[Any, Any]:
    from armbridge.flash import FLASHERS, NOT_YET, TARGETS

    if board in NOT_YET:
        raise ArmbridgeError(f"cannot flash {board} yet: {NOT_YET[board]}")
    target = TARGETS.get(board)
    if target is None:
        raise ArmbridgeError(f"unknown board {board!r}; armbridge flash knows: {', '.join(sorted(TARGETS))}")
    mod, func = FLASHERS[target.kind].split(":")
    return target, getattr(importlib.import_module(mod), func)


def _describe_plan(out: Console, res: Any, port: str) -> None:
    b, plan = res.build, res.plan
    if res.half_flashed_before:
        out.print(f"the board on {port} was left half-flashed by an earlier flash ({res.half_flashed_before}); "
                  "flashing it whole", highlight=False)
    verb = "would write" if res.dry_run else "write"
    for name in plan.write:
        out.print(f"  {verb} {name} ({len(b.files[name])} bytes)", highlight=False)
    for name in plan.remove:
        out.print(f"  {'would remove' if res.dry_run else 'remove'} {name}", highlight=False)
    if plan.manifest and not (plan.write or plan.remove):
        out.print(f"  {verb} the manifest only", highlight=False)
    out.print(f"{b.firmware} {b.version} (protocol {b.protocol}) for {b.board}: {len(plan.write)} to write, "
              f"{len(plan.remove)} to remove, {len(plan.unchanged)} unchanged", highlight=False)


def flash_cmd(
    board: str = typer.Argument(..., metavar="BOARD", help=BOARD_HELP),
    port: str = typer.Option(..., "--port", "-p", envvar="ARMBRIDGE_PORT", callback=auto_port, help=PORT_HELP),
    dry_run: bool = typer.Option(False, "--dry-run", help="List what would change on the board; change nothing."),
    micropython: Optional[Path] = typer.Option(
        None, "--micropython", metavar="IMAGE",
        help="First write this MicroPython image with esptool 5 (write-flash at 0x1000, the classic ESP32's offset)."),
    firmware: Optional[Path] = typer.Option(
        None, "--firmware", metavar="DIR",
        help="The firmware tree to flash (a folder like the checkout's firmware/, holding esp32/, masr_ma/, "
             "common/) [default: the shipped one]."),
    link: Optional[str] = typer.Option(
        None, "--link", metavar="PORT",
        help="The board's line-protocol port for the HELLO check after the reset, when it is not --port "
             "(config UART_ID = 1: a USB-UART adapter on GPIO 16/17) [default: --port]."),
    force: bool = typer.Option(False, "--force", help="Flash even a board that holds another board's firmware."),
    timeout: float = typer.Option(10.0, "--timeout", min=0.5, metavar="SECONDS",
                                  help="How long to wait for the raw REPL and for HELLO after the reset."),
) -> None:
    """Flash a board and check its HELLO: esp32/masr_ma compile with mpy-cross and copy what changed
    over the raw REPL (sha256 checked, a manifest); arduino_pump builds the .hex and writes it with
    avrdude through the Mega's bootloader (verified)."""
    target, flash = _flasher(board)
    out = Console(stderr=True, highlight=False)
    if target.kind == "avrdude":
        foreign = [flag for flag, given in (("--micropython", micropython is not None), ("--dry-run", dry_run),
                                            ("--link", link is not None), ("--force", force)) if given]
        if foreign:
            raise ArmbridgeError(f"{', '.join(foreign)}: for the MicroPython boards; {board} runs its C firmware "
                                 "(avrdude writes and verifies the .hex through its bootloader; it takes --port, "
                                 "--firmware and --timeout)")
    if target.kind == "avrdude":
        _flash_avr(target, flash, port, firmware, timeout, out)
        return
    if firmware is not None and not firmware.is_dir():
        raise ArmbridgeError(f"--firmware {firmware}: not a folder")
    if micropython is not None:
        from armbridge.flash.image import check_image, write_image
        from armbridge.link.transport import port_scheme

        check_image(micropython)
        if port_scheme(port.strip()) == "emu":
            raise ArmbridgeError("--micropython needs the chip's ROM bootloader, which the emulator does not have; "
                                 "an emulated board already runs MicroPython")
        if dry_run:
            out.print(f"would write {micropython} at 0x{target.image_offset:x} with esptool")
        else:
            out.print(f"writing {micropython} at 0x{target.image_offset:x} with esptool ...")
            write_image(micropython, port, target.chip, target.image_offset)

    bar = _Bar(out)

    def on_plan(res: Any) -> None:
        _describe_plan(out, res, port)
        bar.start(res)

    try:
        with stop_on_signals():
            res = flash(target, port, firmware_root=firmware, dry_run=dry_run, link=link, timeout=timeout,
                        force=force, on_plan=on_plan,
                        progress=bar.update)
    except Stopped as stop:
        bar.close()
        typer.secho(f"error: stopped by {stop.name}: the board on {port} may be half-flashed; "
                    f"run armbridge flash {board} again", fg="red", err=True)
        raise typer.Exit(stop.exit_code) from None
    finally:
        bar.close()
    if dry_run:
        print("dry run: nothing written" + ("" if res.plan.changes else " (the board is up to date)"))
        return
    h = res.hello
    what = (f"{len(res.plan.write)} files written ({res.bytes_written} bytes), {len(res.plan.remove)} removed"
            if res.plan.changes else "up to date, nothing written")
    print(f"flashed {res.build.firmware} {res.build.version} to {port}: {what}, {len(res.plan.unchanged)} unchanged; "
          f"HELLO {h.fw} {h.version} protocol {h.proto}")
    sys.stdout.flush()


def _flash_avr(target: Any, flash: Any, port: str, firmware: Optional[Path], timeout: float, out: Console) -> None:
    """The Arduino pump board: avrdude through its bootloader (flash.avrdude), avrdude's progress lines shown."""
    if firmware is not None and not firmware.is_dir():
        raise ArmbridgeError(f"--firmware {firmware}: not a folder")
    out.print(f"writing {target.board} with avrdude through the stk500v2 bootloader on {port} ...")
    try:
        with stop_on_signals():
            res = flash(target, port, firmware_root=firmware, timeout=timeout,
                        progress=lambda line: out.print(f"  {line}", highlight=False))
    except Stopped as stop:
        typer.secho(f"error: stopped by {stop.name}: the board on {port} may be half-flashed; "
                    f"run armbridge flash {target.board} again", fg="red", err=True)
        raise typer.Exit(stop.exit_code) from None
    h = res.hello
    print(f"flashed {res.firmware} {res.version} to {port}: {res.bytes_written} bytes written and verified "
          f"({res.hex.name}); HELLO {h.fw} {h.version} protocol {h.proto}")
    sys.stdout.flush()


class _Bar:
    """A rich progress bar over the bytes to write (a terminal only; plain lines otherwise)."""

    def __init__(self, out: Console) -> None:
        self.out = out
        self.progress: Any = None
        self.task: Any = None
        self.base = 0
        self.sizes: dict[str, int] = {}
        self.done: set[str] = set()

    def start(self, res: Any) -> None:
        if res.dry_run or not res.plan.write:
            return
        self.sizes = {n: len(res.build.files[n]) for n in res.plan.write}
        if self.out.is_terminal:
            from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn

            self.progress = Progress(TextColumn("{task.description}"), BarColumn(), DownloadColumn(),
                                     console=self.out, transient=True)
            self.progress.start()
            self.task = self.progress.add_task("flashing", total=sum(self.sizes.values()))

    def update(self, name: str, n: int, total: int) -> None:
        if self.progress is not None:
            self.progress.update(self.task, completed=self.base + n, description=name)
        if n >= total and name not in self.done:
            self.done.add(name)
            self.base += self.sizes.get(name, total)
            if self.progress is None:
                self.out.print(f"  wrote {name}", highlight=False)

    def close(self) -> None:
        if self.progress is not None:
            self.progress.stop()
            self.progress = None


__all__ = ["flash_cmd", "BoardFailure"]
