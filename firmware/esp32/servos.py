"""Positional hobby servos on a PCA9685: calibration and the rig's outputs.

A positional servo turns its horn to the angle its pulse width stands for, and
that mapping is linear over its travel (a 270 deg servo: 500..2500 us). How the
horn sits on the joint is the rig's, so each joint has a two-point calibration
(config SERVO_CAL, the CAL verb): pulse us_a at joint angle a, us_b at b, both
in mrad, and

    pulse(q) = us_a + (q - a) * (us_b - us_a) / (b - a)

clipped to the servo's pulse range US_MIN..US_MAX.

A positional servo stops as soon as its shaft is within its dead band of the
pulse, so short of the target on the side it came from, and its gear play
lets the joint trail further: the joint's resting angle for one pulse differs
by the hysteresis width (twice the dead band plus the play) between the two
sides it can come from. As a 3D printer's backlash compensation (Marlin's
M425) does, each servo leads its pulse by `lead_us` (half that width, which
`armbridge calibrate esp32`'s jig step measures: DBAND on this rig) toward the
side the pulse last moved to, so the joint rests on the target from either
side. The side changes only when the pulse moves by more than SIDE_US.

`ServoBank` drives the
joints' channels (SERVO_CHANNELS) and the optional pen-lift servo
(PEN_CHANNEL, PEN_UP_US / PEN_DOWN_US) through a pca9685.Pca9685.
"""

from pca9685 import FULL

US_MIN = 500     # us: the pulse range of a 270 deg hobby servo, and what CAL accepts
US_MAX = 2500
SIDE_US = 0.5    # us: a pulse that moves less than this keeps the side it leads to


class Servo:
    """One servo's linear calibration (see the module docstring)."""

    def __init__(self, us_a, mrad_a, us_b, mrad_b) -> None:
        self.us0 = 0.0            # pulse at 0 rad
        self.us_per_rad = 0.0
        self.lead_us = 0.0        # half the hysteresis width (see the module docstring)
        self.side = 0             # +1 / -1: the side the pulse last moved to; 0: none yet
        self._from = None         # the pulse the side was last decided at (None: no pulse yet)
        self.cal = (us_a, mrad_a, us_b, mrad_b)
        self.set(us_a, mrad_a, us_b, mrad_b)

    def set(self, us_a, mrad_a, us_b, mrad_b) -> None:
        """A new calibration; ValueError if the two points do not define a line."""
        if us_a == us_b or mrad_a == mrad_b:
            raise ValueError("calibration needs two different pulses at two different angles")
        k = (us_b - us_a) * 1000.0 / (mrad_b - mrad_a)
        self.us_per_rad = k
        self.us0 = us_a - k * mrad_a / 1000.0
        self.cal = (us_a, mrad_a, us_b, mrad_b)

    def pulse(self, q) -> float:
        """Pulse (us) for joint angle q (rad), within US_MIN..US_MAX."""
        us = self.us0 + self.us_per_rad * q
        if us < US_MIN:
            return float(US_MIN)
        if us > US_MAX:
            return float(US_MAX)
        return us

    def led(self, us) -> float:
        """`us` led by lead_us toward the side it moves to, within US_MIN..US_MAX."""
        f = self._from
        if f is None:
            self._from = us
        elif us > f + SIDE_US or us < f - SIDE_US:
            self.side = 1 if us > f else -1
            self._from = us
        out = us + self.side * self.lead_us
        if out < US_MIN:
            return float(US_MIN)
        if out > US_MAX:
            return float(US_MAX)
        return out

    def angle(self, us) -> float:
        """Joint angle (rad) that pulse `us` stands for (the inverse of pulse)."""
        return (us - self.us0) / self.us_per_rad


class ServoBank:
    """The rig's servos behind one PCA9685 `pca`, wired as `cfg` says.

    write(q): joint set points (rad) -> pulses, one I2C transfer when the
    channels are consecutive, none when no count changed. off(): every servo
    limp (full off), the pen's too; the next write() drives them all again,
    the pen where it was last put (up, before any pen()).
    """

    def __init__(self, pca, cfg) -> None:
        self.pca = pca
        n = cfg.N_JOINTS
        self.n = n
        self.channels = tuple(cfg.SERVO_CHANNELS)
        if len(self.channels) != n or len(cfg.SERVO_CAL) != n:
            raise ValueError("config SERVO_CHANNELS and SERVO_CAL need one entry per joint")
        self.servos = [Servo(c[0], c[1], c[2], c[3]) for c in cfg.SERVO_CAL]
        first = self.channels[0]
        self._first = first
        self._runs = self.channels == tuple(range(first, first + n))
        self._buf = bytearray(4 * n)
        self._sent = bytearray(4 * n)
        self._live = False        # False: the channels are off, the next write sends
        pen = getattr(cfg, "PEN_CHANNEL", None)
        self.has_pen = pen is not None
        self.pen_channel = pen
        self.pen_up_us = getattr(cfg, "PEN_UP_US", 1500)
        self.pen_down_us = getattr(cfg, "PEN_DOWN_US", 1500)
        self.pen_down = False
        self.off()

    def write(self, q) -> None:
        b = self._buf
        pca = self.pca
        for j in range(self.n):
            s = self.servos[j]
            c = pca.counts(s.led(s.pulse(q[j])))
            k = 4 * j
            b[k] = 0
            b[k + 1] = 0
            b[k + 2] = c & 0xFF
            b[k + 3] = c >> 8
        if self._live and b == self._sent:
            return
        if self._runs:
            pca.write_counts(self._first, b)
        else:
            for j in range(self.n):
                pca.write_counts(self.channels[j], b[4 * j:4 * j + 4])
        self._sent[:] = b
        if not self._live and self.has_pen:
            self.pen(self.pen_down)
        self._live = True

    def off(self) -> None:
        b = self._buf
        for k in range(0, 4 * self.n, 4):
            b[k] = 0
            b[k + 1] = 0
            b[k + 2] = 0
            b[k + 3] = FULL
        if self._runs:
            self.pca.write_counts(self._first, b)
        else:
            for ch in self.channels:
                self.pca.off(ch)
        if self.has_pen:
            self.pca.off(self.pen_channel)
        self._live = False

    def pen(self, down) -> None:
        """Pen servo to its down (True) or up pulse; it is driven from now on."""
        self.pen_down = bool(down)
        self.pca.pulse_us(self.pen_channel, self.pen_down_us if down else self.pen_up_us)

    def set_pen_widths(self, up_us, down_us) -> None:
        """The pen's up and down pulse widths (PENPOS); a driven pen moves to its state's new one."""
        self.pen_up_us = up_us
        self.pen_down_us = down_us
        if self._live and self.has_pen:
            self.pen(self.pen_down)

    def set_calibration(self, j, us_a, mrad_a, us_b, mrad_b) -> None:
        """Joint j (0-based): a new two-point calibration, used from the next write."""
        self.servos[j].set(us_a, mrad_a, us_b, mrad_b)

    def set_lead(self, j, mrad) -> None:
        """Joint j (0-based): the hysteresis width (mrad) its pulse is led by half of."""
        s = self.servos[j]
        s.lead_us = 0.5 * abs(s.us_per_rad) * mrad / 1000.0
