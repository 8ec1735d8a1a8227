"""`emu:DEVICE[?key=value&...]`: an emulated board as a port, in this process.

    emu:esp32?speed=4&drop=0.01&delay=0.01:20&seed=3&reset_at=2.5&stall=2@4
    emu:esp32?servos=pca9685
    emu:masr_ma?speed=0&missed=3&slip=2:0.5:0.3&stall=2@4

Parameters (all optional):
  servos=RIG       the board's rig (registry.rig_spec): effort (default) or pca9685
  speed=K          clock mode: 1 wall clock (default), K times faster, 0 as fast as it goes
  interpreter=I    firmware runner: cpython (default) or micropython
  drop=R corrupt=R dup=R   byte fault rates in [0, 1]
  delay=R:MS       a fraction R of bytes delayed MS milliseconds (or delay=R&delay_ms=MS)
  lanes=rx,tx      which directions get the link faults (default both)
  seed=N           seed of plant noise and link faults (and of the plant's truth)
  plant=P          nominal (default: the model the firmware assumes) or random: the
                   plant's physical parameters drawn with seed from their documented
                   spreads (emulator/truth.py), which host and firmware never read
  reset_at=S[,S]   sim seconds at which the board resets
  stall=J@S[,J@S]  joint J (1..n) stalls at sim second S (masr_ma: joint J's worm
                   drive seizes, J = n: the wheel)
  missed=J[,J]     masr_ma: joint J's magnet never fires
  slip=S:D:F[,..]  masr_ma: from sim second S for D seconds the wheel slips by F
  link=PATH        a symlink to the pty (owned while the port is open)
  fs=DIR           the board's non-volatile memory kept in the host folder DIR, as a
                   chip keeps it across power cycles: a MicroPython board's filesystem
                   (seeded when empty; what a flash wrote there boots next time, and
                   its calibration, cal.txt); the pump board's EEPROM
                   (DIR/<chip id>.eeprom: its calibration, latches, Modbus address)

`parse_emu_url` turns the text into EmulatedBoard arguments (the device is its
name, or the rig's BoardSpec when servos= picks another rig; every bad part is
one ArmbridgeError naming the URL and the parameter); `open_emu_port` starts
the emulator on its pty and opens it like any serial port, or, at speed=0
without link=, runs it in lockstep with its host in the host's own thread
(emulator/lockstep.py: a seeded run repeats bit for bit).
"""
from __future__ import annotations

from typing import Any
from urllib.parse import parse_qsl, urlsplit

import serial  # type: ignore[import-untyped]

from armbridge.emulator.faults import (Faults, parse_delay, parse_lanes, parse_missed, parse_rate, parse_seconds,
                                       parse_slip, parse_stall)
from armbridge.emulator.registry import BoardSpec, board_spec, rig_spec
from armbridge.emulator.truth import check_plant
from armbridge.errors import ArmbridgeError

PARAMETERS = ("servos", "speed", "interpreter", "seed", "plant", "link", "fs", "drop", "corrupt", "dup", "delay", "delay_ms",
              "lanes", "reset_at", "stall", "missed", "slip")


def _number(text: str, name: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise ArmbridgeError(f"{name} {text!r} is not a number") from None
    if not x >= 0:
        raise ArmbridgeError(f"{name} {text} must be >= 0")
    return x


def _board_kw(key: str, value: str) -> Any:
    if key == "speed":
        return _number(value, key)
    if key == "seed":
        try:
            return int(value)
        except ValueError:
            raise ArmbridgeError(f"seed {value!r} is not an integer") from None
    if key == "plant":
        return check_plant(value)
    return value  # link, interpreter: checked when the board is built


def _fault_kw(key: str, value: str) -> dict[str, Any]:
    if key in ("drop", "corrupt", "dup"):
        return {key: parse_rate(key, value)}
    if key == "delay":
        if ":" in value:
            rate, ms = parse_delay(value)
            return {"delay": rate, "delay_ms": ms}
        return {"delay": parse_rate(key, value)}
    if key == "delay_ms":
        return {key: _number(value, key)}
    if key == "lanes":
        return {key: parse_lanes(value)}
    if key == "reset_at":
        return {key: tuple(parse_seconds(x, key) for x in value.split(",") if x)}
    if key == "missed":
        return {key: tuple(parse_missed(x) for x in value.split(",") if x)}
    if key == "slip":
        return {key: tuple(parse_slip(x) for x in value.split(",") if x)}
    return {"stall": tuple(parse_stall(x) for x in value.split(",") if x)}


def parse_emu_url(url: str) -> tuple[str | BoardSpec, dict[str, Any]]:
    """'emu:esp32?speed=4&drop=0.01' -> ('esp32', {EmulatedBoard keyword arguments});
    'emu:esp32?servos=pca9685' -> (the pca9685 rig's BoardSpec, {})."""
    parts = urlsplit(url.strip())
    device = parts.path or parts.netloc
    if parts.scheme != "emu" or not device:
        raise ArmbridgeError(f"bad port {url!r}: expected emu:DEVICE[?key=value&...]")
    spec = board_spec(device)  # unknown device -> ArmbridgeError naming the known ones
    try:
        params = parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError as exc:
        raise ArmbridgeError(f"bad port {url!r}: {exc}") from None
    rigs = [value for key, value in params if key == "servos"]
    try:
        spec = rig_spec(spec, rigs[-1] if rigs else None)
    except ArmbridgeError as exc:
        raise ArmbridgeError(f"bad port {url!r}, parameter servos: {exc}") from None
    kw: dict[str, Any] = {}
    fk: dict[str, Any] = {}
    for key, value in params:
        if key not in PARAMETERS:
            raise ArmbridgeError(f"bad port {url!r}: unknown parameter {key!r}; known: {', '.join(PARAMETERS)}")
        try:
            if key == "interpreter" and value not in spec.interpreters:
                on = f" on the {spec.rig} rig" if spec.rigs else ""
                raise ArmbridgeError(f"{value!r} cannot run the {device} firmware{on}; "
                                     f"interpreters: {', '.join(spec.interpreters)}")
            if key == "servos":
                continue
            if key in ("speed", "seed", "plant", "link", "interpreter"):
                kw[key] = _board_kw(key, value)
            elif key == "fs":
                kw["fs_dir"] = value
            else:
                fk.update(_fault_kw(key, value))
        except ArmbridgeError as exc:
            raise ArmbridgeError(f"bad port {url!r}, parameter {key}: {exc}") from None
    if fk:
        try:
            kw["faults"] = Faults(**fk)
        except ArmbridgeError as exc:
            raise ArmbridgeError(f"bad port {url!r}: {exc}") from None
    return (device if spec is board_spec(device) else spec), kw


def open_emu_port(url: str, baud: int = 115200, timeout: float | None = 0.1):
    """Start the emulator `url` names on its pty and open the pty: a
    `armbridge.link.transport.Port` whose close() also stops the emulator,
    with `.emulator` (the EmulatedBoard) and `.clock` (seconds on the
    emulator's time scale: `EmulatedBoard.host_time`)."""
    from armbridge.emulator.board import EmulatedBoard
    from armbridge.link.transport import Port, PortError

    device, kw = parse_emu_url(url)  # a bad URL: ArmbridgeError (usage, exit 2)
    emu = EmulatedBoard(device, **kw)
    if emu.speed == 0 and not kw.get("link"):  # lockstep: board and host take turns in one thread
        from armbridge.emulator.lockstep import lockstep_port

        return lockstep_port(emu, url, timeout, baud)
    try:
        emu.start()
        ser = serial.Serial(emu.port, baudrate=baud, timeout=timeout)
        emu.couple()
    except ArmbridgeError as exc:  # no pty, or its link is owned by a live emulator: the port is busy
        emu.stop()
        raise PortError(f"cannot open port {url!r}: {exc}") from None
    except (serial.SerialException, OSError) as exc:
        emu.stop()
        raise PortError(f"cannot open port {url!r}: emulator pty {emu.port}: {exc}") from exc
    except BaseException:
        emu.stop()
        raise
    return Port(ser, url, emulator=emu, clock=emu.host_time)


def open_lockstep_port(url: str, baud: int = 115200, timeout: float | None = 0.1):
    """The board an `emu:` url names (its speed must be 0), as a lockstep port."""
    from armbridge.emulator.board import EmulatedBoard
    from armbridge.emulator.lockstep import lockstep_port

    device, kw = parse_emu_url(url)
    if float(kw.get("speed", 1.0)) != 0:
        raise ArmbridgeError(f"{url}: a lockstep port needs speed=0")
    return lockstep_port(EmulatedBoard(device, **kw), url, timeout, baud)
