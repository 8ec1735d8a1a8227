"""The HAL the firmware sees in the emulator (docs/architecture.md, "The HAL").

Time is the emulator's simulated clock, an integer count of microseconds.
`ticks_ms`/`ticks_us` wrap like MicroPython's (modulo 2**30) and `ticks_diff`
handles the wrap; `tick_offset_ms` starts the tick counters anywhere, e.g. just
before the wrap to exercise it. The plant is integrated lazily up to the
current time whenever the firmware touches it. The UART is a `PacedUart`.
Persistent memory (RTC memory on the ESP32: survives a reset, not a power cycle)
is a `PersistentMemory` the emulator keeps across board resets.

For the tests and the e-stop latency check, the HAL records: the times outputs
go from on to off (`outputs_off_at`), the times they come back on
(`outputs_on_at`), the efforts written (`efforts`, with times), the delivery
time of every e-stop byte (`estop_byte_at`), and every complete line the
firmware writes (handed to `on_line` before link faults are applied).

The pen-lift servo (config PEN_PIN) is a fourth output: `write_pen(down)`
logs (time, down) in `pen_log`, and the pulse width it commands (the up or
down width: the config's PEN_UP_US / PEN_DOWN_US until `set_pen_widths`,
the firmware's PENPOS) in `pen_us_log`. The pen touches the paper only when
the commanded width reaches `pen_contact_us` (a physical fact of the rig: where
the tip meets the paper, the plant's `pen_contact_us`, PEN_CONTACT_US between
the default widths unless a hidden truth drew another; on the
side of the down width, `pen_contact_above`), `pen_travel_s` after the
command that brought it there, and leaves it at once: `pen_down_at(t)` is
whether it touched at time t (`pen_touch_at_ms`: at a board time).

Files: `read_file(name)` serves the board's filesystem from `files` (name ->
bytes; None for a name it lacks); an emulated board starts with
`boards.files.board_files(cfg)`: the config's IK_WEIGHTS -> the shipped
models/onnx/arm3r-ik/int8.bin (the board IK's net, firmware/esp32/ik3r.py).
`write_file(name, data)` (the firmware's calibration, calstore.py) replaces
one and hands it to `on_file` (the board's filesystem, so a reset keeps it).
`uid()` is the chip id IDENT reports: `uid_hex`, which the emulated board sets
from what it emulates (a drawn plant is another physical board).
"""
from __future__ import annotations

import math
from collections import deque
from typing import Callable

import numpy as np

from armbridge.boards import ESP32_RTC_MEMORY
from armbridge.emulator.plant import PEN_CONTACT_US, ServoPlant
from armbridge.emulator.uart import PacedUart

TICKS_PERIOD = 1 << 30
TICKS_MAX = TICKS_PERIOD - 1
TICKS_HALF = TICKS_PERIOD >> 1
ESTOP_BYTE = 0x98
RTC_MEMORY_SIZE = ESP32_RTC_MEMORY  # bytes of ESP32 RTC user memory


def ticks_diff(a: int, b: int) -> int:
    """Signed a - b for tick values that wrap at 2**30 (MicroPython semantics)."""
    return ((a - b + TICKS_HALF) & TICKS_MAX) - TICKS_HALF


def in_intervals(ts: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Whether each time lies in one of the sorted, disjoint intervals [starts[i], ends[i])."""
    i = np.searchsorted(starts, ts, side="right") - 1
    inside = i >= 0
    inside[inside] = ts[inside] < ends[i[inside]]
    return inside


def ticks_add(t: int, delta: int) -> int:
    return (t + delta) & TICKS_MAX


class SimClock:
    """Simulated time in integer microseconds."""

    def __init__(self, us: int = 0) -> None:
        self.us = us

    @property
    def t(self) -> float:
        return self.us / 1e6

    def advance_us(self, dus: int) -> None:
        if dus < 0:
            raise ValueError("the clock cannot go back")
        self.us += dus


class PersistentMemory:
    """Bytes that survive a board reset (not a power cycle)."""

    def __init__(self, data: bytes = b"", size: int = RTC_MEMORY_SIZE) -> None:
        self.size = size
        self.data = bytes(data)

    def save(self, data) -> None:
        data = bytes(data)
        if len(data) > self.size:
            raise ValueError(f"persistent memory holds {self.size} bytes, got {len(data)}")
        self.data = data


class SimHal:
    """HAL over the sim clock, a ServoPlant, a PacedUart and persistent memory."""

    has_pen = True  # the pen-lift servo of the default config (PEN_PIN)

    def __init__(
        self,
        clock: SimClock,
        plant: ServoPlant,
        uart: PacedUart,
        persist: PersistentMemory | None = None,
        tick_offset_ms: int = 0,
        on_line: Callable[[float, bytes], None] | None = None,
        max_log: int = 200_000,
        files: dict[str, bytes] | None = None,
    ) -> None:
        self.files: dict[str, bytes] = dict(files) if files is not None else {}
        self.on_file: Callable[[str, bytes], None] | None = None
        self.uid_hex = "00000000"
        self.clock = clock
        self.plant = plant
        self.uart = uart
        self.persist = persist if persist is not None else PersistentMemory()
        self.tick_offset_ms = tick_offset_ms
        self.on_line = on_line
        self.outputs_enabled = False
        self.outputs_off_at: list[float] = []
        self.outputs_on_at: list[float] = []
        self.estop_byte_at: list[float] = []
        self.efforts: deque[tuple[float, tuple[float, ...]]] = deque(maxlen=max_log)
        self.saturation_violations = 0  # efforts written outside [-1, 1]
        self.reads = 0
        self.pen_travel_s = 0.15  # servo travel up <-> down (the firmware waits PEN_SETTLE_MS)
        self.pen_log: list[tuple[float, bool]] = []
        self.pen_widths = (1200.0, 1700.0)  # (up, down) us: the default config's, until set_pen_widths
        # where the tip meets the paper: the plant's (a drawn plant's own), else the default rig's
        self.pen_contact_us = float(getattr(getattr(plant, "p", None), "pen_contact_us", PEN_CONTACT_US))
        self.pen_contact_above = True  # the paper is on the long-pulse side (the default config's down)
        self.pen_us_log: list[tuple[float, float]] = []  # (t, us) every width the pen servo was sent
        self._line = bytearray()

    # clock ---------------------------------------------------------------
    def ticks_ms(self) -> int:
        return (self.clock.us // 1000 + self.tick_offset_ms) & TICKS_MAX

    def ticks_us(self) -> int:
        return (self.clock.us + self.tick_offset_ms * 1000) & TICKS_MAX

    ticks_diff = staticmethod(ticks_diff)
    ticks_add = staticmethod(ticks_add)

    # plant ---------------------------------------------------------------
    def _sync(self) -> None:
        self.plant.advance_to(self.clock.t)

    def read_positions(self, out) -> None:
        self._sync()
        m = self.plant.measure()
        for i in range(self.plant.n):
            out[i] = float(m[i])
        self.reads += 1

    def write_outputs(self, efforts) -> None:
        self._sync()
        e = tuple(float(x) for x in efforts)
        if any(x < -1.0 or x > 1.0 for x in e):
            self.saturation_violations += 1
        self.plant.drive(e)
        t = self.clock.t
        if not self.outputs_enabled:
            self.outputs_on_at.append(t)
        self.outputs_enabled = True
        self.efforts.append((t, e))

    def outputs_off(self) -> None:
        self._sync()
        self.plant.off()
        if self.outputs_enabled:
            self.outputs_off_at.append(self.clock.t)
        self.outputs_enabled = False

    # pen -----------------------------------------------------------------
    def write_pen(self, down) -> None:
        self.pen_log.append((self.clock.t, bool(down)))
        self.pen_us_log.append((self.clock.t, self.pen_widths[1 if down else 0]))

    def rig_pen(self, cfg) -> None:
        """The rig's pen as the firmware config `cfg` wires it: its default widths, and the
        paper on the side of its down width."""
        up, down = getattr(cfg, "PEN_UP_US", None), getattr(cfg, "PEN_DOWN_US", None)
        if up is not None and down is not None:
            self.pen_widths = (float(up), float(down))
            self.pen_contact_above = down > up

    def set_pen_widths(self, up_us, down_us) -> None:
        """The firmware's PENPOS: new widths; a pen already driven goes to its state's new one."""
        self.pen_widths = (float(up_us), float(down_us))
        if self.pen_log:
            us = self.pen_widths[1 if self.pen_log[-1][1] else 0]
            if us != self.pen_us_log[-1][1]:
                self.pen_us_log.append((self.clock.t, us))

    def pen_touches(self, us: float) -> bool:
        """Whether a pen servo held at pulse width `us` has its tip on the paper."""
        return us >= self.pen_contact_us if self.pen_contact_above else us <= self.pen_contact_us

    def pen_down_at(self, t: float) -> bool:
        """Whether the pen touched the paper at time t (s)."""
        return bool(self.pen_touching([t])[0])

    def pen_touching(self, ts) -> np.ndarray:
        """pen_down_at for many times (s) at once."""
        starts, ends = [], []   # the pen on the paper: [start, end) from the log
        since = None            # when the pen (commanded to a touching width) meets the paper
        for at, us in list(self.pen_us_log):
            if self.pen_touches(us):
                if since is None:
                    since = at + self.pen_travel_s
                continue
            if since is not None and at > since:
                starts.append(since)
                ends.append(at)
            since = None
        if since is not None:
            starts.append(since)
            ends.append(math.inf)
        return in_intervals(np.asarray(ts, float), np.array(starts, float), np.array(ends, float))

    def pen_touch_at_ms(self, ms) -> np.ndarray:
        """pen_touching at the board times `ms` (ticks_ms) stand for."""
        return self.pen_touching(self._board_t(ms))

    def _board_t(self, ms) -> np.ndarray:
        return ((np.asarray(ms, np.int64) - self.tick_offset_ms) & TICKS_MAX) / 1000.0

    # files ---------------------------------------------------------------
    def read_file(self, name) -> bytes | None:
        """A file of the board's filesystem, None when it has none of that name."""
        return self.files.get(str(name))

    def write_file(self, name, data) -> None:
        self.files[str(name)] = bytes(data)
        if self.on_file is not None:
            self.on_file(str(name), bytes(data))

    def uid(self) -> str:
        return self.uid_hex

    # uart ----------------------------------------------------------------
    def uart_read(self) -> bytes | None:
        lane = self.uart.rx
        now = self.clock.t + 1e-9  # byte times are floats; the clock counts whole us
        nt = lane.next_time()
        if nt is None or nt > now:
            return None
        timed = lane.pop_timed(now)
        for t, b in timed:
            if b == ESTOP_BYTE:
                self.estop_byte_at.append(t)
        return bytes(b for _, b in timed)

    def uart_write(self, data) -> None:
        data = bytes(data)
        t = self.clock.t
        self.uart.firmware_write(data, t)
        if self.on_line is None:
            return
        buf = self._line
        for b in data:
            if b == 0x0A:
                self.on_line(t, bytes(buf))
                buf.clear()
            elif len(buf) < 512:
                buf.append(b)

    def reset_line_tap(self) -> None:
        self._line.clear()

    # persistent memory -----------------------------------------------------
    def load_persist(self) -> bytes:
        return self.persist.data

    def save_persist(self, data) -> None:
        self.persist.save(data)



