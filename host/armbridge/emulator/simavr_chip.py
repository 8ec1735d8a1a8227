"""The simavr harness and the images it runs: the harness binary (built on first
use, keyed by its sources), a firmware folder's .elf (rebuilt when a source is
newer), and the Mega booting through its real stk500v2 bootloader behind a pty
(`BootloaderChip`, what `armbridge flash` drives avrdude against). The lockstep
runner of the emulator's boards is simavr_runner.py.
"""
from __future__ import annotations

import hashlib
import os
import select
import shutil
import subprocess
from pathlib import Path

from armbridge.buildcache import cache_dir, locked_build
from armbridge.errors import ArmbridgeError

APT = "apt-get install -y --no-install-recommends gcc-avr avr-libc binutils-avr arduino-core-avr simavr libsimavr-dev"
ANSWER_TIMEOUT_S = 30.0


def harness_source() -> Path:
    return Path(__file__).resolve().parent / "simavr"


def harness_binary() -> Path:
    """The harness, built on first use into the cache folder (keyed by its sources)."""
    src = harness_source()
    key = hashlib.sha256((src / "harness.c").read_bytes() + (src / "Makefile").read_bytes()).hexdigest()[:16]
    out = cache_dir() / f"simavr-harness-{key}"
    exe = out / "harness"
    if exe.is_file():
        return exe
    if not Path("/usr/include/simavr/sim_avr.h").is_file() or shutil.which("make") is None:
        raise ArmbridgeError(f"the simavr runner needs libsimavr-dev and make to build its harness; run "
                             f"scripts/setup.sh as root, or: {APT}")
    locked_build(["make", "-s", "-C", str(src), f"OUT={out}"], cache_dir() / "simavr-harness.lock",
                 "the simavr harness")
    return exe


def firmware_elf(folder: Path, elf: str) -> Path:
    """`folder/elf`, rebuilt with the folder's Makefile when a source is newer (in the
    folder when it is writable, else in a copy under the cache folder)."""
    if not (folder / "Makefile").is_file():
        raise ArmbridgeError(f"firmware folder {folder} has no Makefile")
    sources = [p for p in folder.rglob("*") if p.is_file() and "build" not in p.relative_to(folder).parts]
    target = folder / elf
    newest = max((p.stat().st_mtime for p in sources), default=0.0)
    if target.is_file() and target.stat().st_mtime >= newest:
        return target
    if shutil.which("avr-gcc") is None or shutil.which("make") is None:
        raise ArmbridgeError(f"{target} must be built and avr-gcc is missing; run scripts/setup.sh as root, or: {APT}")
    if not os.access(folder, os.W_OK):
        h = hashlib.sha256(b"".join(p.read_bytes() for p in sorted(sources))).hexdigest()[:16]
        copy = cache_dir() / f"elf-{folder.name}-{h}"
        if not (copy / elf).is_file():
            shutil.copytree(folder, copy, dirs_exist_ok=True, ignore=shutil.ignore_patterns("build"))
        folder, target = copy, copy / elf
    locked_build(["make", "-s", "-C", str(folder)], cache_dir() / f"elf-{folder.name}.lock", f"{folder.name}")
    if not target.is_file():
        raise ArmbridgeError(f"make -C {folder} did not produce {elf}")
    return target


MEGA_BOOTLOADER = Path("/usr/share/arduino/hardware/arduino/avr/bootloaders/stk500v2/stk500boot_v2_mega2560.hex")


class BootloaderChip:
    """The Mega booting through its stk500v2 bootloader (Debian's Arduino core) in the
    harness's boot mode: flash kept in `flash_file` (what avrdude writes survives, the
    next boot runs it), UART0 on a pty that resets the chip when opened (as DTR on a
    real board), paced to real time. `path` is the pty; no plant, no lockstep."""

    def __init__(self, flash_file: Path, eeprom_file: Path | None = None, bootloader: Path = MEGA_BOOTLOADER,
                 timeout: float = ANSWER_TIMEOUT_S) -> None:
        if not bootloader.is_file():
            raise ArmbridgeError(f"the Mega's bootloader {bootloader} is missing (Debian's arduino-core-avr); "
                                 f"run scripts/setup.sh as root, or: {APT}")
        args = [str(harness_binary()), "-B", str(flash_file), "-b", str(bootloader)]
        if eeprom_file is not None:
            args += ["-e", str(eeprom_file)]
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        line = self.proc.stdout.readline() if ready else ""
        if not line.startswith("PTY "):
            self.close()
            raise ArmbridgeError(f"the simavr harness did not boot the bootloader: {line.strip() or 'no answer'}")
        self.path = line.split(None, 1)[1].strip()

    def close(self) -> None:
        """Stop the chip (SIGTERM: the harness syncs the flash file and the EEPROM)."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def __enter__(self) -> "BootloaderChip":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
