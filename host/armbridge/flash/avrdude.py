"""The Arduino pump board: its Makefile's .hex written with avrdude through the Mega's stk500v2 bootloader.

    avrdude -p atmega2560 -c wiring -P PORT -b 115200 -D -U flash:w:FILE.hex:i

`-c wiring` is the stk500v2 protocol with the DTR pulse the Mega's bootloader
needs (the port's opening resets the chip; the bootloader listens for about
a second, then starts the sketch); `-D` leaves the chip erase to the
bootloader's page writes; avrdude reads the flash back and compares it after
the write (its default). Then the sketch must answer HELLO with the name,
version and protocol of the config.h it was built from (issue 14 §2).

`emu:arduino_pump` (options `?flash=FILE`, `eeprom=FILE`): the emulated Mega in
the simavr harness's boot mode (simavr_chip.BootloaderChip), the real
bootloader behind a pty; avrdude gets the pty, the HELLO check the same chip.
"""
from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable
from urllib.parse import parse_qs

from armbridge.errors import ArmbridgeError, BoardFailure
from armbridge.flash.manifest import Journal

AVRDUDE_APT = "apt-get install -y avrdude"


@dataclass(frozen=True)
class AvrTarget:
    """An AVR board armbridge flashes: its firmware folder under the firmware tree, the
    .hex its Makefile builds, avrdude's part and programmer, the bootloader's baud."""

    board: str
    folder: str = "arduino_pump"
    hex: str = "build/arduino_pump.hex"
    part: str = "atmega2560"
    programmer: str = "wiring"
    baud: int = 115200
    kind: str = "avrdude"


@dataclass
class AvrResult:
    hex: Path
    firmware: str
    version: str
    protocol: int
    bytes_written: int = 0
    hello: Any = None


def build_hex(target: AvrTarget, firmware_root: Path | None) -> tuple[Path, Any]:
    """The .hex and config.h constants of the board's firmware (rebuilt with its Makefile when stale)."""
    from armbridge.boards.config import read_config_h
    from armbridge.emulator.simavr_chip import firmware_elf
    from armbridge.resources import firmware_dir

    folder = (firmware_root or firmware_dir()) / target.folder
    if not (folder / "config.h").is_file():
        raise ArmbridgeError(f"{folder} holds no config.h: not the {target.board} firmware")
    try:
        hexfile = firmware_elf(folder, target.hex)
    except subprocess.CalledProcessError as exc:
        raise ArmbridgeError(f"make -C {folder} failed (exit {exc.returncode})") from None
    cfg = read_config_h(folder / "config.h")
    m = re.search(r"^#define\s+AB_PROTOCOL_VERSION\s+(\d+)", (folder / "protodef.h").read_text(), re.M)
    if m is None:
        raise ArmbridgeError(f"{folder / 'protodef.h'} defines no AB_PROTOCOL_VERSION")
    cfg.AB_PROTOCOL_VERSION = int(m.group(1))
    return hexfile, cfg


def avrdude_args(target: AvrTarget, port: str, hexfile: Path) -> list[str]:
    return ["avrdude", "-p", target.part, "-c", target.programmer, "-P", port, "-b", str(target.baud), "-D",
            "-U", f"flash:w:{hexfile}:i"]


NO_BOOTLOADER = "does not answer the stk500v2 bootloader"
#: The longest avrdude may take (s): the Mega's 256 KB written and verified at 115200 baud take about a minute.
AVRDUDE_S = 300.0


def run_avrdude(target: AvrTarget, port: str, hexfile: Path, label: str,
                progress: Callable[[str], None] | None = None) -> int:
    """Run avrdude; its progress bars go to `progress` line by line. Returns the bytes written;
    a failure is one BoardFailure line naming what avrdude said."""
    if shutil.which("avrdude") is None:
        raise ArmbridgeError(f"avrdude is missing: run scripts/setup.sh as root, or: {AVRDUDE_APT}")
    proc = subprocess.Popen(avrdude_args(target, port, hexfile), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, errors="replace")
    lines: list[str] = []
    assert proc.stdout is not None
    # avrdude on a port that went away can spin for ever: it gets AVRDUDE_S, and never outlives
    # this call (a stop signal or an exception kills it on the way out)
    expired: list[bool] = []

    def expire() -> None:
        expired.append(True)
        proc.kill()

    timer = threading.Timer(AVRDUDE_S, expire)
    timer.start()
    try:
        for line in proc.stdout:
            line = line.strip()
            if line:
                lines.append(line)
                if progress is not None and re.match(r"(avrdude: (writing|verifying|reading)|Writing|Reading)", line):
                    progress(line)
        rc = proc.wait()
    finally:
        timer.cancel()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    if expired:
        raise BoardFailure(f"avrdude did not finish on {label} within {AVRDUDE_S:g} s (stopped): "
                           f"{_last_error(lines)}")
    text = "\n".join(lines)
    if rc == 0:
        m = re.search(r"(\d+) bytes of flash verified", text)
        return int(m.group(1)) if m else 0
    if re.search(r"not in sync|timeout|no response|cannot communicate|initialization failed", text, re.I):
        raise BoardFailure(f"the board on {label} {NO_BOOTLOADER} (avrdude: "
                           f"{_last_error(lines)}): not a Mega with its bootloader, or it was not reset")
    if re.search(r"verification (error|mismatch)|content mismatch", text, re.I):
        raise BoardFailure(f"the flash on {label} failed avrdude's verify ({_last_error(lines)}): "
                           f"the board is half-flashed; run armbridge flash {target.board} again")
    raise BoardFailure(f"avrdude failed on {label} (exit {rc}): {_last_error(lines)}")


def _last_error(lines: list[str]) -> str:
    errs = [ln for ln in lines if "error" in ln.lower() or "not in sync" in ln or "timeout" in ln.lower()]
    errs = [ln for ln in errs if "TIOCM" not in ln] or lines[-1:] or ["no output"]
    return errs[0].removeprefix("avrdude ").removeprefix("avrdude: ")[:160]


def _hello(port: str, res: AvrResult, label: str, timeout: float) -> Any:
    """Open the port (which resets the board: bootloader, then the sketch) and check HELLO."""
    import time

    import serial  # type: ignore[import-untyped]

    from armbridge.executor.session import open_session

    try:
        # Holding the port open keeps DTR up: the board resets once (now), and the HELLOs
        # wait for the sketch's BOOT line (bytes in the bootloader's window keep it there).
        with serial.Serial(port, 115200, timeout=0.1) as hold:
            seen, end = b"", time.monotonic() + max(timeout, 5.0)
            while b" BOOT " not in seen and time.monotonic() < end:
                seen = seen[-64:] + hold.read(256)
            with open_session(port, None, latched="allow", connect_timeout=max(timeout, 5.0)) as client:
                info = client.info
                assert info is not None
    except (ArmbridgeError, serial.SerialException) as exc:
        raise BoardFailure(f"the flashed board on {label} does not answer HELLO after its reset: {exc}") from None
    got, want = (info.fw, info.version, info.proto), (res.firmware, res.version, res.protocol)
    if got != want:
        raise BoardFailure(f"after the flash the board on {label} answers HELLO as {got[0]} {got[1]} (protocol "
                           f"{got[2]}), expected {want[0]} {want[1]} (protocol {want[2]})")
    return info


def _emu_options(port: str, board: str) -> dict[str, str]:
    name, _, query = port[len("emu:"):].partition("?")
    if name != board:
        raise ArmbridgeError(f"--port {port}: armbridge flash {board} flashes emu:{board}")
    opts = {k: v[-1] for k, v in parse_qs(query, keep_blank_values=True).items()}
    unknown = set(opts) - {"flash", "eeprom", "bootloader"}
    if unknown:
        raise ArmbridgeError(f"--port {port}: unknown option {sorted(unknown)[0]!r} (emu:{board} takes flash=FILE, "
                             "eeprom=FILE)")
    return opts


def flash_avrdude(target: AvrTarget, port: str, *, firmware_root: Path | None = None, timeout: float = 10.0,
                  progress: Callable[[str], None] | None = None, **_: Any) -> AvrResult:
    """Build, write and verify with avrdude, then check HELLO (docs/flash.md, "Arduino pump")."""
    hexfile, cfg = build_hex(target, firmware_root)
    res = AvrResult(hexfile, str(cfg.FW_NAME), str(cfg.FW_VERSION), int(cfg.AB_PROTOCOL_VERSION))
    if shutil.which("avrdude") is None:
        raise ArmbridgeError(f"avrdude is missing: run scripts/setup.sh as root, or: {AVRDUDE_APT}")
    if not port.startswith("emu:"):
        # The host's journal says "half-flashed" to `armbridge board` until avrdude has
        # written and verified the whole image (a cut-short write leaves a broken sketch).
        journal = Journal(port)
        journal.start(target.board, f"{res.firmware} {res.version}", 1)
        try:
            res.bytes_written = run_avrdude(target, port, hexfile, port, progress)
        except BoardFailure as exc:
            if NO_BOOTLOADER in str(exc):
                journal.done()  # nothing was written: the board holds what it held
            raise
        journal.done()
        res.hello = _hello(port, res, port, timeout)
        return res
    from armbridge.emulator.simavr_chip import BootloaderChip

    opts = _emu_options(port, target.board)
    with tempfile.TemporaryDirectory(prefix="armbridge-avr-") as tmp:
        flash_file = Path(opts.get("flash") or Path(tmp) / "flash.bin")
        eeprom = Path(opts["eeprom"]) if opts.get("eeprom") else None
        with BootloaderChip(flash_file, eeprom) as chip:
            res.bytes_written = run_avrdude(target, chip.path, hexfile, port, progress)
            res.hello = _hello(chip.path, res, port, timeout)
    return res
