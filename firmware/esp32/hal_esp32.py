"""The HAL of docs/architecture.md over MicroPython's `machine` on an ESP32.

`Esp32Base` is what both rigs share: the clock, the feedback potentiometers
(ADC pins, linear calibration from the config), the link UART at UART_BAUD
(non-blocking reads), persistence in RTC memory (survives a reset, not a
power cycle) and the filesystem. Each rig adds its outputs:

`Esp32Hal` (config SERVOS = "effort"): servos driven by effort, PWM at
PWM_FREQ_HZ, pulse PULSE_MIN_US..PULSE_MAX_US for an effort of -1..1
(PULSE_NEUTRAL_US at 0). The optional pen-lift servo on PEN_PIN (None: none)
gets PEN_UP_US / PEN_DOWN_US, or the widths set_pen_widths gave (PENPOS). outputs_off() stops every pulse (duty 0), the
pen's too, which lets hobby servos go limp; the next write_outputs() drives
them again, the pen where it was last put (up, before any write_pen).

The positional rig (SERVOS = "pca9685") is hal_pca9685.Pca9685Hal.
"""

import machine
from esp32_base import Esp32Base


class ArmBase(Esp32Base):
    """The arm's part of both rigs: the feedback pots, on top of the common
    ESP32 base (firmware/common/esp32_base.py: clock, UART, RTC memory, files)."""

    def __init__(self, cfg) -> None:
        self._adcs = [machine.ADC(machine.Pin(p), atten=machine.ADC.ATTN_11DB)
                      for p in cfg.ADC_PINS]
        Esp32Base.__init__(self, cfg)

    def read_positions(self, out: list) -> None:
        c = self.cfg
        for j in range(len(self._adcs)):
            volts = (self._adcs[j].read_uv() - c.ADC_CENTER_UV[j]) / 1000000.0
            out[j] = c.ADC_RAD_AT_CENTER[j] + c.ADC_RAD_PER_V[j] * volts


class Esp32Hal(ArmBase):
    """The effort rig: continuous servos on PWM pins (see the module docstring)."""

    def __init__(self, cfg) -> None:
        neutral_ns = cfg.PULSE_NEUTRAL_US * 1000
        self._pwms = [machine.PWM(machine.Pin(p), freq=cfg.PWM_FREQ_HZ, duty_ns=neutral_ns)
                      for p in cfg.PWM_PINS]
        ArmBase.__init__(self, cfg)
        pin = getattr(cfg, "PEN_PIN", None)
        self.has_pen = pin is not None
        self._pen = None
        self._pen_ns = cfg.PEN_UP_US * 1000 if pin is not None else 0
        self._pen_up_ns = cfg.PEN_UP_US * 1000
        self._pen_down_ns = cfg.PEN_DOWN_US * 1000
        self._pen_down = False
        self._live = False
        if pin is not None:
            self._pen = machine.PWM(machine.Pin(pin), freq=cfg.PWM_FREQ_HZ, duty_ns=self._pen_ns)
        self.outputs_off()

    def write_outputs(self, efforts: list) -> None:
        c = self.cfg
        for j in range(len(self._pwms)):
            e = efforts[j]
            if e > 1.0:
                e = 1.0
            elif e < -1.0:
                e = -1.0
            if e >= 0:
                us = c.PULSE_NEUTRAL_US + e * (c.PULSE_MAX_US - c.PULSE_NEUTRAL_US)
            else:
                us = c.PULSE_NEUTRAL_US + e * (c.PULSE_NEUTRAL_US - c.PULSE_MIN_US)
            self._pwms[j].duty_ns(int(us * 1000))
        if not self._live:
            self._live = True
            if self._pen is not None:
                self._pen.duty_ns(self._pen_ns)

    def outputs_off(self) -> None:
        for p in self._pwms:
            p.duty_ns(0)
        if self._pen is not None:
            self._pen.duty_ns(0)
        self._live = False

    def write_pen(self, down: bool) -> None:
        """The pen-lift servo to its down or up width (PEN_DOWN_US / PEN_UP_US
        until set_pen_widths); it is driven from now on."""
        if self._pen is not None:
            self._pen_down = bool(down)
            self._pen_ns = self._pen_down_ns if down else self._pen_up_ns
            self._pen.duty_ns(self._pen_ns)

    def set_pen_widths(self, up_us: int, down_us: int) -> None:
        """The pen's up and down pulse widths (PENPOS); a driven pen moves to its state's new one."""
        self._pen_up_ns = up_us * 1000
        self._pen_down_ns = down_us * 1000
        if self._pen is not None:
            self._pen_ns = self._pen_down_ns if self._pen_down else self._pen_up_ns
            if self._live:
                self._pen.duty_ns(self._pen_ns)
