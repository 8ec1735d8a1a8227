"""PCA9685 driver: the 16-channel, 12-bit PWM controller of the servo rig.

Works over any object with MicroPython's machine.I2C memory API
(`writeto_mem(addr, reg, buf)`, `readfrom_mem(addr, reg, n)`): the real bus on
the ESP32, the simulated one in the emulator (host/armbridge/emulator/i2c.py).

The chip (NXP PCA9685 data sheet, rev. 4): one PWM period of 4096 counts for
all channels, from a 25 MHz internal oscillator divided by PRE_SCALE + 1:

    f = osc / (4096 * (PRE_SCALE + 1))       PRE_SCALE = round(osc / (4096 f)) - 1

(50 Hz: PRE_SCALE 121, period 19988 us, 4.88 us per count). Channel n's output
goes high at count LEDn_ON and low at LEDn_OFF (12 bits each, little-endian
in LEDn_ON_L/H, LEDn_OFF_L/H at 0x06 + 4n); bit 4 of LEDn_OFF_H is "full off",
which stops the pulses: a hobby servo without pulses goes limp. PRE_SCALE can
only be written while MODE1.SLEEP is set; after clearing SLEEP the oscillator
needs 500 us, and channels that were running when the chip was put to sleep
stay off until MODE1.RESTART is written 1. MODE1.AI (auto-increment) lets one
transfer write a channel's four registers, or several channels' in a row.
"""

from micropython import const

MODE1 = const(0x00)
MODE2 = const(0x01)
LED0_ON_L = const(0x06)
ALL_LED_ON_L = const(0xFA)
PRE_SCALE = const(0xFE)

RESTART = const(0x80)
AI = const(0x20)
SLEEP = const(0x10)
ALLCALL = const(0x01)
OUTDRV = const(0x04)          # MODE2: totem-pole outputs (servo signal inputs)
FULL = const(0x10)            # bit 4 of LEDn_ON_H (full on) and LEDn_OFF_H (full off)

OSC_HZ = const(25000000)
COUNTS = const(4096)
WAKE_US = const(500)          # oscillator start-up after SLEEP is cleared


def prescale_for(freq_hz, osc_hz=OSC_HZ) -> int:
    """PRE_SCALE for a PWM frequency (data sheet eq. 1), within the chip's 3..255."""
    p = int(osc_hz / (COUNTS * freq_hz) + 0.5) - 1
    if p < 3:
        return 3
    if p > 255:
        return 255
    return p


def period_us(prescale, osc_hz=OSC_HZ) -> float:
    """The PWM period that PRE_SCALE gives, in us."""
    return (prescale + 1) * COUNTS * 1000000.0 / osc_hz


class Pca9685:
    """One PCA9685 at `addr` on `i2c`. __init__ turns every channel off and sets
    the frequency: after it the chip runs with auto-increment and totem-pole
    outputs and sends no pulses until pulse_us() is called.

    sleep_us(us): how to wait for the oscillator (default: time.sleep_us).
    osc_hz: the oscillator's frequency (25 MHz nominal; a chip's own can be a
    few per cent off, which the servos' two-point calibration absorbs).
    """

    def __init__(self, i2c, addr=0x40, freq_hz=50, osc_hz=OSC_HZ, sleep_us=None) -> None:
        self.i2c = i2c
        self.addr = addr
        self.osc_hz = osc_hz
        if sleep_us is None:
            import time
            sleep_us = time.sleep_us
        self._sleep_us = sleep_us
        self._one = bytearray(1)
        self._four = bytearray(4)
        self.prescale = 0
        self.period_us = 0.0
        self._us_per_count = 0.0
        self._write(MODE1, AI | SLEEP | ALLCALL)  # outputs stop now; auto-increment from here on
        self.all_off()                            # an orderly shutdown: RESTART clears
        self._write(MODE2, OUTDRV)
        self.set_freq(freq_hz)

    # ------------------------------------------------------------ registers
    def _write(self, reg, value) -> None:
        self._one[0] = value
        self.i2c.writeto_mem(self.addr, reg, self._one)

    def read(self, reg) -> int:
        return self.i2c.readfrom_mem(self.addr, reg, 1)[0]

    # ------------------------------------------------------------ modes
    def sleep(self) -> None:
        """Oscillator off, every output off; the channels' registers are kept
        (and RESTART is set for those that were running)."""
        self._write(MODE1, (self.read(MODE1) & ~RESTART) | SLEEP)

    def wake(self) -> None:
        """Clear SLEEP, wait for the oscillator, restart the channels that
        were running when the chip went to sleep (data sheet 7.3.1.1)."""
        mode = self.read(MODE1)
        self._write(MODE1, mode & ~(SLEEP | RESTART))
        self._sleep_us(WAKE_US)
        if mode & RESTART:
            self._write(MODE1, (mode & ~SLEEP) | RESTART)

    def set_freq(self, freq_hz) -> None:
        """PWM frequency (Hz) for all channels: PRE_SCALE is written in SLEEP."""
        p = prescale_for(freq_hz, self.osc_hz)
        self.sleep()
        self._write(PRE_SCALE, p)
        self.wake()
        self.prescale = p
        self.period_us = period_us(p, self.osc_hz)
        self._us_per_count = self.period_us / COUNTS

    # ------------------------------------------------------------ channels
    def counts(self, us) -> int:
        """Counts of a pulse of `us` microseconds (rounded, within 1..4095)."""
        c = int(us / self._us_per_count + 0.5)
        if c < 1:
            return 1
        if c > COUNTS - 1:
            return COUNTS - 1
        return c

    def pulse_us(self, ch, us) -> None:
        """Channel ch sends a pulse of `us` (high from count 0) every period."""
        c = self.counts(us)
        b = self._four
        b[0] = 0
        b[1] = 0
        b[2] = c & 0xFF
        b[3] = c >> 8
        self.i2c.writeto_mem(self.addr, LED0_ON_L + 4 * ch, b)

    def write_counts(self, first, buf) -> None:
        """Raw LEDn registers for channels first, first+1, ... in one transfer:
        buf holds 4 bytes (ON_L, ON_H, OFF_L, OFF_H) per channel."""
        self.i2c.writeto_mem(self.addr, LED0_ON_L + 4 * first, buf)

    def off(self, ch) -> None:
        """Channel ch: full off (no pulses)."""
        b = self._four
        b[0] = 0
        b[1] = 0
        b[2] = 0
        b[3] = FULL
        self.i2c.writeto_mem(self.addr, LED0_ON_L + 4 * ch, b)

    def all_off(self) -> None:
        """Every channel full off, in one transfer (ALL_LED registers)."""
        b = self._four
        b[0] = 0
        b[1] = 0
        b[2] = 0
        b[3] = FULL
        self.i2c.writeto_mem(self.addr, ALL_LED_ON_L, b)
