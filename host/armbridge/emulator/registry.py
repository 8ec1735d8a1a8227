"""How the emulator emulates each board: one `BoardSpec` per board in `BOARDS`.

What a board is (its name, identity, firmware, rigs, baud, persisted memory)
is boards/'s (`armbridge.boards.BOARDS`); this registry adds only how to
emulate it, registered against the board's name: how to build its plant and
its HAL from the firmware's config, per rig, and the plant's defaults. A
`BoardSpec` is the two together, the emulator's one view of a board.

A new board plugs in with its entry in boards/ and one entry here (its own
plant/HAL modules); `EmulatedBoard` also takes a `BoardSpec` directly, so a
variant of a board (another plant, other initial positions) needs no
registration and no copy:

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

from armbridge import boards
from armbridge.boards import ElfFirmware, MicroPythonFirmware, joint_limits_rad
from armbridge.emulator.plant import PlantParams, ServoPlant
from armbridge.emulator.plant import hidden_truth as servo_truth
from armbridge.emulator.simhal import RTC_MEMORY_SIZE, SimHal
from armbridge.errors import ArmbridgeError

__all__ = ["BOARDS", "BoardSpec", "ElfFirmware", "MicroPythonFirmware", "Rig", "board_spec", "known_boards",
           "rig_spec"]


class Plant(Protocol):
    """What the emulator needs of a plant (ServoPlant is one)."""

    n: int
    q: np.ndarray

    def advance_to(self, t: float) -> None: ...

    def stall(self, j: int, t: float) -> None: ...


PlantFactory = Callable[..., Plant]   # (cfg, params, q0, seed) -> Plant
HalFactory = Callable[..., Any]       # (clock, plant, uart, persist, *, tick_offset_ms, on_line, files) -> HAL
TruthFactory = Callable[..., Any]     # (cfg, rng) -> the plant's parameters drawn from its SPREADS (truth.py)


def servo_plant(cfg, params: PlantParams | None, q0, seed: int) -> ServoPlant:
    """The servo plant of docs/emulator.md, its hard stops around the firmware's limits."""
    lo, hi = joint_limits_rad(cfg)
    return ServoPlant(lo, hi, params, q0=q0, seed=seed)


@dataclass(frozen=True)
class Rig:
    """How to emulate one rig of a board: its plant and HAL factories (as BoardSpec's),
    with the rig's facts (description, interpreters) from boards/."""

    description: str
    plant: PlantFactory
    hal: HalFactory
    truth: TruthFactory
    interpreters: tuple[str, ...]


def _pca_truth(cfg, rng) -> Any:
    from armbridge.emulator.servo_plant import hidden_truth
    return hidden_truth(cfg, rng)


def _ma_truth(cfg, rng) -> Any:
    from armbridge.emulator.ma_plant import hidden_truth
    return hidden_truth(cfg, rng)


def _pump_truth(cfg, rng) -> Any:
    from armbridge.emulator.pump_plant import hidden_truth
    return hidden_truth(cfg, rng)


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


#: board name -> rig name -> (plant factory, HAL factory, hidden-truth factory): how each rig is emulated
EMULATIONS: dict[str, dict[str, tuple[PlantFactory, HalFactory, TruthFactory]]] = {
    "esp32": {"effort": (servo_plant, SimHal, servo_truth), "pca9685": (_pca_plant, _pca_hal, _pca_truth)},
    "masr_ma": {"effort": (_ma_plant, _ma_hal, _ma_truth)},
    "arduino_pump": {"effort": (_pump_plant, _pump_hal, _pump_truth)},
}


@dataclass(frozen=True)
class BoardSpec:
    """One emulated board; see the module docstring.

    name: the DEVICE of `armbridge emulate DEVICE` and `emu:DEVICE`.
    identity: the firmware name the board reports (BOOT, HELLO), for messages and checks.
    plant(cfg, params, q0, seed), hal(clock, plant, uart, persist, tick_offset_ms=, on_line=):
    factories; q0 / plant_params: defaults handed to the plant (None: the plant's own);
    truth(cfg, rng): the plant's parameters drawn from its spreads (`plant=random`, truth.py).
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
    truth: TruthFactory = servo_truth
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


def _spec(b: boards.Board) -> BoardSpec:
    """The emulator's spec of board `b`: its facts and how each of its rigs is emulated."""
    emulation = EMULATIONS[b.name]
    plant, hal, truth = emulation[b.rig]
    rigs = {name: Rig(fact.description, *emulation[name], fact.interpreters) for name, fact in b.rigs.items()}
    return BoardSpec(name=b.name, description=b.description, identity=b.identity, firmware=b.firmware,
                     plant=plant, hal=hal, truth=truth, baud=b.baud, tick_us=b.tick_us, persist_bytes=b.persist_bytes,
                     rig=b.rig, rigs=rigs)


BOARDS: dict[str, BoardSpec] = {name: _spec(b) for name, b in boards.BOARDS.items() if name in EMULATIONS}


def known_boards() -> str:
    return ", ".join(sorted(BOARDS))



def board_spec(device: str | BoardSpec) -> BoardSpec:
    """The spec of `device` (a name in BOARDS, or a BoardSpec, returned as is); an unknown name
    is boards.board's one error naming the known ones."""
    if isinstance(device, BoardSpec):
        return device
    spec = BOARDS.get(device) if isinstance(device, str) else None
    return spec if spec is not None else BOARDS[boards.board(device).name]


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
    return replace(spec, plant=rig.plant, hal=rig.hal, truth=rig.truth, plant_params=None, rig=name, firmware=fw)
