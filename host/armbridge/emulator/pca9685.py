"""Register model of the NXP PCA9685 (16-channel, 12-bit PWM controller; data
sheet rev. 4), as an `i2c.I2CDevice` on the simulated bus.

What is modelled (register addresses as in the data sheet's Table 4):

  MODE1 0x00   power-on 0x11 (SLEEP, ALLCALL). SLEEP stops the oscillator and
               every output; clearing it starts the oscillator, which runs the
               PWM counter WAKE_S (500 us) later. AI (bit 5) turns on
               auto-increment. RESTART (bit 7) reads 1 after the chip was put to
               sleep with a channel running; those channels then stay off after
               waking until RESTART is written 1 (no earlier than 500 us after
               SLEEP was cleared: an early write is counted in `restart_early`
               and ignored) or a PWM register is written. EXTCLK, SUBn and
               ALLCALL are stored and have no effect (one address answers).
  MODE2 0x01   power-on 0x04. INVRT (bit 4) inverts the outputs; OCH, OUTDRV
               and OUTNE are stored (every transfer ends with a STOP; there is
               no /OE pin: it is tied low, as on servo boards).
  LEDn 0x06+4n ON_L, ON_H, OFF_L, OFF_H: the output goes high at count ON and
               low at count OFF (12 bits); ON_H bit 4 is full on, OFF_H bit 4
               full off (it wins over full on); power-on: full off.
  ALL_LED 0xFA..0xFD  write-only (read 0): a byte written there goes to the
               same register of all 16 channels.
  PRE_SCALE 0xFE  power-on 30; only written while SLEEP is set (writes while
               awake are ignored and counted in `prescale_blocked`); values
               below 3 read as 3. Period = (PRE_SCALE + 1) * 4096 / osc.

Auto-increment: with AI set the register pointer moves after every byte of a
transfer, from LED15_OFF_H (0x45) back to MODE1, and from 0xFA on up to
PRE_SCALE, then to MODE1; with AI clear every byte goes to the same register.

Outputs: `pulse_us(ch)` is the width of the high pulse channel ch sends every
period (us), or None when it sends none (sleeping, waiting for RESTART, full
off, full on, or ON == OFF). Output changes reach the pins at the start of a
PWM period (`next_frame(t)`), which is when a servo samples them.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

MODE1, MODE2, LED0_ON_L, LED15_OFF_H = 0x00, 0x01, 0x06, 0x45
ALL_LED_ON_L, ALL_LED_OFF_H, PRE_SCALE, TESTMODE = 0xFA, 0xFD, 0xFE, 0xFF
RESTART, EXTCLK, AI, SLEEP, ALLCALL = 0x80, 0x40, 0x20, 0x10, 0x01
INVRT, OUTDRV = 0x10, 0x04
FULL = 0x10
CHANNELS, COUNTS = 16, 4096
OSC_HZ = 25_000_000.0
WAKE_S = 500e-6


class Pca9685Model:
    """One PCA9685's registers and outputs. now(): the bus's clock in seconds
    (the emulator's sim clock), used for the oscillator's start-up and the PWM
    period grid. osc_hz: the internal oscillator (25 MHz nominal)."""

    def __init__(self, now: Callable[[], float] = lambda: 0.0, osc_hz: float = OSC_HZ) -> None:
        self.now = now
        self.osc_hz = float(osc_hz)
        self.regs = bytearray(256)
        self.regs[MODE1] = SLEEP | ALLCALL
        self.regs[MODE2] = OUTDRV
        self.regs[0x02:0x06] = bytes((0xE2, 0xE4, 0xE8, 0xE0))  # SUBADR1..3, ALLCALLADR
        for ch in range(CHANNELS):
            self.regs[LED0_ON_L + 4 * ch + 3] = FULL
        self.regs[PRE_SCALE] = 0x1E
        self.restart_pending = False
        self.woke_at: float | None = None      # when SLEEP was last cleared
        self.frame0: float | None = None       # start of the PWM period grid (None: counter stopped)
        self.restart_early = 0
        self.prescale_blocked = 0
        self.writes = 0                        # bytes written

    # ------------------------------------------------------------ I2CDevice
    def write(self, reg: int, data: bytes) -> None:
        for b in data:
            self._write1(reg, b)
            self.writes += 1
            reg = self._next(reg)

    def read(self, reg: int, n: int) -> bytes:
        out = bytearray()
        for _ in range(n):
            out.append(self._read1(reg))
            reg = self._next(reg)
        return bytes(out)

    # ------------------------------------------------------------ registers
    @property
    def sleeping(self) -> bool:
        return bool(self.regs[MODE1] & SLEEP)

    @property
    def prescale(self) -> int:
        return self.regs[PRE_SCALE]

    @property
    def period_s(self) -> float:
        return (self.prescale + 1) * COUNTS / self.osc_hz

    def _next(self, reg: int) -> int:
        if not self.regs[MODE1] & AI:
            return reg
        if reg == LED15_OFF_H or reg >= PRE_SCALE:
            return MODE1
        return reg + 1

    def _read1(self, reg: int) -> int:
        if ALL_LED_ON_L <= reg <= ALL_LED_OFF_H or reg == TESTMODE or LED15_OFF_H < reg < ALL_LED_ON_L:
            return 0
        if reg == MODE1:
            return (self.regs[MODE1] & ~RESTART & 0xFF) | (RESTART if self.restart_pending else 0)
        return self.regs[reg]

    def _write1(self, reg: int, b: int) -> None:
        if reg == MODE1:
            self._write_mode1(b)
        elif reg == PRE_SCALE:
            if self.sleeping:
                self.regs[PRE_SCALE] = max(b, 3)
            else:
                self.prescale_blocked += 1
        elif LED0_ON_L <= reg <= LED15_OFF_H:
            self.regs[reg] = b
            self._pwm_written()
        elif ALL_LED_ON_L <= reg <= ALL_LED_OFF_H:
            for ch in range(CHANNELS):
                self.regs[LED0_ON_L + 4 * ch + reg - ALL_LED_ON_L] = b
            self._pwm_written()
        elif reg < LED0_ON_L:
            self.regs[reg] = b                   # MODE2, SUBADRn, ALLCALLADR

    def _pwm_written(self) -> None:
        """A PWM register write (OCH = 0, then STOP) clears RESTART: the channels run."""
        if self.restart_pending and not self.sleeping:
            self.restart_pending = False
            self._start_counter()

    def _start_counter(self) -> None:
        t = self.now()
        assert self.woke_at is not None
        self.frame0 = max(t, self.woke_at + WAKE_S)

    def _write_mode1(self, b: int) -> None:
        was_asleep = self.sleeping
        keep = self.regs[MODE1] & EXTCLK            # EXTCLK is sticky
        self.regs[MODE1] = (b & ~RESTART & 0xFF) | keep
        t = self.now()
        if not was_asleep and self.sleeping:        # to sleep: counter stops
            if any(self._pulse_counts(ch) is not None for ch in range(CHANNELS)) and self.frame0 is not None:
                self.restart_pending = True
            self.frame0 = None
        elif was_asleep and not self.sleeping:      # wake: oscillator starts
            self.woke_at = t
            if not self.restart_pending:
                self._start_counter()
        if b & RESTART and self.restart_pending and not self.sleeping:
            assert self.woke_at is not None
            if t - self.woke_at < WAKE_S - 1e-9:
                self.restart_early += 1
            else:
                self.restart_pending = False
                self._start_counter()

    # ------------------------------------------------------------ outputs
    def _pulse_counts(self, ch: int) -> int | None:
        base = LED0_ON_L + 4 * ch
        on_l, on_h, off_l, off_h = self.regs[base:base + 4]
        if off_h & FULL or on_h & FULL:
            return None
        width = (((off_h & 0x0F) << 8 | off_l) - ((on_h & 0x0F) << 8 | on_l)) % COUNTS
        return width or None

    def pulse_us(self, ch: int) -> float | None:
        """Width (us) of the high pulse channel ch sends each period, or None."""
        if not 0 <= ch < CHANNELS:
            raise ValueError(f"PCA9685 channel {ch} does not exist (0..15)")
        if self.frame0 is None:
            return None
        c = self._pulse_counts(ch)
        if c is None:
            return None
        if self.regs[MODE2] & INVRT:
            c = COUNTS - c
        return c * self.period_s * 1e6 / COUNTS

    def pulses_us(self, channels) -> np.ndarray:
        """pulse_us of each channel, NaN where it sends none."""
        return np.array([np.nan if (p := self.pulse_us(int(ch))) is None else p for ch in channels])

    def next_frame(self, t: float) -> float:
        """When a register change made at time t reaches the outputs: the start of
        the next PWM period (t itself while the counter is stopped)."""
        if self.frame0 is None or t <= self.frame0:
            return t if self.frame0 is None else self.frame0
        per = self.period_s
        return self.frame0 + math.ceil((t - self.frame0) / per - 1e-9) * per
