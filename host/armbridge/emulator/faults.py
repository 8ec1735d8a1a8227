"""The faults an emulated board can be given, and their parsing from text.

One module parses every fault the CLI flags (`armbridge emulate --drop ...`)
and the `emu:` URL parameters (`emu:esp32?drop=...`) name, so both refuse bad
input with the same one-line message naming the flag or parameter and the
allowed range. The per-byte model itself is `uart.LinkFaults`.
"""
from __future__ import annotations

from dataclasses import dataclass

from armbridge.emulator.uart import LANES, LinkFaults
from armbridge.errors import ArmbridgeError


@dataclass(frozen=True)
class Faults:
    """Faults to inject.

    Link (per byte, rates in [0, 1]; on the lanes named in `lanes`: "rx" host ->
    board, "tx" board -> host, both by default): drop, corrupt (one bit flipped),
    dup, delay (rate) with delay_ms extra.
    Board: reset_at (sim seconds at which the board resets).
    Plant: stall ((joint, sim seconds), ...), joints numbered 1..n as in the protocol.
    The MASR actuator's plant (ma_plant.py) only: missed (joints 1..n-1 whose
    magnet never fires), slip ((from sim seconds, for seconds, fraction F), ...):
    bursts in which the wheel slips by F (the MA advances by its travel times 1 - F).
    """

    drop: float = 0.0
    corrupt: float = 0.0
    dup: float = 0.0
    delay: float = 0.0
    delay_ms: float = 0.0
    lanes: tuple[str, ...] = LANES
    reset_at: tuple[float, ...] = ()
    stall: tuple[tuple[int, float], ...] = ()
    missed: tuple[int, ...] = ()
    slip: tuple[tuple[float, float, float], ...] = ()

    def __post_init__(self) -> None:
        try:
            self.link  # LinkFaults checks the rates and the delay
        except ValueError as exc:
            raise ArmbridgeError(f"fault {exc}") from None
        parse_lanes(",".join(self.lanes), "lanes")
        for t in self.reset_at:
            if not t >= 0:
                raise ArmbridgeError(f"reset time {t} s must be >= 0")
        for j, t in self.stall:
            if j < 1 or not t >= 0:
                raise ArmbridgeError(f"stall {j}@{t}: joint is numbered from 1, time must be >= 0")
        for j in self.missed:
            parse_missed(str(j))
        for burst in self.slip:
            if len(burst) != 3:
                raise ArmbridgeError(f"slip burst {burst}: expected (start s, duration s, fraction)")
            check_slip(*burst, label=f"slip burst {burst}")

    @property
    def plant_faults(self) -> tuple[str, ...]:
        """The names of the set faults that only a plant with `inject(faults)` takes (the MA's)."""
        return tuple(name for name in ("missed", "slip") if getattr(self, name))

    @property
    def link(self) -> LinkFaults:
        return LinkFaults(self.drop, self.corrupt, self.dup, self.delay, self.delay_ms)

    def describe(self) -> str:
        """One line for a person: 'drop 0.01, dup 0.01 on rx+tx, reset at 2 s' or 'none'."""
        parts = [f"{name} {getattr(self, name):g}" for name in ("drop", "corrupt", "dup") if getattr(self, name)]
        if self.delay and self.delay_ms:
            parts.append(f"delay {self.delay:g} x {self.delay_ms:g} ms")
        if parts:
            parts.append("on " + "+".join(self.lanes))
        parts += [f"reset at {t:g} s" for t in self.reset_at]
        parts += [f"joint {j} stalls at {t:g} s" for j, t in self.stall]
        parts += [f"magnet {j} missed" for j in self.missed]
        parts += [f"wheel slips {f:g} from {s:g} s for {d:g} s" for s, d, f in self.slip]
        return ", ".join(parts) if parts else "none"


def parse_rate(name: str, value: str | float) -> float:
    """A fault rate in [0, 1]; `name` (flag or parameter) is named in the error."""
    try:
        r = float(value)
    except (TypeError, ValueError):
        raise ArmbridgeError(f"{name} {value!r} is not a number; expected a rate in the range [0, 1]") from None
    if not 0.0 <= r <= 1.0:  # also refuses nan
        raise ArmbridgeError(f"{name} {value} is outside the range [0, 1]")
    return r


def parse_delay(value: str, name: str = "delay") -> tuple[float, float]:
    """'R:MS' -> (rate in [0, 1], extra delay in ms >= 0)."""
    rate, sep, ms = str(value).partition(":")
    if not sep:
        raise ArmbridgeError(f"{name} {value!r}: expected RATE:MS, e.g. 0.01:50")
    r = parse_rate(name, rate)
    try:
        d = float(ms)
    except ValueError:
        raise ArmbridgeError(f"{name} {value!r}: MS {ms!r} is not a number") from None
    if not d >= 0:
        raise ArmbridgeError(f"{name} {value!r}: MS must be >= 0")
    return r, d


def parse_stall(value: str, name: str = "stall") -> tuple[int, float]:
    """'J@SECONDS' -> (joint 1..n, sim seconds)."""
    j, sep, t = str(value).partition("@")
    try:
        if not sep:
            raise ValueError
        jj, tt = int(j), float(t)
    except ValueError:
        raise ArmbridgeError(f"{name} {value!r}: expected JOINT@SECONDS, e.g. 2@1.5") from None
    if jj < 1 or not tt >= 0:
        raise ArmbridgeError(f"{name} {value!r}: joints are numbered from 1 and the time must be >= 0")
    return jj, tt


def parse_missed(value: str, name: str = "missed") -> int:
    """'J' -> joint J (>= 1) whose magnet never fires (the MASR actuator)."""
    try:
        j = int(str(value))
    except ValueError:
        raise ArmbridgeError(f"{name} {value!r}: expected a JOINT number (1..n-1), e.g. 3") from None
    if j < 1:
        raise ArmbridgeError(f"{name} {value!r}: joints are numbered from 1")
    return j


def parse_slip(value: str, name: str = "slip") -> tuple[float, float, float]:
    """'S:D:F' -> (from sim second S, for D seconds, slip fraction F in [0, 1]) (the MASR actuator)."""
    parts = str(value).split(":")
    try:
        if len(parts) != 3:
            raise ValueError
        s, d, f = (float(x) for x in parts)
    except ValueError:
        raise ArmbridgeError(f"{name} {value!r}: expected START:DURATION:FRACTION, e.g. 2:0.5:0.3 "
                             "(from 2 s for 0.5 s the wheel slips 30 %)") from None
    return check_slip(s, d, f, label=f"{name} {value!r}")


def check_slip(s: float, d: float, f: float, label: str = "slip") -> tuple[float, float, float]:
    """A slip burst's (start >= 0 s, duration > 0 s, fraction in [0, 1]), or one error naming `label`."""
    if not (s >= 0 and d > 0 and 0 <= f <= 1):
        raise ArmbridgeError(f"{label}: START must be >= 0 s, DURATION > 0 s and FRACTION in [0, 1]")
    return float(s), float(d), float(f)


def parse_lanes(value: str, name: str = "lanes") -> tuple[str, ...]:
    """'rx,tx' -> ('rx', 'tx'): the directions link faults apply to."""
    lanes = tuple(x.strip() for x in str(value).split(",") if x.strip())
    for lane in lanes:
        if lane not in LANES:
            raise ArmbridgeError(f"{name} {value!r}: unknown lane {lane!r}; lanes are rx (host->board) "
                                 "and tx (board->host)")
    return lanes


def parse_seconds(value: str | float, name: str) -> float:
    """A sim time in seconds, >= 0 (reset times)."""
    try:
        t = float(value)
    except (TypeError, ValueError):
        raise ArmbridgeError(f"{name} {value!r} is not a number of seconds") from None
    if not t >= 0:
        raise ArmbridgeError(f"{name} {value} must be >= 0 seconds")
    return t
