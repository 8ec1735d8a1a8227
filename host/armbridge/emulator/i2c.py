"""A simulated I2C bus with the subset of MicroPython's `machine.I2C` that
register-based drivers use: `writeto_mem`, `readfrom_mem`,
`readfrom_mem_into`, `scan` (8-bit register addresses).

Devices attach at 7-bit addresses and see register transfers (`I2CDevice`:
`write(reg, data)` and `read(reg, n)`). A transfer to an address where no
device answers raises `OSError(ENODEV)`, as MicroPython's ESP32 port does
(`OSError: [Errno 19] ENODEV`) when the address byte is not acknowledged.

Hooks: `before()` runs before every transfer and `after()` after every write,
so a HAL can bring its plant up to the transfer's time and then let it see the
new register contents. `transfers` counts them and `bits` the bits on the wire
(9 per byte with ACK, plus start and stop), so `bus_time_us()` is the wire time
at `freq` (400 kHz: 27.5 us for a 1-byte register write).
"""
from __future__ import annotations

import errno
from typing import Callable, Protocol


class I2CDevice(Protocol):
    def write(self, reg: int, data: bytes) -> None: ...

    def read(self, reg: int, n: int) -> bytes: ...


def _check_addr(addr: int) -> None:
    if not (isinstance(addr, int) and 0 <= addr < 0x80):
        raise ValueError(f"I2C address {addr!r} is not a 7-bit address")


class SimI2C:
    """The bus: devices by address, MicroPython's method names and errors."""

    def __init__(self, freq: int = 400_000, before: Callable[[], None] | None = None,
                 after: Callable[[], None] | None = None) -> None:
        self.freq = int(freq)
        self.devices: dict[int, I2CDevice] = {}
        self.before = before
        self.after = after
        self.transfers = 0
        self.bits = 0

    def attach(self, addr: int, device: I2CDevice) -> None:
        _check_addr(addr)
        if addr in self.devices:
            raise ValueError(f"I2C address 0x{addr:02x} is taken")
        self.devices[addr] = device

    def bus_time_us(self) -> float:
        """Wire time of every transfer so far, in us."""
        return self.bits * 1e6 / self.freq

    def _device(self, addr: int) -> I2CDevice:
        _check_addr(addr)
        if self.before is not None:
            self.before()
        dev = self.devices.get(addr)
        self.transfers += 1
        if dev is None:
            self.bits += 2 + 9          # start, address byte NACKed, stop
            raise OSError(errno.ENODEV, "ENODEV")
        return dev

    # ------------------------------------------------------------ machine.I2C
    def scan(self) -> list[int]:
        return sorted(self.devices)

    def writeto_mem(self, addr: int, memaddr: int, buf, *, addrsize: int = 8) -> None:
        dev = self._device(addr)
        data = bytes(buf)
        self.bits += 2 + 9 * (1 + addrsize // 8 + len(data))
        dev.write(int(memaddr), data)
        if self.after is not None:
            self.after()

    def readfrom_mem(self, addr: int, memaddr: int, nbytes: int, *, addrsize: int = 8) -> bytes:
        dev = self._device(addr)
        self.bits += 3 + 9 * (2 + addrsize // 8 + nbytes)   # write the pointer, repeated start, read
        return bytes(dev.read(int(memaddr), int(nbytes)))

    def readfrom_mem_into(self, addr: int, memaddr: int, buf, *, addrsize: int = 8) -> None:
        buf[:] = self.readfrom_mem(addr, memaddr, len(buf), addrsize=addrsize)
