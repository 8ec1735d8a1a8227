"""Raw Modbus RTU frames to an emulated board in lockstep (no master, no pymodbus):
what the tests that probe the firmware byte by byte share (docs/modbus.md)."""
from __future__ import annotations


def crc16(data: bytes) -> bytes:
    """CRC-16/MODBUS bit by bit (independent of pymodbus and of the firmware), low byte first."""
    c = 0xFFFF
    for b in data:
        c ^= b
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
    return bytes([c & 0xFF, c >> 8])


def rtu(emu, pdu: bytes) -> bytes:
    """One request frame (address and PDU, the CRC added); the board's reply, after
    t3.5 of silence on both sides."""
    emu.advance(0.005)
    emu.read_output()
    emu.inject(pdu + crc16(pdu))
    emu.advance(0.03)
    return emu.read_output()


def inputs(emu, addr: int, n: int, unit: int = 1) -> list[int]:
    """FC4: n input registers from addr."""
    r = rtu(emu, bytes([unit, 4, addr >> 8, addr & 0xFF, 0, n]))
    assert r[:3] == bytes([unit, 4, 2 * n]) and crc16(r[:-2]) == r[-2:], r.hex()
    return [r[3 + 2 * i] << 8 | r[4 + 2 * i] for i in range(n)]
