"""The syringe-pump board's pins in the emulator: the chip's side of `PumpPlant`.

The firmware runs in simavr (simavr_runner.py); this HAL is what its pins
touch. Clock, UART lanes and persisted memory are SimHal's (it subclasses
it; the persisted memory holds the chip's EEPROM, copied whenever the
firmware changes it). The pins come from the firmware's config.h (the cfg:
PIN_EN, PIN_IN1, PIN_IN2, PIN_BEND, PIN_STOP_RET, PIN_STOP_EXT):

    outputs  motor k's L298: EN (PWM duty from OCRnx/COMnx1), IN1/IN2 levels.
             IN1 high, IN2 low: + (the syringe pushes, the joint inflates);
             IN1 low, IN2 high: -; equal: the motor stops. Signed duty in [-1, 1].
    inputs   bend sensor k on ADC channel PIN_BEND[k] (mV from the plant);
             end stops on PIN_STOP_RET[k] / PIN_STOP_EXT[k] (LOW at the stop).

Records for the tests (besides SimHal's outputs_off_at, outputs_on_at,
estop_byte_at): `duty_log` ((t, duties) at every change of the motor pins),
`telemetry` ((t, every T column as int)), `track` ((t, true angles, the T
line's angles) in rad), `adc_starts` ((t, channel) of every ADC conversion
the firmware starts: the control loop's sampling instants).
"""
from __future__ import annotations

import math

from collections import deque
from typing import Any, Callable, cast

import numpy as np

from armbridge.emulator.pump_plant import PumpParams, PumpPlant, PumpTruth, nominal_rig
from armbridge.emulator.simavr import mega2560 as mega
from armbridge.emulator.simhal import ESTOP_BYTE, SimHal
from armbridge.errors import ArmbridgeError

EEPROM_BYTES = 4096      # the ATmega2560's EEPROM


def pump_plant(cfg: Any, params: PumpParams | PumpTruth | None, q0: Any, seed: int) -> PumpPlant:
    """The plant of docs/emulator.md for the firmware's config: each joint's range is its
    upper limit (LIMITS_MRAD), the sensors are calibrated as BEND_DEFAULT, and a full
    stroke at full duty takes SYRINGE_STROKE_MS (the firmware's travel estimate).
    params: the rig's PumpParams, or a PumpTruth (plant=random: pump_plant.hidden_truth)."""
    rng = np.asarray([hi for _lo, hi in cfg.LIMITS_MRAD], dtype=float) / 1000.0
    p: PumpParams | PumpTruth = params if params is not None else nominal_rig(cfg)
    if q0 is not None:
        raise ArmbridgeError("the syringe-pump plant starts deflated (straight joints); it takes no q0")
    plant = PumpPlant(rng, cfg.BEND_DEFAULT, p, seed=seed)
    plant.cfg = cfg     # the HAL's pins (the HAL factory is not handed the config)
    return plant


class PumpSimHal(SimHal):
    """The pump board's pins over a PumpPlant; see the module docstring."""

    has_pen = False

    def __init__(self, clock, plant: PumpPlant, uart, persist=None, *,
                 on_line: Callable[[float, bytes], None] | None = None, **kw: Any) -> None:
        kw.pop("files", None)   # the chip has no filesystem
        super().__init__(clock, cast(Any, plant), uart, persist, on_line=self._watch_line, **kw)
        self.pump = plant
        self._forward = on_line
        self._cfg = getattr(plant, "cfg", None)
        max_log = int(kw.get("max_log", 200_000))
        self.duty_log: deque[tuple[float, tuple[float, ...]]] = deque(maxlen=max_log)
        self.telemetry: deque[tuple[float, tuple[int, ...]]] = deque(maxlen=max_log)
        self.track: deque[tuple[float, tuple[float, ...], tuple[float, ...]]] = deque(maxlen=max_log)
        self.adc_starts: deque[tuple[float, int]] = deque(maxlen=max_log)
        self._pins: tuple | None = None
        self._duties = (0.0,) * plant.n

    # the firmware's pins (config.h) -----------------------------------------
    def _pinmap(self) -> tuple:
        if self._pins is None:
            cfg = self._cfg
            if cfg is None:
                raise ArmbridgeError("the pump HAL needs the firmware's config (its pins)")
            n = self.pump.n
            try:
                en = [mega.pin(p) for p in cfg.PIN_EN[:n]]
                in1 = [mega.pin(p) for p in cfg.PIN_IN1[:n]]
                in2 = [mega.pin(p) for p in cfg.PIN_IN2[:n]]
                ret = [mega.pin(p) for p in cfg.PIN_STOP_RET[:n]]
                ext = [mega.pin(p) for p in cfg.PIN_STOP_EXT[:n]]
                adc = [int(c) for c in cfg.PIN_BEND[:n]]
            except (AttributeError, ValueError) as exc:
                raise ArmbridgeError(f"the pump firmware's pins in config.h: {exc}") from None
            for p in en:
                if p.timer is None:
                    raise ArmbridgeError(f"EN pin {p.number} has no timer PWM on the Mega")
            watch = sorted({a for p in (*en, *in1, *in2) for a in p.watch()})
            self._pins = (en, in1, in2, ret, ext, adc, watch)
        return self._pins

    def elf_watch(self) -> list[int]:
        return list(self._pinmap()[6])

    def elf_adc(self) -> tuple[int, int, int]:
        """ADCSRA, its ADSC bit and ADMUX: the harness logs each conversion the firmware starts."""
        return mega.ADCSRA, mega.ADSC, mega.ADMUX

    def elf_adc_start(self, t: float, channel: int) -> None:
        self.adc_starts.append((t, channel))

    def elf_inputs(self) -> tuple[dict[int, int], dict[str, int]]:
        """Sensors as they are now (the plant is not advanced: the slice runs on them)."""
        _en, _i1, _i2, ret, ext, adc, _w = self._pinmap()
        mv = self.pump.sensor_mv()
        at_ret, at_ext = self.pump.end_stops()
        pins: dict[str, int] = {}
        for k in range(self.pump.n):
            pins[ret[k].name] = 0 if at_ret[k] else 1
            pins[ext[k].name] = 0 if at_ext[k] else 1
        return {adc[k]: int(round(float(mv[k]))) for k in range(self.pump.n)}, pins

    def elf_outputs(self, t: float, regs: dict[int, int]) -> None:
        """A change of the watched registers at sim time t: new duties from then on."""
        en, in1, in2, _r, _e, _a, _w = self._pinmap()
        duties = []
        for k in range(self.pump.n):
            d = en[k].duty(regs)
            a, b = in1[k].level(regs), in2[k].level(regs)
            duties.append(d if a and not b else -d if b and not a else 0.0)
        u = tuple(duties)
        if u == self._duties:
            return
        self.pump.advance_to(max(t, self.pump.t))
        self.pump.drive(u)
        self._duties = u
        self.duty_log.append((t, u))
        on = any(u)
        if on and not self.outputs_enabled:
            self.outputs_on_at.append(t)
        elif not on and self.outputs_enabled:
            self.outputs_off_at.append(t)
        self.outputs_enabled = on

    @property
    def duties(self) -> tuple[float, ...]:
        return self._duties

    def outputs_off(self) -> None:
        """The chip in reset: its pins float, the L298 stops the motors."""
        self._sync()
        self.pump.off()
        if self.outputs_enabled:
            self.outputs_off_at.append(self.clock.t)
            self.duty_log.append((self.clock.t, (0.0,) * self.pump.n))
        self._duties = (0.0,) * self.pump.n
        self.outputs_enabled = False

    # UART with the bytes' own times -------------------------------------------
    def uart_read_timed(self, until: float) -> list[tuple[float, int]]:
        """Bytes the rx lane delivers by sim time `until` (s), with their times."""
        timed = self.uart.rx.pop_timed(until + 1e-9)
        for t, b in timed:
            if b == ESTOP_BYTE:
                self.estop_byte_at.append(t)
        return timed

    def uart_write_at(self, t: float, data: bytes) -> None:
        self.uart.firmware_write(bytes(data), t)
        for b in data:
            if b == 0x0A:
                if self.on_line is not None:
                    self.on_line(t, bytes(self._line))
                self._line.clear()
            elif len(self._line) < 512:
                self._line.append(b)

    def uart_tx_byte_time(self, seconds: float) -> None:
        """The chip's UART sends a byte per `seconds` (its baud divisor and frame, as the
        harness reports them): the tx lane paces its bytes so, not at the nominal baud."""
        self.uart.tx.set_byte_time(seconds)

    def uart_read(self) -> bytes | None:
        raise ArmbridgeError("the pump board's UART is the chip's: simavr_runner feeds it (uart_read_timed)")

    # records -------------------------------------------------------------------
    def _watch_line(self, t: float, line: bytes) -> None:
        parts = line.split(b"*", 1)[0].split()
        n = self.pump.n
        if len(parts) > 5 + n and parts[1] == b"T":
            try:
                cols = tuple(int(x) for x in parts[2:3] + parts[6:])
            except ValueError:
                cols = ()
            if cols:
                self.telemetry.append((t, cols))
                est = tuple(float(x) / 1000.0 for x in cols[1:1 + n])
                self.track.append((t, tuple(float(x) for x in self.pump.q), est))
        if self._forward is not None:
            self._forward(t, line)

    # the arm's HAL calls: not on this board ------------------------------------
    def read_positions(self, out) -> None:
        raise ArmbridgeError("the pump board has no read_positions: its bend sensors are ADC pins")

    def write_outputs(self, efforts) -> None:
        raise ArmbridgeError("the pump board has no write_outputs: its motors are the chip's pins")


def _spread(xs: list[float]) -> dict[str, float]:
    a = np.asarray(xs, dtype=float)
    if not a.size:
        return {"n": 0}
    return {"n": int(a.size), "mean": float(a.mean()), "min": float(a.min()), "max": float(a.max()),
            "std": float(a.std())}


def pump_timing(emu: Any, window: tuple[float, float] | None = None) -> dict[str, Any]:
    """The board's timing in simulated cycles (a simavr-run EmulatedBoard after a run);
    `window` (t0, t1) in sim seconds: only what happened in it (a stream, not its set-up).

    control_period_us: between successive entries of the control period's work
      (PumpBoard::control); jitter = max - min. sample_period_us: the same between
      conversions of joint 1's bend sensor (the control period samples it first).
    isr_period_cycles / isr_jitter_us: the same between starts of the period proper
      (ctl_period, entered from the timer interrupt TIMER5_COMPA after its alignment
      wait), where the image has them; isr_cycles: the interrupt's length, entry to
      reti, the interrupts nested in it (the receive, ADC, millis ones) included;
      period_cycles: the period proper's; overruns: starts while the last one still
      ran (the firmware counts and skips them).
    pass_cycles: each main-loop pass (main_loop_pass), less the periods' interrupts inside
      it: the main loop's own work; worst case = max.
    control_cycles: the control period's work, per call.
    line_check_cycles: per host line, the CRC check (ab_crc32) just before the grammar and
      range checks (ab_parse_command) plus those; worst case = max.
    estop_latency_us: from each e-stop byte's delivery (its receive flag) to every motor
      pin off; estop_in_isr_us: those whose byte came while the period's interrupt ran.
    free_ram_bytes: lowest stack pointer seen minus the end of .data/.bss/.noinit."""
    runner, hal, cfg = emu.runner, emu.hal, emu.cfg
    lo, hi = window if window is not None else (-math.inf, math.inf)
    hz = float(runner.harness.hz)
    ch0 = int(cfg.PIN_BEND[0])
    starts = [t for t, ch in hal.adc_starts if ch == ch0 and lo <= t <= hi]
    sample = [(b - a) * 1e6 for a, b in zip(starts, starts[1:])]
    probes = {name: [r for r in recs if lo <= r[0] <= hi] for name, recs in runner.stats["probes"].items()}
    entries = [t for t, _ in probes.get("control", [])]
    period = [(b - a) * 1e6 for a, b in zip(entries, entries[1:])]
    control = [d for _, d in probes.get("control", [])]
    crcs = sorted(probes.get("crc", []))
    lines = []
    for t, d in probes.get("parse", []):
        before = [c for c in crcs if c[0] <= t]
        lines.append(d + (before[-1][1] if before else 0))
    isr = sorted(probes.get("isr", []))
    starts_p = sorted(probes.get("period", [])) or isr
    isr_spans = [(t, t + d / hz) for t, d in isr]
    per_spans = [(t, t + d / hz) for t, d in starts_p]
    overruns = sum(1 for i in range(1, len(isr_spans)) if isr_spans[i][0] < isr_spans[i - 1][1])
    isr_period = [round((b[0] - a[0]) * hz) for a, b in zip(per_spans, per_spans[1:])]
    # the periods' time inside a pass: each interrupt, and a period run at an unlock (simavr)
    spans = sorted(isr_spans + [p for p in per_spans if not any(s <= p[0] <= e for s, e in isr_spans)])
    passes = []
    k = 0
    for t, d in sorted(probes.get("pass", [])):
        end = t + d / hz
        while k < len(spans) and spans[k][1] <= t:
            k += 1
        inside = sum(min(e, end) - max(s, t) for s, e in spans[k:] if s < end and e > t)
        passes.append(d - inside * hz)
    latency, in_isr = [], []
    for t in (t for t in hal.estop_byte_at if lo <= t <= hi):
        off = [x for x in hal.outputs_off_at if x >= t - 1e-6]
        if off:
            latency.append((off[0] - t) * 1e6)
            if any(s <= t <= e for s, e in spans):
                in_isr.append(latency[-1])
    spread = _spread(period)
    ip = _spread(isr_period)
    return {
        "hz": hz,
        "control_period_us": spread,
        "control_jitter_us": (spread["max"] - spread["min"]) if period else None,
        "isr_period_cycles": ip,
        "isr_jitter_us": (ip["max"] - ip["min"]) * 1e6 / hz if isr_period else None,
        "isr_cycles": _spread([d for _, d in isr]),
        "period_cycles": _spread([d for _, d in starts_p]),
        "overruns": overruns,
        "pass_cycles": _spread(passes),
        "sample_period_us": _spread(sample),
        "control_cycles": _spread(control),
        "line_check_cycles": _spread(lines),
        "estop_latency_us": _spread(latency),
        "estop_in_isr_us": _spread(in_isr),
        "min_sp": runner.stats["min_sp"],
        "free_ram_bytes": (runner.stats["min_sp"] or 0) - runner.elf.ram_end_of_statics,
        "flash_bytes": runner.elf.flash_bytes,
        "static_ram_bytes": runner.elf.static_ram_bytes,
        "uart_bytes_lost": runner.stats["lost"],
    }
