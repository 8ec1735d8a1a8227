"""Which serial ports hold one of our boards: pyserial's `list_ports` against the
USB ids of the bridges these boards use, for `--port auto` and `armbridge ports`
(as mpremote's `connect auto` and esptool's port scan).

A board is behind a USB-serial bridge (the ESP32 DevKits' CP210x, the clones'
CH340 / CH9102, FTDI cables) or speaks USB itself (the Mega's own ATmega16U2,
the ESP32-S3's native USB). `BRIDGES` maps (vid, pid) to what the chip is and
which of our boards usually sit behind it; a port whose id is not there is
listed by `armbridge ports --all` and never picked by `auto`, which takes
exactly one candidate or says in one line why it cannot (none, or several:
name one). Pure but for `comports()`, which a caller may pass in.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Iterable

from armbridge.errors import ArmbridgeError

#: (vid, pid) -> (the chip, the boards usually behind it)
BRIDGES: dict[tuple[int, int], tuple[str, str]] = {
    (0x10C4, 0xEA60): ("Silicon Labs CP210x", "esp32, masr_ma"),
    (0x1A86, 0x7523): ("WCH CH340", "esp32, masr_ma, arduino_pump (clones)"),
    (0x1A86, 0x55D4): ("WCH CH9102", "esp32, masr_ma"),
    (0x0403, 0x6001): ("FTDI FT232R", "any (a USB-serial cable)"),
    (0x0403, 0x6015): ("FTDI FT231X", "any (a USB-serial cable)"),
    (0x2341, 0x0010): ("Arduino Mega 2560 (ATmega8U2)", "arduino_pump"),
    (0x2341, 0x0042): ("Arduino Mega 2560 R3 (ATmega16U2)", "arduino_pump"),
    (0x2A03, 0x0042): ("Arduino Mega 2560 R3 (arduino.org)", "arduino_pump"),
    (0x303A, 0x1001): ("ESP32-S3 native USB (USB-Serial/JTAG)", "esp32, masr_ma"),
}
#: the families of BRIDGES, in a line
FAMILIES = "CP210x, CH340 / CH9102, FTDI, an Arduino Mega's own USB, the ESP32-S3's native USB"


@dataclass(frozen=True)
class SerialPort:
    """One port as `armbridge ports` lists it; `bridge` None: not a known board bridge."""

    device: str
    usb_id: str | None          # "VID:PID" in hex, None for a port that is not USB
    bridge: str | None
    boards: str | None
    description: str
    serial_number: str | None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def describe(info: Any) -> SerialPort:
    """A pyserial ListPortInfo as a SerialPort."""
    vid, pid = getattr(info, "vid", None), getattr(info, "pid", None)
    known = BRIDGES.get((vid, pid)) if vid is not None and pid is not None else None
    return SerialPort(
        device=str(info.device),
        usb_id=None if vid is None or pid is None else f"{vid:04X}:{pid:04X}",
        bridge=known[0] if known else None,
        boards=known[1] if known else None,
        description=str(getattr(info, "description", "") or ""),
        serial_number=getattr(info, "serial_number", None),
    )


def comports() -> list[Any]:
    """pyserial's list of this machine's serial ports."""
    from serial.tools import list_ports  # type: ignore[import-untyped]

    return list(list_ports.comports())


def scan(ports: Iterable[Any] | None = None, everything: bool = False) -> list[SerialPort]:
    """The ports with a known bridge (every port with `everything`), by device name."""
    found = [describe(p) for p in (comports() if ports is None else ports)]
    return sorted((p for p in found if everything or p.bridge is not None), key=lambda p: p.device)


def resolve_auto(ports: Iterable[Any] | None = None) -> str:
    """`--port auto`: the one port with a known bridge, else an ArmbridgeError in one line."""
    cands = scan(ports)
    if len(cands) == 1:
        return cands[0].device
    if not cands:
        raise ArmbridgeError(f"--port auto: no board found (no serial port with a known USB bridge: {FAMILIES}); "
                             "plug one in or name the port (`armbridge ports --all` lists every port)")
    listed = ", ".join(f"{p.device} ({p.bridge})" for p in cands)
    raise ArmbridgeError(f"--port auto: {len(cands)} boards found ({listed}): name one with --port")


def auto_port(value: str | None) -> str | None:
    """The `--port` options' callback: 'auto' is the one board `resolve_auto` finds; anything else stays."""
    if value is not None and value.strip().lower() == "auto":
        return resolve_auto()
    return value
