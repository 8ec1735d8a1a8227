"""Writing a MicroPython image to the chip with esptool 5 (`--micropython IMAGE`).

The ESP32 boards' MicroPython 1.29 image (micropython.org/download/ESP32_GENERIC,
`ESP32_GENERIC-20xx-v1.29.x.bin`) holds the second-stage bootloader, the
partition table and MicroPython; on the classic ESP32 it goes at flash offset
0x1000 (the ROM loads the bootloader from there; ESP32-S2/S3/C3 images go at
0x0). esptool 5 spells its commands with dashes:

    python -m esptool --chip esp32 --port PORT --baud 460800 write-flash -z 0x1000 IMAGE

(-z: the image is sent compressed; esptool verifies each block's MD5 after
writing). It needs the chip's ROM bootloader (DTR/RTS on the USB bridge put
the chip there), which no emulator here has: `esptool_argv` is tested, the
chip is not. A first install on a board with other firmware may need
`python -m esptool --chip esp32 --port PORT erase-flash` first.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from armbridge.errors import ArmbridgeError, BoardFailure

ESP_IMAGE_MAGIC = 0xE9   # the first byte of an ESP bootloader/app image
BAUD = 460800


def check_image(image: str | Path) -> Path:
    """The image file, or one ArmbridgeError naming what is wrong with it."""
    p = Path(image)
    if not p.exists():
        raise ArmbridgeError(f"--micropython {image}: no such file")
    if not p.is_file():
        raise ArmbridgeError(f"--micropython {image}: not a file")
    with p.open("rb") as f:
        head = f.read(1)
    if not head:
        raise ArmbridgeError(f"--micropython {image}: the file is empty")
    if head[0] != ESP_IMAGE_MAGIC:
        raise ArmbridgeError(f"--micropython {image}: not an ESP32 firmware image (its first byte is "
                             f"0x{head[0]:02X}, an ESP image starts with 0x{ESP_IMAGE_MAGIC:02X}); "
                             "use the .bin from micropython.org/download/ESP32_GENERIC")
    return p


def esptool_argv(image: str | Path, port: str, chip: str = "esp32", offset: int = 0x1000,
                 baud: int = BAUD) -> list[str]:
    """The esptool 5 command line that writes `image` at `offset` (see the module docstring)."""
    p = check_image(image)
    return [sys.executable, "-m", "esptool", "--chip", chip, "--port", port, "--baud", str(baud),
            "write-flash", "-z", f"0x{offset:x}", str(p)]


def write_image(image: str | Path, port: str, chip: str, offset: int, timeout: float = 300.0) -> None:
    """Run esptool; its failure is one BoardFailure with esptool's last line."""
    argv = esptool_argv(image, port, chip, offset)
    try:
        import esptool  # type: ignore[import-untyped]  # noqa: F401  (only to say it is missing)
    except ImportError:
        raise ArmbridgeError('--micropython needs esptool 5: pip install "esptool>=5,<6" '
                             '(or pip install "armbridge[flash]")') from None
    try:
        r = subprocess.run(argv, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise BoardFailure(f"esptool did not finish writing {image} to {port} within {timeout:g} s") from None
    if r.returncode != 0:
        lines = [ln for ln in (r.stderr + r.stdout).strip().splitlines() if ln.strip()]
        raise BoardFailure(f"esptool could not write {image} to {port}: {lines[-1] if lines else r.returncode}")
