"""A board's real firmware on a simulated HAL, in sim time: the tick machinery.

This is the board-independent machinery; what differs between boards is data
(`registry.BoardSpec`: firmware, plant, HAL, clock, identity) and the firmware
runner (`runner.py`: MicroPython under CPython, the same under the real
MicroPython interpreter, ...). `SimBoard("esp32")` builds the runner, reads
the firmware's config, builds the plant and the HAL from the spec (sim clock,
plant, `PacedUart`, persistent memory) and boots the board, which prints BOOT.
Each iteration (`_tick`) advances the sim clock by one tick (1 ms), moves host
bytes into the UART, calls `board.poll()`, moves the bytes that have left the
board to the host, and integrates the plant.

Its caller drives it: `step(n)` advances n control periods (10 ms each),
`run_for(s)`, `run_until(pred)`, with `inject(bytes)` / `read_output()`
standing for the host. Nothing here knows a wall clock, a thread or a pty:
`EmulatedBoard` (board.py) serves a SimBoard on a pty from a thread, paced to
the wall clock or in lockstep, through the hooks `_from_host`, `_to_host`,
`_booted`, `_serving_thread` and `_check_not_running`.

Resets (`reset()`, `Faults.reset_at`, `schedule_reset(t)`) throw away the board
and its firmware state, keep the persisted memory and the plant, switch the
outputs off for `boot_ms` of sim time (bytes from the host are lost meanwhile),
then boot the firmware afresh (`runner.boot`), which prints BOOT.

A MicroPython board also has its flash filesystem (`boardfs.BoardFs`, seeded
from the firmware folders; `fs_dir=` keeps it in a host folder) and its REPL
console (`repl.Console`): a Ctrl-C from the host stops the firmware and the
pty speaks MicroPython's raw REPL, so mpremote can copy files; a reset then
boots the firmware in that filesystem (main.py and the modules it holds), not
the checkout's (docs/flash.md).
"""
from __future__ import annotations

import bisect
import math
import os
import threading
import traceback
import types
import zlib
from pathlib import Path
from typing import Any, Callable

import numpy as np

from armbridge.boards.files import board_files
from armbridge.emulator.boardfs import BoardFs
from armbridge.emulator.faults import Faults
from armbridge.emulator.plant import PlantParams
from armbridge.emulator.registry import BoardSpec, MicroPythonFirmware, board_spec
from armbridge.emulator.repl import Console, cooked
from armbridge.emulator.runner import boot_from, firmware_config, make_runner
from armbridge.emulator.simhal import PersistentMemory, SimClock
from armbridge.emulator.truth import check_plant, truth_rng
from armbridge.emulator.uart import PacedUart
from armbridge.errors import ArmbridgeError
from armbridge.resources import firmware_dir


def board_uid(device: str, plant: str, seed: int) -> str:
    """The chip id an emulated board reports (IDENT): one per physical board it
    stands for, so a drawn plant (plant=random, its seed) is another board and
    the nominal one is the same board whatever the noise seed."""
    key = f"{device}:{plant}:{seed}" if plant == "random" else f"{device}:{plant}"
    return "%08x" % zlib.crc32(key.encode())

class SimBoard:
    """A board running its real firmware on a simulated HAL, stepped in sim time; see the module docstring.

    device: a name in registry.BOARDS, or a BoardSpec. speed: clock mode (1.0
    wall clock, K faster, 0 lockstep: what EmulatedBoard serves it at). faults:
    `Faults`. seed: seeds the plant noise and the link faults. interpreter: the
    firmware runner ("cpython", "micropython"; None: the spec's default). q0,
    plant_params: override the spec's. plant: "nominal" (the spec's parameters)
    or "random" (drawn from the plant's spreads with `seed`: truth.py; the drawn
    parameters are the plant's `p`, which only tests and benches read). on_line(t, line): called with every line
    the firmware writes (sim seconds, bytes without LF), before link faults.
    """

    def __init__(
        self,
        device: str | BoardSpec = "esp32",
        speed: float = 1.0,
        faults: Faults | None = None,
        seed: int = 0,
        *,
        interpreter: str | None = None,
        q0=None,
        plant_params: PlantParams | None = None,
        plant: str = "nominal",
        firmware_root: str | os.PathLike | None = None,
        tick_offset_ms: int = 0,
        boot_ms: float = 250.0,
        on_line: Callable[[float, bytes], None] | None = None,
        fs_dir: str | os.PathLike | None = None,
    ) -> None:
        spec = board_spec(device)
        self.spec = spec
        self.device = spec.name
        if not speed >= 0:
            raise ArmbridgeError(f"speed {speed} must be >= 0 (0 = lockstep)")
        self.speed = float(speed)
        self.faults = faults or Faults()
        self.seed = seed
        self.boot_ms = boot_ms
        self.on_line = on_line
        self.tick_us = int(spec.tick_us)   # one iteration of the emulator (1 ms of sim time)
        root = Path(firmware_root) if firmware_root is not None else firmware_dir()
        self.runner = make_runner(spec, interpreter, root)
        self.interpreter: str = getattr(self.runner, "interpreter", interpreter or spec.interpreters[0])

        self.cfg: Any = firmware_config(spec, root)
        self.period_ms = int(getattr(self.cfg, "PERIOD_MS", 10))
        self.clock = SimClock()
        self.plant_kind = check_plant(plant)
        if plant == "random":
            if plant_params is not None:
                raise ArmbridgeError("plant=random draws the plant's parameters; it takes no plant_params")
            plant_params = spec.truth(self.cfg, truth_rng(seed))
        self.plant = spec.plant(self.cfg, plant_params if plant_params is not None else spec.plant_params,
                                q0 if q0 is not None else spec.q0, seed)
        self.n = int(self.plant.n)
        for j, t in self.faults.stall:
            if j > self.n:
                raise ArmbridgeError(f"stall joint {j} does not exist; the {self.device} board has joints 1..{self.n}")
            self.plant.stall(j - 1, t)
        if self.faults.plant_faults:  # the MA's own (missed magnets, slip bursts): its plant's inject
            inject = getattr(self.plant, "inject", None)
            if inject is None:
                raise ArmbridgeError(f"{' and '.join(self.faults.plant_faults)}: faults of the masr_ma board; "
                                     f"the {self.device} board has none")
            inject(self.faults)
        self.uart = PacedUart(spec.baud, self.faults.link, self.faults.lanes, seed)
        self.persist = PersistentMemory(size=spec.persist_bytes)
        self.hal = spec.hal(self.clock, self.plant, self.uart, self.persist,
                            tick_offset_ms=tick_offset_ms, on_line=self._tap, files=board_files(self.cfg))
        self.hal.uid_hex = board_uid(self.device, self.plant_kind, seed)
        getattr(self.hal, "rig_pen", lambda cfg: None)(self.cfg)  # the pen's widths, its paper's side
        self.fs: BoardFs | None = None
        self.console: Console | None = None
        if isinstance(spec.firmware, MicroPythonFirmware):
            self.fs = BoardFs.for_board([root / d for d in spec.firmware.dirs], self.hal.files, fs_dir)
            self.console = Console(self.fs, self.uart.bytes_per_s, self._interrupt, self._repl_reset)
            self.hal.on_file = self.fs.put
        elif fs_dir is not None and hasattr(self.runner, "eeprom_dir"):   # a C board: its EEPROM, per chip id
            self.runner.eeprom_dir = Path(fs_dir)

        # (board_ms, id, (q1..qn) in milli-units as the W line carried them) of every
        # completed waypoint (the firmware's on_done hook), across resets.
        self.executed: list[tuple[int, int, tuple[int, ...]]] = []
        self.boots: list[float] = []                # sim times of BOOT (board constructions)
        self.resets: list[float] = []               # sim times resets began
        self.crash: str | None = None               # traceback if the firmware raised
        self._reset_times = sorted(float(t) for t in self.faults.reset_at)
        self._boot_at: float | None = None
        self._counters = {"resets": 0, "lost_in_reset": 0, "overruns": 0}
        self._out = bytearray()          # bytes to the host when nobody serves the board (read_output)
        self._lock = threading.RLock()
        self._closed = False

        self.board: Any = None
        self._boot()

    # ------------------------------------------------------------ firmware
    @property
    def modules(self) -> dict[str, types.ModuleType]:
        """The firmware's modules when it runs in this process ({} otherwise, and during a reset)."""
        return getattr(self.runner, "modules", {}) if self.board is not None else {}

    def _boot(self) -> None:
        self.uart.rx.clear()
        self.hal.reset_line_tap()
        self._boot_at = None
        self.boots.append(self.clock.t)
        cfg = self.cfg
        if self.fs is not None and not self.fs.pristine:  # boot what the filesystem holds
            try:
                if "main.py" not in self.fs.files:
                    self.console.to_repl()  # type: ignore[union-attr]  # no main.py: the board sits at its REPL
                    return
                fw = self.spec.firmware
                cfg = boot_from(self.runner, [self.fs.firmware_dir()], fw.config_module)  # type: ignore[union-attr]
                self.hal.files = self.fs.board_files()
                board = self.runner.boot(self.hal, cfg)
            except Exception:
                self.crash = traceback.format_exc()
                self.console.to_repl(cooked(self.crash))  # type: ignore[union-attr]  # as main.py's traceback
                return
        else:
            board = self.runner.boot(self.hal, cfg)
        board.on_done = self._on_done
        self.board = board
        self._booted()

    def _interrupt(self) -> None:
        """Ctrl-C from the host: the firmware stops (outputs off) and the REPL has the pty."""
        if self.board is not None:
            self.hal.outputs_off()
        self.board = None
        self._boot_at = None
        self.uart.rx.clear()

    def _repl_reset(self, kind: str) -> None:
        """machine.reset() or a soft reboot from the friendly REPL: main.py boots."""
        self._begin_reset()

    def _begin_reset(self) -> None:
        if self.console is not None:
            self.console.to_link()
        self.hal.outputs_off()
        self.board = None
        self._counters["resets"] += 1
        self._counters["lost_in_reset"] += self.uart.rx.clear() + self.uart.tx.clear()
        self.hal.reset_line_tap()
        self.resets.append(self.clock.t)
        self._boot_at = self.clock.t + self.boot_ms / 1000.0

    def _on_done(self, wid: int, targets_milli) -> None:
        self.executed.append((self.hal.ticks_ms(), int(wid), tuple(int(x) for x in targets_milli)))

    def _tap(self, t: float, line: bytes) -> None:
        if self.on_line is not None:
            self.on_line(t, line)

    # ------------------------------------------------------------ hooks of the one who serves it
    def _booted(self) -> None:
        """The firmware has booted (a runner may have started new processes)."""

    def _from_host(self) -> bytes:
        """Bytes the host has sent since the last tick (stepped by hand: `inject` puts them in)."""
        return b""

    def _to_host(self, out: bytes) -> None:
        """Bytes that have left the board for the host in this tick (stepped by hand: `read_output`)."""
        if out:
            self._out += out

    def _serving_thread(self) -> bool:
        """Whether this is the thread that serves the board (a firmware crash there is kept, not raised)."""
        return False

    def _check_not_running(self) -> None:
        """Stepping by hand while a thread runs the board is an error (stepped by hand: nobody does)."""

    # ------------------------------------------------------------ one tick
    def _tick(self, dus: int) -> None:
        """Advance the sim clock by dus microseconds and run one pass of the board; the
        host's bytes read now (`_from_host`: from the pty) arrive at the board now."""
        self.clock.advance_us(dus)
        now = self.clock.t
        if self._reset_times and self._reset_times[0] <= now:
            self._reset_times.pop(0)
            self._begin_reset()
        data = self._from_host()
        if data and self.console is not None:
            data = self.console.from_host(data, now)
        if data:
            self.uart.host_write(data, now)
        if self.board is None and self._boot_at is not None and now >= self._boot_at:
            self._boot()
        if self.board is not None:
            try:
                self.board.poll()
            except Exception:
                # the board stops (until a reset), as an unhandled exception stops main.py
                self.crash = traceback.format_exc()
                self.hal.outputs_off()
                self.board = None
                if not self._serving_thread():
                    raise
        elif self._boot_at is not None:
            self._counters["lost_in_reset"] += self.uart.rx.clear()
        out = self.uart.host_read(now + 1e-9)
        if self.console is not None:
            out += self.console.poll(now + 1e-9)
        self._to_host(out)
        self.plant.advance_to(now)

    def _next_due(self, limit_us: int) -> int:
        """When the next pass should run: at `limit_us`, or earlier when a line end
        or an e-stop byte becomes readable by the firmware, or a line end leaves
        the board for the host (the real firmware polls far more often than once a
        millisecond; this keeps reply latency exact without polling every byte)."""
        due = limit_us
        now = self.clock.us
        for lane in (self.uart.rx, self.uart.tx):
            t = lane.next_mark()
            if t is not None:
                us = int(math.ceil(t * 1e6 - 1e-3))
                if now < us < due:
                    due = us
        return due

    def _advance_to(self, target_us: int) -> None:
        while self.clock.us < target_us:
            self._tick(self._next_due(min(target_us, self.clock.us + self.tick_us)) - self.clock.us)

    # ------------------------------------------------------------ stepping by hand (lockstep)
    def advance(self, seconds: float) -> None:
        """Advance sim time by `seconds` in 1 ms ticks (lockstep use)."""
        self._check_not_running()
        with self._lock:
            self._advance_to(self.clock.us + int(round(seconds * 1e6)))

    def step(self, n: int = 1) -> None:
        """Advance n control periods."""
        self.advance(n * self.period_ms / 1000.0)

    run_for = advance

    def run_until(self, pred: Callable[[], bool], max_s: float = 10.0) -> bool:
        """Tick until pred() is true or max_s of sim time has passed; returns pred()."""
        self._check_not_running()
        end = self.clock.us + int(max_s * 1e6)
        with self._lock:
            while not pred():
                if self.clock.us >= end:
                    return False
                self._tick(self._next_due(min(end, self.clock.us + self.tick_us)) - self.clock.us)
        return True

    def inject(self, data: bytes) -> None:
        """Bytes from the host, arriving now (they go through the paced, faulty rx lane)."""
        with self._lock:
            data = bytes(data)
            if self.console is not None:
                data = self.console.from_host(data, self.clock.t)
            self.uart.host_write(data, self.clock.t)

    def read_output(self) -> bytes:
        """Bytes that have left the board for the host since the last call (no-pty use)."""
        with self._lock:
            out = bytes(self._out)
            self._out.clear()
            return out

    # ------------------------------------------------------------ control
    def reset(self) -> None:
        """Reset the board now (asynchronous when the thread runs: takes effect at the next tick)."""
        self.schedule_reset(self.now())

    def schedule_reset(self, t: float) -> None:
        """Reset the board at sim time t (s)."""
        with self._lock:
            bisect.insort(self._reset_times, float(t))

    def schedule_stall(self, joint: int, t: float) -> None:
        """Stall joint `joint` (1..n, as in the protocol) from sim time t (s) on,
        like Faults.stall but decided while the emulator runs."""
        if not (isinstance(joint, int) and 1 <= joint <= self.n) or not t >= 0:
            raise ArmbridgeError(f"stall {joint}@{t}: the {self.device} board has joints 1..{self.n}, "
                                 "the time must be >= 0")
        with self._lock:
            self.plant.stall(joint - 1, float(t))

    def now(self) -> float:
        """Sim time in seconds."""
        return self.clock.t

    @property
    def state(self) -> str:
        b = self.board
        if b is None:
            if self.console is not None and self.console.mode == "repl":
                return "REPL"
            return "CRASHED" if self.crash else "RESET"
        return b.state

    @property
    def outputs_off_at(self) -> list[float]:
        return self.hal.outputs_off_at

    @property
    def estop_byte_at(self) -> list[float]:
        return self.hal.estop_byte_at

    @property
    def counters(self) -> dict:
        """Link faults per lane ("rx": host->board, "tx": board->host: bytes, drop,
        corrupt, dup, delay) and resets, lost_in_reset, overruns; host_line_gap_s: the longest
        time between two host lines reaching the firmware (what its watchdog sees)."""
        c: dict = dict(self.uart.counters)
        c.update(self._counters)
        c["host_line_gap_s"] = self.uart.rx.longest_line_gap
        return c

    def positions(self) -> np.ndarray:
        """True joint positions (rad), without sensor noise."""
        with self._lock:
            self.plant.advance_to(self.clock.t)
            return self.plant.q.copy()

    def close(self) -> None:
        """Close the firmware runner, the REPL console and the filesystem. The records stay readable."""
        if not self._closed:
            self._closed = True
            self.runner.close()
            if self.console is not None:
                self.console.close()
            if self.fs is not None:
                self.fs.close()
