"""Byte transports to a board: `open_port(url)`.

A url is one of
  /dev/ttyUSB0, COM3        a serial device
  socket://host:port, loop://, rfc2217://...   any pyserial URL (serial.serial_for_url)
  emu:DEVICE[?k=v&...]      an emulated board started in this process, on its own pty

Parameters of emu: URLs (all optional):
  speed=K        clock mode: 1 wall clock (default), K times faster, 0 as fast as it goes
  drop=R corrupt=R dup=R   byte fault rates in [0, 1]
  delay=R:MS     a fraction R of bytes delayed MS milliseconds (or delay=R&delay_ms=MS)
  lanes=rx,tx    which directions get the link faults (default both)
  seed=N         seed of plant noise and link faults
  reset_at=S[,S] sim seconds at which the board resets
  stall=J@S[,J@S]  joint J (1..n) stalls at sim second S
  link=PATH      a symlink to the pty

The returned `Port` has read(n), write(b), in_waiting, timeout, baudrate, reset_input_buffer(),
close() (which also stops an in-process emulator) and `.emulator`
(the EmulatedBoard, or None).
"""
from __future__ import annotations

from typing import Any
from urllib.parse import parse_qsl, urlsplit

import serial  # type: ignore[import-untyped]

from armbridge.errors import ArmbridgeError

DEFAULT_BAUD = 115200


class Port:
    """A byte link to a board (a thin wrapper over a pyserial object)."""

    def __init__(self, ser: Any, url: str, emulator: Any = None) -> None:
        self._ser = ser
        self.url = url
        self.emulator = emulator

    def read(self, n: int = 1) -> bytes:
        """Up to n bytes; waits at most `timeout` seconds for them."""
        return self._ser.read(n)

    def write(self, data: bytes) -> int:
        n = self._ser.write(data)
        return len(data) if n is None else n

    def flush(self) -> None:
        self._ser.flush()

    @property
    def in_waiting(self) -> int:
        return self._ser.in_waiting

    @property
    def baudrate(self) -> int:
        return int(getattr(self._ser, "baudrate", DEFAULT_BAUD) or DEFAULT_BAUD)

    @property
    def timeout(self) -> float | None:
        return self._ser.timeout

    @timeout.setter
    def timeout(self, value: float | None) -> None:
        self._ser.timeout = value

    def reset_input_buffer(self) -> None:
        self._ser.reset_input_buffer()

    @property
    def is_open(self) -> bool:
        return bool(self._ser.is_open)

    def close(self) -> None:
        try:
            self._ser.close()
        finally:
            if self.emulator is not None:
                self.emulator.stop()

    def __enter__(self) -> "Port":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Port({self.url!r})"


def open_port(url: str, baud: int = DEFAULT_BAUD, timeout: float | None = 0.1) -> Port:
    """Open a serial device, a pyserial URL or an in-process emulator (`emu:DEVICE?...`)."""
    if not url or not url.strip():
        raise ArmbridgeError("empty port: give a serial device, a pyserial URL or emu:DEVICE")
    url = url.strip()
    if url.startswith("emu:"):
        return _open_emulator(url, baud, timeout)
    try:
        ser = serial.serial_for_url(url, baudrate=baud, timeout=timeout)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise ArmbridgeError(f"cannot open port {url!r}: {exc}") from exc
    return Port(ser, url)


def parse_emu_url(url: str) -> tuple[str, dict[str, Any]]:
    """'emu:esp32?speed=4&drop=0.01' -> ('esp32', {EmulatedBoard keyword arguments})."""
    from armbridge.emulator.board import Faults, device_spec, parse_delay, parse_rate, parse_stall

    parts = urlsplit(url)
    device = parts.path or parts.netloc
    if not device:
        raise ArmbridgeError(f"bad port {url!r}: expected emu:DEVICE[?key=value&...]")
    device_spec(device)  # unknown device -> ArmbridgeError naming the known ones
    try:
        params = parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError as exc:
        raise ArmbridgeError(f"bad port {url!r}: {exc}") from exc
    kw: dict[str, Any] = {}
    fk: dict[str, Any] = {}
    for key, value in params:
        where = f"port {url!r}, parameter {key}"
        try:
            if key == "speed":
                kw["speed"] = float(value)
                if kw["speed"] < 0:
                    raise ValueError("must be >= 0")
            elif key == "seed":
                kw["seed"] = int(value)
            elif key == "link":
                kw["link"] = value
            elif key in ("drop", "corrupt", "dup"):
                fk[key] = parse_rate(key, value)
            elif key == "delay":
                if ":" in value:
                    fk["delay"], fk["delay_ms"] = parse_delay(value)
                else:
                    fk["delay"] = parse_rate(key, value)
            elif key == "delay_ms":
                fk["delay_ms"] = float(value)
                if fk["delay_ms"] < 0:
                    raise ValueError("must be >= 0")
            elif key == "lanes":
                fk["lanes"] = tuple(x for x in value.split(",") if x)
            elif key == "reset_at":
                fk["reset_at"] = tuple(float(x) for x in value.split(",") if x)
            elif key == "stall":
                fk["stall"] = tuple(parse_stall(x) for x in value.split(",") if x)
            else:
                raise ArmbridgeError(
                    f"bad {where}: unknown; known: speed, seed, link, drop, corrupt, dup, delay, "
                    "delay_ms, lanes, reset_at, stall"
                )
        except ArmbridgeError as exc:
            if str(exc).startswith("bad "):
                raise
            raise ArmbridgeError(f"bad {where}: {exc}") from None
        except ValueError as exc:
            raise ArmbridgeError(f"bad {where}={value!r}: {exc}") from None
    if fk:
        try:
            kw["faults"] = Faults(**fk)
        except ArmbridgeError as exc:
            raise ArmbridgeError(f"bad port {url!r}: {exc}") from None
    return device, kw


def _open_emulator(url: str, baud: int, timeout: float | None) -> Port:
    from armbridge.emulator.board import EmulatedBoard

    device, kw = parse_emu_url(url)
    emu = EmulatedBoard(device, **kw)
    emu.start()
    try:
        ser = serial.Serial(emu.port, baudrate=baud, timeout=timeout)
    except (serial.SerialException, OSError) as exc:
        emu.stop()
        raise ArmbridgeError(f"cannot open port {url!r}: emulator pty {emu.port}: {exc}") from exc
    return Port(ser, url, emulator=emu)
