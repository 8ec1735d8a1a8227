"""The boards the emulator knows, as data: one `BoardSpec` per board in `BOARDS`.

A board is where its firmware is (`MicroPythonFirmware`: folders searched in
order, the module that defines `Board(hal, cfg)` and the config module; or
`ElfFirmware`: a folder with a Makefile and the .elf it builds, for a board in
C run under simavr), which interpreters can run that firmware, how to build its
plant and its HAL from the firmware's config, its clock (emulator tick, baud)
and its identity (the firmware name it reports in BOOT and HELLO).

A new board plugs in with one entry here and its own plant/HAL modules;
`EmulatedBoard` also takes a `BoardSpec` directly, so a variant of a board
(another plant, other initial positions) needs no registration and no copy:

    slow = dataclasses.replace(board_spec("esp32"), name="esp32-slow",
                               plant_params=PlantParams(v_servo=2.0))
    EmulatedBoard(slow, speed=0)

A board can have more than one rig (the hardware its firmware drives, chosen by
its config: the esp32's SERVOS): `BoardSpec.rigs` names them, and
`rig_spec(spec, name)` is the spec of the same board on another rig, its plant
and HAL swapped (`armbridge emulate esp32 --servos pca9685`, `emu:esp32?servos=pca9685`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Protocol

import numpy as np

from armbridge.emulator.plant import PlantParams, ServoPlant
from armbridge.emulator.simhal import RTC_MEMORY_SIZE, SimHal
from armbridge.errors import ArmbridgeError


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
    """C firmware: `folder` under the firmware root holds the Makefile that
    builds `elf` (relative to the folder); simavr runs the image. `config` is
    the header whose `#define`s are the board's constants for the emulator
    (simavr_runner.read_config_h: N_JOINTS, PERIOD_MS, the limits, the pins)."""

    folder: str
    elf: str
    interpreters: tuple[str, ...] = ("simavr",)
    config: str = "config.h"


class Plant(Protocol):
    """What the emulator needs of a plant (ServoPlant is one)."""

    n: int
    q: np.ndarray

    def advance_to(self, t: float) -> None: ...

    def stall(self, j: int, t: float) -> None: ...


PlantFactory = Callable[..., Plant]   # (cfg, params, q0, seed) -> Plant
HalFactory = Callable[..., Any]       # (clock, plant, uart, persist, *, tick_offset_ms, on_line, files) -> HAL


def joint_limits_rad(cfg) -> tuple[np.ndarray, np.ndarray]:
    """Joint limits (rad) from the firmware config (LIMITS_MRAD: ((min, max), ...) in mrad)."""
    lims = np.asarray(cfg.LIMITS_MRAD, dtype=float) / 1000.0
    n = int(getattr(cfg, "N_JOINTS", len(lims)))
    if lims.shape != (n, 2):
        raise ArmbridgeError(f"firmware config LIMITS_MRAD has shape {lims.shape}, expected ({n}, 2)")
    return lims[:, 0], lims[:, 1]


def servo_plant(cfg, params: PlantParams | None, q0, seed: int) -> ServoPlant:
    """The servo plant of docs/emulator.md, its hard stops around the firmware's limits."""
    lo, hi = joint_limits_rad(cfg)
    return ServoPlant(lo, hi, params, q0=q0, seed=seed)


@dataclass(frozen=True)
class Rig:
    """One rig of a board: its plant and HAL factories (as BoardSpec's) and the
    interpreters whose runners can carry its HAL."""

    description: str
    plant: PlantFactory
    hal: HalFactory
    interpreters: tuple[str, ...]


def _pca_plant(cfg, params, q0, seed: int) -> Any:
    from armbridge.emulator.pcahal import rig_plant  # pcahal imports runner, which imports this module
    return rig_plant(cfg, params, q0, seed)


def _pca_hal(*args: Any, **kw: Any) -> Any:
    from armbridge.emulator.pcahal import PcaSimHal
    return PcaSimHal(*args, **kw)


def _ma_plant(cfg, params, q0, seed: int) -> Any:
    from armbridge.emulator.ma_plant import ma_plant
    return ma_plant(cfg, params, q0, seed)


def _ma_hal(*args: Any, **kw: Any) -> Any:
    from armbridge.emulator.ma_hal import MaSimHal
    return MaSimHal(*args, **kw)


def _pump_plant(cfg, params, q0, seed: int) -> Any:
    from armbridge.emulator.pump_hal import pump_plant
    return pump_plant(cfg, params, q0, seed)


def _pump_hal(*args: Any, **kw: Any) -> Any:
    from armbridge.emulator.pump_hal import PumpSimHal
    return PumpSimHal(*args, **kw)


ESP32_RIGS: dict[str, Rig] = {
    "effort": Rig("continuous servos driven by effort, potentiometer feedback (hal_esp32.Esp32Hal)",
                  servo_plant, SimHal, ("cpython", "micropython")),
    # The MicroPython bridge replays write_outputs only: this rig runs under CPython.
    "pca9685": Rig("positional hobby servos behind a PCA9685 on I2C, the paper's rig (hal_pca9685.Pca9685Hal)",
                   _pca_plant, _pca_hal, ("cpython",)),
}


@dataclass(frozen=True)
class BoardSpec:
    """One emulated board; see the module docstring.

    name: the DEVICE of `armbridge emulate DEVICE` and `emu:DEVICE`.
    identity: the firmware name the board reports (BOOT, HELLO), for messages and checks.
    plant(cfg, params, q0, seed), hal(clock, plant, uart, persist, tick_offset_ms=, on_line=):
    factories; q0 / plant_params: defaults handed to the plant (None: the plant's own).
    tick_us: one emulator iteration in sim time; baud: the UART's (8N1 pacing);
    persist_bytes: memory that survives a reset (RTC memory on the ESP32).
    rig: the rig this spec emulates; rigs: every rig of the board (see rig_spec).
    """

    name: str
    description: str
    identity: str
    firmware: MicroPythonFirmware | ElfFirmware
    plant: PlantFactory = servo_plant
    hal: HalFactory = SimHal
    q0: tuple[float, ...] | None = None
    plant_params: PlantParams | None = None
    tick_us: int = 1000
    baud: int = 115200
    persist_bytes: int = RTC_MEMORY_SIZE
    rig: str = "effort"
    rigs: Mapping[str, Rig] = field(default_factory=dict, hash=False)

    @property
    def interpreters(self) -> tuple[str, ...]:
        return self.firmware.interpreters


BOARDS: dict[str, BoardSpec] = {
    spec.name: spec
    for spec in (
        BoardSpec(
            name="esp32",
            description="3R servo arm, ESP32, MicroPython",
            identity="arm3r",
            firmware=MicroPythonFirmware(dirs=("esp32", "common")),
            rigs=ESP32_RIGS,
        ),
        # The MicroPython bridge carries the arm's HAL (joint readings in, efforts
        # out), not the MA's (counts and hall edges in, loco/rot/grip out): cpython only.
        BoardSpec(
            name="masr_ma",
            description="MASR mobile actuator, ESP32, MicroPython",
            identity="masr_ma",
            firmware=MicroPythonFirmware(dirs=("masr_ma", "common"), board_module="ma", interpreters=("cpython",)),
            plant=_ma_plant,
            hal=_ma_hal,
        ),
        # The real .elf in simavr (simavr_runner.py) against the pneumatic plant
        # (pump_plant.py); the pins, limits and period are config.h's.
        BoardSpec(
            name="arduino_pump",
            description="soft arm's syringe-pump board, Arduino Mega 2560, C++ in simavr",
            identity="arduino_pump",
            firmware=ElfFirmware(folder="arduino_pump", elf="build/arduino_pump.elf"),
            plant=_pump_plant,
            hal=_pump_hal,
            persist_bytes=4096,   # the ATmega2560's EEPROM
        ),
    )
}


def known_boards() -> str:
    return ", ".join(sorted(BOARDS))


def board_spec(device: str | BoardSpec) -> BoardSpec:
    """The spec of `device` (a name in BOARDS, or a BoardSpec, returned as is)."""
    if isinstance(device, BoardSpec):
        return device
    try:
        return BOARDS[device]
    except (KeyError, TypeError):
        raise ArmbridgeError(f"unknown device {device!r}; known devices: {known_boards()}") from None


def rig_spec(spec: BoardSpec, name: str | None) -> BoardSpec:
    """`spec`'s board on the rig `name` (None: as it is). An unknown rig is one
    ArmbridgeError naming the board's rigs."""
    if name is None or name == spec.rig:
        return spec
    rig = spec.rigs.get(name)
    if rig is None:
        known = ", ".join(sorted(set(spec.rigs) | {spec.rig}))
        raise ArmbridgeError(f"unknown rig {name!r} for the {spec.name} board; known rigs: {known}")
    fw = spec.firmware
    if isinstance(fw, MicroPythonFirmware):
        fw = replace(fw, interpreters=rig.interpreters)
    return replace(spec, plant=rig.plant, hal=rig.hal, plant_params=None, rig=name, firmware=fw)
