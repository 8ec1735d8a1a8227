"""An emulated board: a board's real firmware on a simulated HAL, served on a pty.

This is the board-independent machinery; what differs between boards is data
(`registry.BoardSpec`: firmware, plant, HAL, clock, identity) and the firmware
runner (`runner.py`: MicroPython under CPython, the same under the real
MicroPython interpreter, ...). `EmulatedBoard("esp32")` builds the runner, reads
the firmware's config, builds the plant and the HAL from the spec (sim clock,
plant, `PacedUart`, persistent memory) and boots the board, which prints BOOT.
Each iteration of the emulator advances the sim clock by one tick (1 ms),
moves host bytes into the UART, calls `board.poll()`, moves the bytes that
have left the board to the host, and integrates the plant.

Clock modes (`speed`):
  1.0   paced to the wall clock (default). Between ticks the loop waits in
        `select` on the pty master, so a byte from the host is taken in with
        sub-millisecond latency; while it catches up with the wall clock it
        still reads the host's bytes every tick.
  K>0   sim time runs K times faster (or slower) than wall time. When the
        machine cannot keep up, sim time runs slower, `counters["overruns"]`
        counts the catch-ups given up, and the emulator says so (`on_note`,
        `notes`, `pace()`).
  0     lockstep: no wall clock. Without `start()`, the caller drives it:
        `step(n)` advances n control periods (10 ms each), `run_for(s)`,
        `run_until(pred)`, with `inject(bytes)` / `read_output()` standing for
        the host. With `start()`, a thread runs it as fast as it can, 10 ms an
        iteration, on a pty; a host in this process that `couple()`s to it
        (`emu:` ports do) holds it within HOST_LEAD_S of sim time of its own
        last read, so a host busy elsewhere (or starved of the CPU) never
        finds the board's watchdog fired for want of its keep-alive.

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
import select
import threading
import time
import traceback
import types
from pathlib import Path
from typing import Any, Callable

import numpy as np

from armbridge.boards.files import board_files
from armbridge.emulator.faults import Faults
from armbridge.emulator.plant import PlantParams
from armbridge.emulator.pace import PaceLog, realtime
from armbridge.emulator.pty import Pty, open_pty
from armbridge.emulator.boardfs import BoardFs
from armbridge.emulator.registry import BoardSpec, MicroPythonFirmware, board_spec
from armbridge.emulator.repl import Console, cooked
from armbridge.emulator.runner import boot_from, firmware_config, make_runner
from armbridge.emulator.simhal import PersistentMemory, SimClock
from armbridge.emulator.uart import PacedUart
from armbridge.errors import ArmbridgeError
from armbridge.resources import firmware_dir


class EmulatedBoard:
    """A board running its real firmware on a simulated HAL; see the module docstring.

    device: a name in registry.BOARDS, or a BoardSpec. speed: clock mode (1.0
    wall clock, K faster, 0 lockstep). faults: `Faults`. seed: seeds the plant
    noise and the link faults. link: optional symlink to the pty (owned: see
    pty.py). interpreter: the firmware runner ("cpython", "micropython"; None:
    the spec's default). q0, plant_params: override the spec's. on_line(t, line):
    called with every line the firmware writes (sim seconds, bytes without LF),
    before link faults. on_note(text): what the emulator has to say while it runs
    (a paced one that cannot keep the wall clock says so; also kept in `notes`).
    realtime: run the emulator thread and the runner's processes at real-time
    priority (pace.realtime; said when refused).
    """

    MAX_CATCHUP_S = 0.2     # paced modes: a backlog larger than this is given up
    HOST_LEAD_S = 0.05      # lockstep with a coupled host: sim time runs at most this far past its last read

    def __init__(
        self,
        device: str | BoardSpec = "esp32",
        speed: float = 1.0,
        faults: Faults | None = None,
        seed: int = 0,
        link: str | None = None,
        *,
        interpreter: str | None = None,
        q0=None,
        plant_params: PlantParams | None = None,
        firmware_root: str | os.PathLike | None = None,
        tick_offset_ms: int = 0,
        boot_ms: float = 250.0,
        on_line: Callable[[float, bytes], None] | None = None,
        fs_dir: str | os.PathLike | None = None,
        on_note: Callable[[str], None] | None = None,
        realtime: bool = False,
    ) -> None:
        spec = board_spec(device)
        self.spec = spec
        self.device = spec.name
        if not speed >= 0:
            raise ArmbridgeError(f"speed {speed} must be >= 0 (0 = lockstep)")
        self.speed = float(speed)
        self.faults = faults or Faults()
        self.seed = seed
        self.link = link
        self.boot_ms = boot_ms
        self.on_line = on_line
        self.on_note = on_note
        self.realtime = realtime
        self.tick_us = int(spec.tick_us)   # one iteration of the emulator (1 ms of sim time)
        root = Path(firmware_root) if firmware_root is not None else firmware_dir()
        self.runner = make_runner(spec, interpreter, root)
        self.interpreter: str = getattr(self.runner, "interpreter", interpreter or spec.interpreters[0])

        self.cfg: Any = firmware_config(spec, root)
        self.period_ms = int(getattr(self.cfg, "PERIOD_MS", 10))
        self.clock = SimClock()
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
        self.fs: BoardFs | None = None
        self.console: Console | None = None
        if isinstance(spec.firmware, MicroPythonFirmware):
            self.fs = BoardFs.for_board([root / d for d in spec.firmware.dirs], self.hal.files, fs_dir)
            self.console = Console(self.fs, self.uart.bytes_per_s, self._interrupt, self._repl_reset)

        # (board_ms, id, (q1..qn) in milli-units as the W line carried them) of every
        # completed waypoint (the firmware's on_done hook), across resets.
        self.executed: list[tuple[int, int, tuple[int, ...]]] = []
        self.boots: list[float] = []                # sim times of BOOT (board constructions)
        self.resets: list[float] = []               # sim times resets began
        self.crash: str | None = None               # traceback if the firmware raised
        self._reset_times = sorted(float(t) for t in self.faults.reset_at)
        self._boot_at: float | None = None
        self._counters = {"resets": 0, "lost_in_reset": 0, "overruns": 0}
        self._out = bytearray()          # bytes to the host when there is no pty
        self._pty: Pty | None = None
        self._pty_dropped = 0            # bytes nobody read, on ptys already closed
        self._lock = threading.RLock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._closed = False
        self._pace: tuple[float, int, float] | None = None  # (wall0, sim0 us, sim us per wall s)
        self._host_us = 0.0  # latest host_time(), us: it never runs backwards
        self._coupled = False  # a host in this process reads the pty (lockstep waits for it)
        self._host_read_us = 0  # sim time of the coupled host's latest read
        self._pace_log = PaceLog(self.device)
        self.notes: list[str] = []  # what the emulator had to say while running (pace_note)

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
        if self.realtime and self._thread is not None:
            realtime(self._runner_pids())  # a runner may start new processes at a boot

    def _runner_pids(self) -> list[int]:
        pids = getattr(self.runner, "pids", None)
        return list(pids()) if callable(pids) else []

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

    # ------------------------------------------------------------ one tick
    def _tick(self, dus: int) -> None:
        """Advance the sim clock by dus microseconds and run one pass of the board; the
        host's bytes read from the pty now arrive at the board now."""
        self.clock.advance_us(dus)
        now = self.clock.t
        if self._reset_times and self._reset_times[0] <= now:
            self._reset_times.pop(0)
            self._begin_reset()
        if self._pty is not None:
            data = self._pty.read()
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
                if self._thread is None or threading.current_thread() is not self._thread:
                    raise
        elif self._boot_at is not None:
            self._counters["lost_in_reset"] += self.uart.rx.clear()
        out = self.uart.host_read(now + 1e-9)
        if self.console is not None:
            out += self.console.poll(now + 1e-9)
        if out:
            if self._pty is not None:
                self._pty.pending += out
            else:
                self._out += out
        if self._pty is not None and self._pty.pending:
            self._pty.flush()
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

    # ------------------------------------------------------------ lockstep helpers
    def _check_not_running(self) -> None:
        if self._thread is not None:
            raise RuntimeError("the emulator thread is running; stop() it before stepping by hand")

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

    def host_time(self) -> float:
        """Seconds on the emulator's time scale, for a host's clock. Paced: the
        sim time the pacer aims at (wall clock times `speed`, smooth between
        ticks) but never more than a tick ahead of the board's own clock, so a
        host's timers do not run out early while a starved emulator lags (after
        its thread has stopped, the pacer's aim alone, so timers still run out).
        Lockstep, or before the pacer starts: sim time (the wall clock means
        nothing there)."""
        pace = self._pace
        if self.speed <= 0 or pace is None:
            return self.clock.t
        wall0, sim0_us, rate = pace
        us = sim0_us + (time.monotonic() - wall0) * rate
        if self.running:
            us = min(us, self.clock.us + self.tick_us)
        self._host_us = max(self._host_us, us)  # never backwards
        return self._host_us / 1e6

    def wall_time(self, t: float) -> float:
        """The time.monotonic() at which sim time t (s) happened (paced modes only):
        lets a host compare its own clock with the board's records."""
        if self._pace is None:
            raise ArmbridgeError("wall_time needs a paced emulator (speed > 0) that has started")
        wall0, sim0_us, rate = self._pace
        return wall0 + (t * 1e6 - sim0_us) / rate

    @property
    def state(self) -> str:
        b = self.board
        if b is None:
            if self.console is not None and self.console.mode == "repl":
                return "REPL"
            return "CRASHED" if self.crash else "RESET"
        return b.state

    @property
    def port(self) -> str | None:
        return self._pty.name if self._pty is not None else None

    @property
    def link_note(self) -> str | None:
        """What start() had to say about the link (a dead owner's link taken over)."""
        return self._pty.note if self._pty is not None else None

    @property
    def outputs_off_at(self) -> list[float]:
        return self.hal.outputs_off_at

    @property
    def estop_byte_at(self) -> list[float]:
        return self.hal.estop_byte_at

    @property
    def counters(self) -> dict:
        """Link faults per lane ("rx": host->board, "tx": board->host: bytes, drop,
        corrupt, dup, delay) and resets, lost_in_reset, pty_dropped, overruns; host_line_gap_s: the
        longest time between two host lines reaching the firmware (what its watchdog sees)."""
        c: dict = dict(self.uart.counters)
        c.update(self._counters)
        c["host_line_gap_s"] = self.uart.rx.longest_line_gap
        c["pty_dropped"] = self._pty_dropped + (self._pty.dropped if self._pty is not None else 0)
        return c

    def positions(self) -> np.ndarray:
        """True joint positions (rad), without sensor noise."""
        with self._lock:
            self.plant.advance_to(self.clock.t)
            return self.plant.q.copy()

    # ------------------------------------------------------------ thread
    def start(self) -> "EmulatedBoard":
        """Open the pty (and the symlink) and run the emulator in a background thread."""
        if self._thread is not None:
            return self
        if self._pty is None:
            if self._closed:
                raise ArmbridgeError("this emulator was stopped; build a new EmulatedBoard")
            try:
                self._pty = open_pty(self.link)
            except OSError as exc:
                raise ArmbridgeError(f"cannot open a pseudo-terminal for the emulator: {exc}") from exc
            self._pty.pending += self._out  # BOOT written before the pty existed
            self._out.clear()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"emulator-{self.device}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """End the emulator: stop the thread, close the pty (removing the symlink
        and its lock) and the firmware runner. The records stay readable."""
        t = self._thread
        if t is not None:
            self._stop.set()
            t.join(timeout=5.0)
            self._thread = None
        if self._pty is not None:
            self._pty.close()
            self._pty_dropped += self._pty.dropped
            self._pty = None
        if not self._closed:
            self._closed = True
            self.runner.close()
            if self.console is not None:
                self.console.close()
            if self.fs is not None:
                self.fs.close()

    close = stop

    def __enter__(self) -> "EmulatedBoard":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def __del__(self) -> None:
        try:
            self.stop()
        except Exception:
            pass

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _run(self) -> None:
        if self.realtime:
            note = realtime(self._runner_pids(), this_thread=True)
            if note is not None:
                self._say(note)
        try:
            if self.speed == 0:
                self._run_lockstep()
            else:
                self._run_paced()
        except Exception:
            if self.crash is None:
                self.crash = traceback.format_exc()

    def couple(self) -> None:
        """A host in this process reads this board's pty (`emu:` ports): in lockstep the
        thread then never runs more than HOST_LEAD_S of sim time past the host's latest
        read (`host_reading`), so sim time waits for a host that is busy or starved."""
        self._host_read_us = self.clock.us
        self._coupled = True

    def host_reading(self) -> None:
        """The coupled host is about to read (transport.Port.read calls this)."""
        self._host_read_us = self.clock.us

    def _run_lockstep(self) -> None:
        per = self.period_ms * 1000
        lead = int(self.HOST_LEAD_S * 1e6)
        while not self._stop.is_set():
            if self._coupled and self.clock.us - self._host_read_us >= lead:
                time.sleep(0.0002)  # the host has not read for HOST_LEAD_S of sim time: wait for it
                continue
            with self._lock:
                self._advance_to(self.clock.us + per)
            time.sleep(0)  # let other threads run

    def _run_paced(self) -> None:
        """Sim time follows the wall clock times `speed`. Every pass reads the host's bytes
        (stamped with the sim time of the tick that reads them, which is the time a coupled
        host's clock shows: `host_time` never runs more than a tick ahead of the board), so
        a host's line is never held back while the loop catches up. A backlog over
        MAX_CATCHUP_S is given up (the board's time slips behind the wall clock) and said
        (`pace_note`): on a pty, a host on the wall clock would otherwise find the board
        slow without being told."""
        assert self._pty is not None
        master = self._pty.master
        tick = self.tick_us
        rate = self.speed * 1e6  # sim us per wall second
        wall0 = time.monotonic()
        sim0 = self.clock.us
        self._pace = (wall0, sim0, rate)
        self._pace_log.start(wall0, sim0)
        while not self._stop.is_set():
            now = time.monotonic()
            target = sim0 + int((now - wall0) * rate)  # sim time of the wall clock now
            behind = target - self.clock.us
            self._pace_log.lag(behind / 1e6)
            if behind > self.MAX_CATCHUP_S * 1e6:  # cannot keep up: give the backlog up
                self._counters["overruns"] += 1
                self._pace_log.slipped(now, self.clock.us, behind / 1e6, self._say)
                wall0, sim0 = now, self.clock.us
                self._pace = (wall0, sim0, rate)
                continue
            with self._lock:
                due = self._next_due(self.clock.us + tick)
                n = 0
                while due <= target and n < 50:  # catch up with the wall clock
                    self._tick(due - self.clock.us)
                    due = self._next_due(self.clock.us + tick)
                    n += 1
            if n:
                continue
            wait = (due - target) / rate
            try:
                r, _, _ = select.select([master], [], [], max(wait, 0.0))
            except (OSError, ValueError):
                return
            if r:  # bytes from the host: take them in at the sim time of their arrival
                target = sim0 + int((time.monotonic() - wall0) * rate)
                with self._lock:
                    # A wake-up late by more than a tick (a starved CPU) catches up in
                    # ticks (reading the pty in each), so the firmware never sees its
                    # clock jump.
                    while target - self.clock.us > tick:
                        self._tick(self._next_due(self.clock.us + tick) - self.clock.us)
                    self._tick(max(1, target - self.clock.us))

    def _say(self, text: str) -> None:
        self.notes.append(text)
        if self.on_note is not None:
            self.on_note(text)

    def pace(self) -> dict:
        """How well a paced emulator kept the wall clock (docs/emulator.md, "Pace"): the
        speed asked, the speed achieved (sim over wall time since start), the largest lag
        behind the wall clock seen (s), and how often and how much of a backlog it gave up."""
        return self._pace_log.report(self.speed, time.monotonic(), self.clock.us)
