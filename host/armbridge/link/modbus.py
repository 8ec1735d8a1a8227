"""Modbus RTU to the syringe-pump board (docs/modbus.md): the `modbus:` port kind and its master.

    modbus:/dev/ttyUSB0?addr=1        a board already speaking Modbus on a serial device
    modbus:emu:arduino_pump?speed=0   the emulated board, switched into Modbus (MODBUS addr)

`open_modbus_port(url)` (the scheme table's opener, link/transport.py) opens the
port inside the url with `open_port` (so locks, pyserial URLs and the emulator all
work as for the line protocol) and returns a `ModbusPort`: the same Port, plus
`.master`, an `RtuMaster` talking to device `addr`.

Why our own master over pymodbus's PDUs, not pymodbus's client: the client opens
its own serial device, and the port here may be an emulator's pty on its own clock
or a locked device; the frames are still built and decoded by pymodbus
(`pymodbus.pdu` requests, `FramerRTU`, its CRC-16), and the tests check it against
pymodbus's own server. RTU timing: a request goes out only after t3.5 (1.75 ms
above 19200 baud, RTU spec) of line silence; a reply is complete when its length
(known from the function code) has arrived with a good CRC; a damaged or missing
reply is retried (`retries`), an exception reply is a `ModbusError` at once.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qsl, urlencode

from pymodbus.framer import FramerRTU
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.pdu.register_message import (ReadHoldingRegistersRequest, ReadInputRegistersRequest,
                                           WriteMultipleRegistersRequest, WriteSingleRegisterRequest)

from armbridge.errors import ArmbridgeError
from armbridge.link.transport import DEFAULT_BAUD, Port

EXCEPTION_NAMES = {1: "ILLEGAL FUNCTION", 2: "ILLEGAL DATA ADDRESS", 3: "ILLEGAL DATA VALUE",
                   4: "SERVER DEVICE FAILURE", 6: "SERVER DEVICE BUSY"}
URL_PARAMS = ("addr", "baud", "timeout", "retries")


class ModbusError(ArmbridgeError):
    """An exception reply (`code` 1..11) or no valid reply (`code` None)."""

    def __init__(self, message: str, code: int | None = None) -> None:
        super().__init__(message)
        self.code = code


def t35_s(baud: int) -> float:
    """The RTU inter-frame silence: 3.5 characters of 11 bits, 1.75 ms above 19200 baud."""
    return 0.00175 if baud > 19200 else 38.5 / baud


def to_u16(value: int) -> int:
    """A signed value as its int16 two's complement register (ArmbridgeError outside int16/uint16)."""
    v = int(value)
    if not -32768 <= v <= 65535:
        raise ArmbridgeError(f"{v} does not fit a 16-bit register")
    return v & 0xFFFF


def to_i16(reg: int) -> int:
    """A register read as int16 two's complement."""
    return reg - 65536 if reg >= 32768 else reg


@dataclass
class MasterStats:
    requests: int = 0  # frames written, retries included
    retries: int = 0
    timeouts: int = 0  # no complete reply in time
    bad_replies: int = 0  # CRC wrong, or a reply that does not match the request
    exceptions: int = 0


class RtuMaster:
    """A Modbus RTU master for one device over a byte `Port` (read/write/in_waiting)."""

    def __init__(self, port: Any, addr: int, *, baud: int | None = None, timeout: float = 0.25, retries: int = 2,
                 clock: Callable[[], float] | None = None) -> None:
        if not 0 <= addr <= 247:
            raise ArmbridgeError(f"Modbus address {addr} is outside 1..247 (0: broadcast)")
        self.port = port
        self.addr = addr
        self.baud = int(baud or getattr(port, "baudrate", DEFAULT_BAUD) or DEFAULT_BAUD)
        self.gap = t35_s(self.baud)
        self.timeout = timeout
        self.retries = retries
        if clock is None:
            clock = getattr(port, "clock", None)
        self.now: Callable[[], float] = clock if callable(clock) else time.monotonic
        self.stats = MasterStats()
        self._framer = FramerRTU(DecodePDU(is_server=False))
        self._quiet_since = self.now()

    # ------------------------------------------------------------------ register access
    def read_holding(self, address: int, count: int = 1) -> list[int]:
        return list(self.request(ReadHoldingRegistersRequest(address=address, count=count)).registers)

    def read_input(self, address: int, count: int = 1) -> list[int]:
        return list(self.request(ReadInputRegistersRequest(address=address, count=count)).registers)

    def write_register(self, address: int, value: int, *, retries: int | None = None) -> None:
        self.request(WriteSingleRegisterRequest(address=address, registers=[to_u16(value)]), retries=retries)

    def write_registers(self, address: int, values: Sequence[int], *, retries: int | None = None) -> None:
        self.request(WriteMultipleRegistersRequest(address=address, registers=[to_u16(v) for v in values]),
                     retries=retries)

    def broadcast_register(self, address: int, value: int) -> None:
        """FC6 to address 0: every board on the line executes it, none answers."""
        pdu = WriteSingleRegisterRequest(address=address, registers=[to_u16(value)], dev_id=0)
        self._send(self._framer.buildFrame(pdu))

    # ------------------------------------------------------------------ frames
    def request(self, pdu: ModbusPDU, *, retries: int | None = None) -> ModbusPDU:
        """Send `pdu` to our device and return its reply PDU; retried on silence or a
        damaged reply; an exception reply raises ModbusError(code)."""
        pdu.dev_id = self.addr
        frame = self._framer.buildFrame(pdu)
        tries = 1 + (self.retries if retries is None else retries)
        why = "no reply"
        for attempt in range(tries):
            if attempt:
                self.stats.retries += 1
            self._send(frame)
            reply, why = self._receive(pdu)
            if reply is None:
                continue
            if isinstance(reply, ExceptionResponse) or reply.isError():
                self.stats.exceptions += 1
                code = int(reply.exception_code)
                raise ModbusError(f"device {self.addr} answered function {pdu.function_code} at register "
                                  f"{pdu.address} with exception {code:02d} {EXCEPTION_NAMES.get(code, '')}".rstrip(),
                                  code)
            return reply
        raise ModbusError(f"device {self.addr} did not answer function {pdu.function_code} at register {pdu.address} "
                          f"({why}, {tries} tries of {self.timeout * 1000:.0f} ms): is it on this port, at this "
                          f"address and baud rate, and speaking Modbus RTU?")

    def idle(self, seconds: float) -> None:
        """Wait about `seconds` by reading the port (a late byte is dropped: no request is
        open). Reading, not sleeping: a lockstep emulator runs only while its host reads."""
        saved = getattr(self.port, "timeout", None)
        self.port.timeout = max(0.0005, min(seconds, 0.01))
        try:
            if self.port.read(64):
                self._quiet_since = self.now()
        finally:
            self.port.timeout = saved

    def _send(self, frame: bytes) -> None:
        while self.now() - self._quiet_since < self.gap:  # t3.5 of silence before a frame
            self.idle(self.gap / 4)
        try:
            stale = self.port.in_waiting
            if stale:
                self.port.read(stale)  # a late reply to an earlier try: not ours now
        except (OSError, AttributeError):
            pass
        self.port.write(frame)
        self.stats.requests += 1
        self._quiet_since = self.now()

    def _expected(self, buf: bytes) -> int | None:
        """The reply's length from its first bytes (None: not known yet)."""
        if len(buf) < 2:
            return None
        fc = buf[1]
        if fc & 0x80:
            return 5
        if fc in (3, 4):
            return 5 + buf[2] if len(buf) >= 3 else None
        return 8

    def _receive(self, req: ModbusPDU) -> tuple[ModbusPDU | None, str]:
        buf = b""
        end = self.now() + self.timeout
        saved = getattr(self.port, "timeout", None)
        self.port.timeout = 0.002
        try:
            while True:
                need = self._expected(buf)
                if need is not None and len(buf) >= need:
                    self._quiet_since = self.now()
                    return self._decode(req, buf[:need])
                if self.now() > end:
                    self.stats.timeouts += 1
                    return None, "a partial reply" if buf else "no reply"
                chunk = self.port.read(max(1, (need or 2) - len(buf)))
                if chunk:
                    buf += chunk
                    self._quiet_since = self.now()
        finally:
            self.port.timeout = saved

    def _decode(self, req: ModbusPDU, frame: bytes) -> tuple[ModbusPDU | None, str]:
        crc = int.from_bytes(frame[-2:], "big")
        if not FramerRTU.check_CRC(frame[:-2], crc) or frame[0] != self.addr:
            self.stats.bad_replies += 1
            return None, "a damaged reply (CRC)" if frame[0] == self.addr else f"a reply from device {frame[0]}"
        pdu = self._framer.decoder.decode(frame[1:-2])
        if pdu is None or (pdu.function_code & 0x7F) != req.function_code:
            self.stats.bad_replies += 1
            return None, "a reply to another request"
        if not pdu.isError():
            if req.function_code in (3, 4) and len(pdu.registers) != req.count:
                self.stats.bad_replies += 1
                return None, "a reply of the wrong length"
            if req.function_code in (6, 16) and pdu.address != req.address:
                self.stats.bad_replies += 1
                return None, "a reply to another request"
        return pdu, ""


# ---------------------------------------------------------------------- the port kind
class ModbusPort(Port):
    """The port named inside a `modbus:` url, taken over, with `.master` (an RtuMaster)."""

    def __init__(self, inner: Port, url: str, addr: int, timeout: float, retries: int) -> None:
        super().__init__(inner._ser, url, inner.emulator, clock=inner.clock, lock=inner._lock)
        inner._lock = None  # ours to release now
        self.inner_url = inner.url
        self.master = RtuMaster(self, addr, timeout=timeout, retries=retries)


def parse_modbus_url(url: str) -> tuple[str, dict[str, Any]]:
    """'modbus:emu:arduino_pump?speed=0&addr=2' -> ('emu:arduino_pump?speed=0', {'addr': 2, ...}).
    Our parameters (addr, baud, timeout in ms, retries) are taken out; the rest stays with the inner port."""
    rest = url.split(":", 1)[1] if ":" in url else ""
    if not rest:
        raise ArmbridgeError(f"port {url!r} names no port after 'modbus:': give modbus:/dev/ttyUSB0?addr=1 or "
                             "modbus:emu:arduino_pump")
    inner, _, query = rest.partition("?")
    ours: dict[str, Any] = {"addr": 1, "baud": DEFAULT_BAUD, "timeout": 0.25, "retries": 2}
    keep = []
    for key, value in parse_qsl(query, keep_blank_values=True):
        if key not in URL_PARAMS:
            keep.append((key, value))
            continue
        try:
            n = int(value)
        except ValueError:
            raise ArmbridgeError(f"{key}={value!r} in {url!r} is not an integer") from None
        limits = {"addr": (1, 247), "baud": (1200, 4000000), "timeout": (1, 60000), "retries": (0, 10)}[key]
        if not limits[0] <= n <= limits[1]:
            raise ArmbridgeError(f"{key}={n} in {url!r} is outside {limits[0]}..{limits[1]}")
        ours[key] = n / 1000.0 if key == "timeout" else n
    return (inner + ("?" + urlencode(keep) if keep else "")), ours


def open_modbus_port(url: str, baud: int = DEFAULT_BAUD, timeout: float | None = 0.1) -> ModbusPort:
    """The scheme table's opener: open the inner port, reach the board over Modbus (an
    emulated board is switched into Modbus first: HELLO, then `MODBUS addr`)."""
    from armbridge.link.transport import open_port

    inner_url, p = parse_modbus_url(url)
    if inner_url.startswith("modbus:"):
        raise ArmbridgeError(f"port {url!r}: a modbus: port inside a modbus: port")
    inner = open_port(inner_url, p["baud"], timeout)
    return ModbusPort(inner, url, p["addr"], p["timeout"], p["retries"])
