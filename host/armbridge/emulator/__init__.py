"""Emulated boards: the real MicroPython firmware modules run under CPython
against a simulated HAL (clock, servo plant, paced UART, persistent memory),
served on a pseudo-terminal so a host cannot tell them from a real board.

    from armbridge.emulator import EmulatedBoard
    with EmulatedBoard("esp32", speed=1.0) as emu:
        print(emu.port)          # /dev/pts/N

See docs/emulator.md.
"""
from armbridge.emulator.board import DEVICES, EmulatedBoard, Faults
from armbridge.emulator.plant import PlantParams, ServoPlant
from armbridge.emulator.uart import LinkFaults, PacedUart

__all__ = [
    "DEVICES",
    "EmulatedBoard",
    "Faults",
    "LinkFaults",
    "PacedUart",
    "PlantParams",
    "ServoPlant",
]
