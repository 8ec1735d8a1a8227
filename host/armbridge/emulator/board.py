"""An emulated board served: a SimBoard (simboard.py) on a pty, run by a thread.

`EmulatedBoard("esp32")` is a `SimBoard` (the real firmware on a simulated
HAL, its tick machinery, resets, records) with what serves it to a host:
`start()` opens a pty (and the `link` symlink) and runs the board in a
background thread, `stop()` ends both. Its clock follows the wall clock, or
the host in lockstep, by `speed`:

Clock modes (`speed`):
  1.0   paced to the wall clock (default). Between ticks the loop waits in
        `select` on the pty master, so a byte from the host is taken in with
        sub-millisecond latency; while it catches up with the wall clock it
        still reads the host's bytes every tick.
  K>0   sim time runs K times faster (or slower) than wall time. When the
        machine cannot keep up, sim time runs slower, `counters["overruns"]`
        counts the catch-ups given up, and the emulator says so (`on_note`,
        `notes`, `pace()`).
  0     lockstep: no wall clock. Without `start()`, the caller drives it
        (SimBoard's `step(n)`, `run_for(s)`, `run_until(pred)`, `inject`,
        `read_output`). With `start()`, a thread runs it as fast as it can,
        10 ms an iteration, on a pty; a host in this process that `couple()`s
        to it (`emu:` ports do) holds it within HOST_LEAD_S of sim time of its
        own last read, so a host busy elsewhere (or starved of the CPU) never
        finds the board's watchdog fired for want of its keep-alive.

Apart from simboard.py because this is the board against the wall clock and
the operating system (threads, `select`, a pty, real-time priority, the pace
kept or lost); the tick machinery knows none of them.
"""
from __future__ import annotations

import select
import threading
import time
import traceback
from typing import Any, Callable

from armbridge.emulator.faults import Faults
from armbridge.emulator.pace import PaceLog, realtime
from armbridge.emulator.pty import Pty, open_pty
from armbridge.emulator.registry import BoardSpec
from armbridge.emulator.simboard import SimBoard
from armbridge.errors import ArmbridgeError


class EmulatedBoard(SimBoard):
    """A board running its real firmware on a simulated HAL, served on a pty; see the module docstring.

    device, speed (clock mode: 1.0 wall clock, K faster, 0 lockstep), faults,
    seed and the keyword options (interpreter, q0, plant_params, firmware_root,
    tick_offset_ms, boot_ms, on_line, fs_dir): as SimBoard's. link: optional
    symlink to the pty (owned: see pty.py). on_note(text): what the emulator has
    to say while it runs (a paced one that cannot keep the wall clock says so;
    also kept in `notes`). realtime: run the emulator thread and the runner's
    processes at real-time priority (pace.realtime; said when refused).
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
        on_note: Callable[[str], None] | None = None,
        realtime: bool = False,
        **options: Any,
    ) -> None:
        self.link = link
        self.on_note = on_note
        self.realtime = realtime
        self._pty: Pty | None = None
        self._pty_dropped = 0            # bytes nobody read, on ptys already closed
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._pace: tuple[float, int, float] | None = None  # (wall0, sim0 us, sim us per wall s)
        self._host_us = 0.0  # latest host_time(), us: it never runs backwards
        self._coupled = False  # a host in this process reads the pty (lockstep waits for it)
        self._host_read_us = 0  # sim time of the coupled host's latest read
        self.notes: list[str] = []  # what the emulator had to say while running (pace_note)
        super().__init__(device, speed, faults, seed, **options)
        self._pace_log = PaceLog(self.device)

    # ------------------------------------------------------------ SimBoard's hooks
    def _booted(self) -> None:
        if self.realtime and self._thread is not None:
            realtime(self._runner_pids())  # a runner may start new processes at a boot

    def _from_host(self) -> bytes:
        return self._pty.read() if self._pty is not None else b""

    def _to_host(self, out: bytes) -> None:
        if self._pty is None:
            super()._to_host(out)
            return
        if out:
            self._pty.pending += out
        if self._pty.pending:
            self._pty.flush()

    def _serving_thread(self) -> bool:
        return self._thread is not None and threading.current_thread() is self._thread

    def _check_not_running(self) -> None:
        if self._thread is not None:
            raise RuntimeError("the emulator thread is running; stop() it before stepping by hand")

    def _runner_pids(self) -> list[int]:
        pids = getattr(self.runner, "pids", None)
        return list(pids()) if callable(pids) else []

    # ------------------------------------------------------------ clocks
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
    def port(self) -> str | None:
        return self._pty.name if self._pty is not None else None

    @property
    def link_note(self) -> str | None:
        """What start() had to say about the link (a dead owner's link taken over)."""
        return self._pty.note if self._pty is not None else None

    @property
    def counters(self) -> dict:
        """SimBoard's counters and pty_dropped: bytes the host never read."""
        c = super().counters
        c["pty_dropped"] = self._pty_dropped + (self._pty.dropped if self._pty is not None else 0)
        return c

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
        super().close()

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
