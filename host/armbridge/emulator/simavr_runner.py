"""C firmware (an AVR .elf) run for real in simavr, in lockstep with the emulator.

The runner of `runner.py` for `ElfFirmware` boards (`interpreter="simavr"`).
The chip is simulated cycle by cycle by a small C harness on libsimavr
(`simavr/harness.c`: its header documents the request/answer lines), a child
process driven over pipes. The emulator keeps everything else (sim clock,
`PacedUart` with its link faults, resets, pty, threads, plant); each
`board.poll()` is one emulator tick:

  1. the UART bytes the rx lane delivers by the tick's end are fed to UART0,
     each at its own cycle (one byte time before the lane's delivery time, so
     that the receive flag rises when the lane says the byte has arrived);
  2. the HAL's sensor values (ADC millivolts per channel, levels of the input
     pins it drives) are held for the slice; the harness runs the chip up to
     the tick's cycle;
  3. the bytes the chip wrote to UDR0 go into the tx lane at their cycles,
     paced at the chip's own byte time (the harness reports the cycles a frame
     takes from the UBRR, U2X and frame format the firmware programmed: 85 us
     for the Arduino core's 115200, really 117,647 baud, not the lane's nominal
     86.8 us, which would queue a back-to-back stream ever later), and
     every change of the watched registers (the HAL's output pins: port, DDR,
     timer) goes to the HAL at its own time, which decodes it (duty from OCRnx
     and COMnx1) and drives the plant.

Time: the chip's cycle counter maps onto the emulator's clock, `cycle0` at
`us0` (set at every boot); F_CPU is the harness's (16 MHz for the Mega).

A reset (`boot()` again) resets the chip as its reset pin does: RAM and I/O
cleared, flash and EEPROM kept. The EEPROM also goes into the HAL's
persisted memory whenever the firmware changes it, and a fresh harness
starts from it (`eeprom_file=` keeps it in a file across emulator runs).

The board's `state` and the `on_done` hook come from the lines the firmware
writes, as a host would see them unfaulted: `BOOT`'s and `T`'s state and the
latching events; a `W` it answered `OK` is queued by its id with the values
of the `W` that first queued that id (a replayed `OK`, or an id already
completed, adds nothing), and each `EV DONE id` completes the queued
waypoints up to `id`, in queue order, each once (`CLR`, a latch, a `BOOT`
or a new session flush the queue; `CLR` and a new session also forget the
completed ids).

HAL methods the board calls (pump_hal.PumpSimHal has them): `elf_watch()` ->
data addresses; `elf_adc()` -> (ADCSRA, ADSC bit, ADMUX) or None, whose
conversion starts come to `elf_adc_start(t, channel)`; `elf_inputs()` ->
({adc channel: mV}, {"C7": level}); `elf_outputs(t, regs)`; `uart_read_timed(until)` -> [(t, byte)];
`uart_write_at(t, data)`; `uart_tx_byte_time(seconds)`; `load_persist()` / `save_persist(data)`.
"""
from __future__ import annotations

import re
import tempfile
import weakref
from pathlib import Path
from typing import Any, Callable

from armbridge.emulator.lineproc import LineProcess
from armbridge.emulator.simavr.mega2560 import ElfImage, read_elf
from armbridge.emulator.simavr_chip import ANSWER_TIMEOUT_S, harness_binary
from armbridge.errors import ArmbridgeError
from armbridge.link import protocol as P

STATES = {7: "done (slept with interrupts off)", 8: "crashed"}
# Timed whenever the image has them (docs/emulator.md, "Syringe-pump board in simavr"):
# the control period's work, and the checks of a host line (CRC, then grammar and ranges).
# The control period's interrupt (TIMER5_COMPA, vector 47 on the Mega 2560) and one main-
# loop pass (main_loop_pass) where the image has them: the period's start and length, the
# main loop's longest pass (pump_hal.pump_timing).
DEFAULT_PROBES = {"control": "PumpBoard::control", "crc": "ab_crc32", "parse": "ab_parse_command",
                  "isr": "__vector_47", "period": "ctl_period", "pass": "main_loop_pass"}


class FirmwareCrashed(RuntimeError):
    """The chip stopped in simavr (a crash, or sleep with interrupts off)."""


def fresh_eeprom(hal: Any, size: int = 4096) -> bytes | None:
    """The EEPROM of a board that has never run: erased (0xFF), but for the serial the
    firmware reports as IDENT's uid (config.h EE_SERIAL): one per physical board the
    emulator stands for, the HAL's `uid_hex` (a drawn plant's seed makes another board,
    the nominal board is always the same), as a factory would have written it. None
    when the firmware keeps no serial (then its EEPROM starts all erased)."""
    cfg = getattr(getattr(hal, "plant", None), "cfg", None)
    addr = getattr(cfg, "EE_SERIAL", None)
    uid = getattr(hal, "uid_hex", None)
    if addr is None or not uid:
        return None
    serial = int(uid, 16) & 0xFFFFFFFF
    if serial in (0, 0xFFFFFFFF):          # the firmware's "erased": it would make its own
        serial ^= 0x5EED0001
    data = bytearray(b"\xff" * size)
    data[int(addr):int(addr) + 4] = serial.to_bytes(4, "little")
    return bytes(data)


class Harness(LineProcess):
    """One harness child process (the lockstep line protocol of harness.c)."""

    def __init__(self, elf: Path, eeprom_file: Path, timeout: float = ANSWER_TIMEOUT_S) -> None:
        super().__init__([str(harness_binary()), "-e", str(eeprom_file), str(elf)], "the simavr harness", timeout,
                         encoding="ascii")
        fields = self.readline().split()
        if not fields or fields[0] != "READY":
            raise ArmbridgeError(f"the simavr harness said {' '.join(fields)[:200]!r} instead of READY{self.stderr()}")
        self.mcu, self.hz, self.ramend, self.e2end, self.cycle = fields[1], *map(int, fields[2:6])

    def call(self, line: str) -> str:
        answer = super().call(line)
        if answer.startswith("ERR"):
            raise ArmbridgeError(f"the simavr harness refused {line[:60]!r}: {answer}")
        return answer

    def close(self, last: bytes | None = b"QUIT\n", wait_s: float = 5.0) -> None:
        super().close(last, wait_s)


def _stop(state: dict) -> None:
    h = state.pop("harness", None)
    if h is not None:
        h.close()
    tmp = state.pop("tmp", None)
    if tmp is not None:
        tmp.cleanup()


class SimavrRunner:
    """Boots an .elf in simavr (see the module docstring); `boot(hal, cfg)` -> `SimavrBoard`.

    probes: {name: function} whose calls the harness times (entry time and
    duration in cycles of each), kept in `stats["probes"][name]` (None:
    DEFAULT_PROBES, those the image has). eeprom_file: where the
    EEPROM lives across emulator runs (None: a temporary file, the HAL's
    persisted memory carries it across resets)."""

    interpreter = "simavr"

    def __init__(self, elf: Path, probes: dict[str, str] | None = None, eeprom_file: Path | None = None) -> None:
        self.elf_path = Path(elf)
        self.elf: ElfImage = read_elf(self.elf_path)
        self.probes: dict[str, int] = {}
        for name, sym in (DEFAULT_PROBES if probes is None else probes).items():
            addr = self.elf.function(sym)
            if addr is not None:
                self.probes[name] = addr
            elif probes is not None:
                raise ArmbridgeError(f"probe {name}: {self.elf_path.name} has no function {sym!r}")
        self.modules: dict = {}     # the firmware does not run in this process
        self._state: dict[str, Any] = {}
        self._finalizer = weakref.finalize(self, _stop, self._state)
        self.eeprom_file = Path(eeprom_file) if eeprom_file is not None else None
        self.eeprom_dir: Path | None = None   # emu:arduino_pump?fs=DIR: the board's EEPROM kept in DIR
        self.stats: dict[str, Any] = {"min_sp": None, "lost": 0, "probes": {n: [] for n in self.probes}}
        self.harness: Harness | None = None

    def boot(self, hal: Any, cfg: Any) -> "SimavrBoard":
        h = self.harness
        if h is not None and h.proc.poll() is None and not self._state.get("stopped"):
            h.cycle = int(h.call("RESET").split()[1])
        else:
            if h is not None:
                _stop(self._state)
            h = self.harness = Harness(self.elf_path, self._eeprom_path(hal))
            self._state["harness"] = h
            h.call("WATCH " + " ".join(str(a) for a in hal.elf_watch()))
            h.call("PROBE " + " ".join(map(str, self.probes.values())))
            adc = hal.elf_adc()
            if adc is not None:
                h.call("ADCSTART %d %d %d" % adc)
        self._state["stopped"] = False
        return SimavrBoard(self, h, hal, int(cfg.N_JOINTS))

    def _eeprom_path(self, hal: Any) -> Path:
        if self.eeprom_file is not None:
            return self.eeprom_file
        if self.eeprom_dir is not None and getattr(hal, "uid_hex", None):   # the board's EEPROM across emulator runs
            path = Path(self.eeprom_dir) / f"{hal.uid_hex}.eeprom"
            if not path.exists():
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_bytes(fresh_eeprom(hal) or b"\xff" * 4096)
            return path
        if "tmp" not in self._state:
            self._state["tmp"] = tempfile.TemporaryDirectory(prefix="armbridge-eeprom-")
        path = Path(self._state["tmp"].name) / "eeprom.bin"
        data = hal.load_persist()
        if data:
            path.write_bytes(bytes(data))
        else:
            fresh = fresh_eeprom(hal)
            if fresh is not None:
                path.write_bytes(fresh)
        return path

    def stopped(self) -> None:
        self._state["stopped"] = True

    def pids(self) -> list[int]:
        """The processes the chip runs in (the harness), for real-time scheduling."""
        h = self.harness
        return [h.proc.pid] if h is not None and h.proc.poll() is None else []

    def close(self) -> None:
        self._finalizer()


_CRC = re.compile(rb"[0-9A-F]{8}")


class SimavrBoard:
    """The emulator's view of the chip (poll(), state, on_done); see the module docstring."""

    def __init__(self, runner: SimavrRunner, h: Harness, hal: Any, n: int) -> None:
        self.runner, self.h, self.hal, self.n = runner, h, hal, n
        self.state = "RESET"
        self.on_done: Callable[..., None] | None = None
        self.cycle0 = self.cycle = h.cycle
        self.us0 = hal.clock.us
        self.byte_s = 10.0 / float(getattr(hal.uart, "baud", 115200))
        self.tx_cycles = 0      # the chip's UART frame in cycles (harness), 0 while its transmitter is off
        self._rx = bytearray()
        self._tx = bytearray()
        self._pending: dict[str, tuple[str, list[str]]] = {}   # host seq -> (verb, args) of lines fed
        self._queue: dict[int, tuple[int, ...]] = {}           # id -> values of the W that first queued it, queue order
        self._epoch = 0                                         # the epoch of the session the board accepted
        self._logged: set[int] = set()                          # ids completed (EV DONE) in this session

    def t_of(self, cycle: int) -> float:
        return (self.us0 + (cycle - self.cycle0) * 1e6 / self.h.hz) / 1e6

    def cycle_of(self, t: float) -> int:
        return self.cycle0 + int(round((t * 1e6 - self.us0) * self.h.hz / 1e6))

    def poll(self) -> None:
        hal, h = self.hal, self.h
        until = self.cycle0 + (hal.clock.us - self.us0) * h.hz // 1_000_000
        if until <= self.cycle:
            return
        fed = hal.uart_read_timed(self.t_of(until) + self.byte_s)
        uart = ",".join(f"{min(max(self.cycle_of(t - self.byte_s), self.cycle), until)}:{b:02x}" for t, b in fed)
        adc, pins = hal.elf_inputs()
        answer = h.call("RUN %d %s %s %s" % (
            until, uart or "-", ",".join(f"{c}:{int(mv)}" for c, mv in adc.items()) or "-",
            ",".join(f"{p}:{int(v)}" for p, v in pins.items()) or "-"))
        f = answer.split()
        if len(f) != 11 or f[0] != "DONE":
            raise ArmbridgeError(f"the simavr harness answered {answer[:200]!r}")
        self.cycle = int(f[1])
        for _, b in fed:
            self._host_byte(b)
        stats = self.runner.stats
        if f[4] != "-":
            watch = hal.elf_watch()
            for rec in f[4].split(";"):
                c, vals = rec.split(":")
                hal.elf_outputs(self.t_of(int(c)), dict(zip(watch, (int(v, 16) for v in vals.split(".")))))
        tx_cycles = int(f[9])
        if tx_cycles and tx_cycles != self.tx_cycles:
            self.tx_cycles = tx_cycles
            hal.uart_tx_byte_time(tx_cycles / h.hz)
        if f[3] != "-":
            for item in f[3].split(","):
                c, b = item.split(":")
                hal.uart_write_at(self.t_of(int(c)), bytes((int(b, 16),)))
                self._board_byte(int(b, 16))
        if f[5] != "-":
            names = list(self.runner.probes)
            for item in f[5].split(","):
                i, c0, d = map(int, item.split(":"))
                stats["probes"][names[i]].append((self.t_of(c0), d))
        if f[10] != "-":
            for item in f[10].split(","):
                c, ch = item.split(":")
                hal.elf_adc_start(self.t_of(int(c)), int(ch))
        sp = int(f[6])
        stats["min_sp"] = sp if stats["min_sp"] is None else min(stats["min_sp"], sp)
        stats["lost"] += int(f[8])
        if f[7] == "1":
            hal.save_persist(bytes.fromhex(h.call("EEPROM").split()[1]))
        if int(f[2]) in STATES:
            self.runner.stopped()
            raise FirmwareCrashed(f"the chip stopped in simavr: {STATES[int(f[2])]}{h.stderr()}")

    # ---------------------------------------------------------------- lines
    def _host_byte(self, b: int) -> None:
        if b == 0x98:          # e-stop: the firmware drops the line it was receiving
            self._rx.clear()
        elif b == 0x0A:
            raw = bytes(self._rx).rstrip(b"\r")
            self._rx.clear()
            # Only a line the board accepts (its CRC from the session's epoch, HELLO's
            # from 0): a damaged copy of a line fed in the same slice as the good one
            # must not lend its values to the good one's OK.
            text, star, crc = raw.rpartition(b"*")
            epoch = 0 if P.is_hello(text) else self._epoch
            if not star or _CRC.fullmatch(crc) is None or P.crc32(text, epoch) != int(crc, 16):
                return
            body = text.decode("latin-1").split()
            if len(body) >= 2:
                self._pending[body[0]] = (body[1], body[2:])
                if len(self._pending) > 256:
                    self._pending.pop(next(iter(self._pending)))
        elif len(self._rx) < 200:
            self._rx.append(b)

    def _board_byte(self, b: int) -> None:
        if b != 0x0A:
            if len(self._tx) < 256:
                self._tx.append(b)
            return
        f = bytes(self._tx).split(b"*", 1)[0].decode("latin-1").split()
        self._tx.clear()
        if len(f) < 2:
            return
        kind = f[1]
        if kind == "BOOT" and len(f) >= 6:
            self.state = f[5]
            self._queue = {}
        elif kind == "T" and len(f) >= 4:
            self.state = f[3]
        elif kind == "OK" and len(f) >= 3:
            verb, args = self._pending.pop(f[2], ("", []))
            if verb == "W" and len(args) >= 2 + self.n:
                try:
                    wid, vals = int(args[0]), tuple(int(x) for x in args[2:2 + self.n])
                except ValueError:
                    pass
                else:   # a replayed OK (or a W resent after a reset) does not queue its id twice
                    if wid not in self._queue and wid not in self._logged:
                        self._queue[wid] = vals
            elif verb == "CLR" or (verb == "HELLO" and len(f) >= 12 and f[-2] == "-"):
                self._queue, self._logged = {}, set()
            if verb == "HELLO" and len(f) >= 5:
                self.state = f[-1]
                if len(args) >= 3 and args[2].isdigit():
                    self._epoch = int(args[2])
        elif kind == "EV" and len(f) >= 4:
            ev = f[3]
            if ev in ("ESTOP", "WDOG", "FAULT"):
                self.state, self._queue = ev, {}
            elif ev in ("HOLD", "RESUME", "START"):
                self.state = {"HOLD": "HOLD"}.get(ev, "RUN")
            elif ev == "CLEAR":
                self.state, self._queue = "IDLE", {}
            elif ev == "DONE" and len(f) >= 5:
                self._done(f[4])

    def _done(self, text: str) -> None:
        try:
            wid = int(text)
        except ValueError:
            return
        if wid not in self._queue:
            return
        while self._queue:   # EV DONE coalesces per control tick: every queued id up to wid
            qid = next(iter(self._queue))
            targets = self._queue.pop(qid)
            self._logged.add(qid)
            if self.on_done is not None:
                self.on_done(qid, targets)
            if qid == wid:
                break
