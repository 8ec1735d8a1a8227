"""Emulated boards: a board's real firmware (MicroPython under CPython, or under
the real MicroPython interpreter) against a simulated HAL (clock, plant, paced
UART, persistent memory), served on a pseudo-terminal so a host cannot tell
them from a real board. Boards are data: `registry.BOARDS`.

    from armbridge.emulator import EmulatedBoard
    with EmulatedBoard("esp32", speed=1.0) as emu:
        print(emu.port)          # /dev/pts/N

See docs/emulator.md.
"""
from armbridge.emulator.board import EmulatedBoard
from armbridge.emulator.faults import Faults
from armbridge.emulator.plant import PlantParams, ServoPlant
from armbridge.emulator.registry import BOARDS, BoardSpec, MicroPythonFirmware, board_spec
from armbridge.emulator.uart import LinkFaults, PacedUart

__all__ = [
    "BOARDS",
    "BoardSpec",
    "EmulatedBoard",
    "Faults",
    "LinkFaults",
    "MicroPythonFirmware",
    "PacedUart",
    "PlantParams",
    "ServoPlant",
    "board_spec",
]
