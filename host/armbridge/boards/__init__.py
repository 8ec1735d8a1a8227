"""What a board is, as data: one `Board` per board in `BOARDS` (as robots/catalog.py is for robots).

A board is its name (the DEVICE of `armbridge flash|emulate DEVICE` and
`emu:DEVICE`), the firmware name it reports in BOOT and HELLO (`identity`),
the robot it drives, where its firmware is (`MicroPythonFirmware`: folders
searched in order, its board and config modules; `ElfFirmware`: a C folder,
its Makefile, the .elf it builds and its config header), its rigs (the
hardware its firmware can drive, chosen by its config: the esp32's SERVOS),
its UART's baud and the memory it keeps across a reset. Its constants (joint
limits, control period, watchdog, pins ...) are its firmware's own config,
read as data (`config`, boards/config.py), so every reader sees what the board
runs with.

Everything that needs a board fact reads it here: flashing, the console, the
executor, planning, IK, the benchmarks, and the emulator, which keeps only how
to emulate a board (plants, HALs, runners) and registers that against these
names. A host without the emulator can flash and run a real board.
"""
from __future__ import annotations

import types
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from armbridge.boards.config import read_config_h, read_micropython_config
from armbridge.errors import ArmbridgeError

__all__ = ["BOARDS", "Board", "ElfFirmware", "MicroPythonFirmware", "Rig", "board", "boards_of_robot", "config",
           "joint_limits_rad", "names", "of_identity", "register"]


@dataclass(frozen=True)
class MicroPythonFirmware:
    """MicroPython firmware: `dirs` under the firmware root, searched in order
    (flat module names); `board_module` defines `Board(hal, cfg)`;
    `config_module` holds the board's constants (N_JOINTS, LIMITS_MRAD, PERIOD_MS ...)."""

    dirs: tuple[str, ...]
    board_module: str = "arm"
    config_module: str = "config"
    interpreters: tuple[str, ...] = ("cpython", "micropython")  # the first is the default


@dataclass(frozen=True)
class ElfFirmware:
    """C firmware: `folder` under the firmware root holds the Makefile that builds `elf`
    (relative to the folder); `config` is the header whose `#define`s are the board's
    constants (N_JOINTS, PERIOD_MS, the limits, the pins)."""

    folder: str
    elf: str
    interpreters: tuple[str, ...] = ("simavr",)
    config: str = "config.h"


@dataclass(frozen=True)
class Rig:
    """One rig of a board: what the hardware is, and the interpreters that can carry its
    HAL in the emulator (a rig whose HAL the MicroPython bridge does not carry: cpython)."""

    description: str
    interpreters: tuple[str, ...]


@dataclass(frozen=True)
class Board:
    """One board; see the module docstring. `rig` is the default rig (its config's), `rigs`
    every rig by name; `tick_us`: one emulator iteration; `persist_bytes`: memory kept
    across a reset (RTC memory on the ESP32, EEPROM on the Mega)."""

    name: str
    description: str
    identity: str
    robot: str
    firmware: MicroPythonFirmware | ElfFirmware
    rig: str = "effort"
    rigs: dict[str, Rig] = field(default_factory=dict, hash=False, compare=False)
    baud: int = 115200
    tick_us: int = 1000
    persist_bytes: int = 4096

    @property
    def interpreters(self) -> tuple[str, ...]:
        return self.firmware.interpreters


ESP32_RTC_MEMORY = 2048  # bytes the ESP32 keeps across a reset (machine.RTC().memory())

BOARDS: dict[str, Board] = {}


def register(b: Board) -> Board:
    """Add a board to the registry (a new board is one entry and its firmware folder)."""
    BOARDS[b.name] = b
    return b


register(Board(
    name="esp32", description="3R servo arm, ESP32, MicroPython", identity="arm3r", robot="arm3r",
    firmware=MicroPythonFirmware(dirs=("esp32", "common")), persist_bytes=ESP32_RTC_MEMORY,
    rigs={"effort": Rig("continuous servos driven by effort, potentiometer feedback (hal_esp32.Esp32Hal)",
                        ("cpython", "micropython")),
          # Under MicroPython the firmware's own PCA9685 driver runs there, on the bridged I2C bus.
          "pca9685": Rig("positional hobby servos behind a PCA9685 on I2C, the paper's rig (hal_pca9685.Pca9685Hal)",
                         ("cpython", "micropython"))}))
# The MicroPython bridge carries the MA's HAL too (counts and hall edges in, loco/rot/grip out).
register(Board(
    name="masr_ma", description="MASR mobile actuator, ESP32, MicroPython", identity="masr_ma", robot="masr5",
    firmware=MicroPythonFirmware(dirs=("masr_ma", "common"), board_module="ma"),
    persist_bytes=ESP32_RTC_MEMORY))
register(Board(
    name="arduino_pump", description="soft arm's syringe-pump board, Arduino Mega 2560, C++ in simavr",
    identity="arduino_pump", robot="soft3", firmware=ElfFirmware(folder="arduino_pump", elf="build/arduino_pump.elf"),
    persist_bytes=4096))  # the ATmega2560's EEPROM


def names() -> list[str]:
    return sorted(BOARDS)


def board(name: str | Board) -> Board:
    """The board called `name` (a Board is returned as is); an unknown name is one
    ArmbridgeError naming the known ones."""
    if isinstance(name, Board):
        return name
    try:
        return BOARDS[name]
    except (KeyError, TypeError):
        raise ArmbridgeError(f"unknown device {name!r}; known devices: {', '.join(names())}") from None


def of_identity(fw: str) -> str | None:
    """The board whose firmware reports `fw` in BOOT and HELLO (its identity, or its name), None."""
    for b in BOARDS.values():
        if b.identity == fw or b.name == fw:
            return b.name
    return None


def boards_of_robot(robot: str) -> tuple[str, ...]:
    """The firmware names (identities) of the boards that drive the robot called `robot`."""
    return tuple(b.identity for b in BOARDS.values() if b.robot == robot)


def config(b: str | Board, root: Path | None = None) -> types.SimpleNamespace:
    """The board's constants, read as data from its firmware under `root` (default: the
    shipped firmware, armbridge.resources.firmware_dir)."""
    b = board(b)
    if root is None:
        from armbridge.resources import firmware_dir

        root = firmware_dir()
    fw = b.firmware
    if isinstance(fw, ElfFirmware):
        return read_config_h(root / fw.folder / fw.config)
    for d in fw.dirs:
        path = root / d / f"{fw.config_module}.py"
        if path.is_file():
            return read_micropython_config(path)
    raise ArmbridgeError(f"the {b.name} board's config {fw.config_module}.py is in none of "
                         f"{', '.join(str(root / d) for d in fw.dirs)}")


def joint_limits_rad(cfg) -> tuple[np.ndarray, np.ndarray]:
    """Joint limits (rad) from the firmware config (LIMITS_MRAD: ((min, max), ...) in mrad)."""
    lims = np.asarray(cfg.LIMITS_MRAD, dtype=float) / 1000.0
    n = int(getattr(cfg, "N_JOINTS", len(lims)))
    if lims.shape != (n, 2):
        raise ArmbridgeError(f"firmware config LIMITS_MRAD has shape {lims.shape}, expected ({n}, 2)")
    return lims[:, 0], lims[:, 1]
