"""The MASR actuator's HAL over MicroPython's `machine` on an ESP32
(docs/architecture.md, "The MA HAL"; wiring in README.md).

The clock, UART, RTC memory and files are the common Esp32Base
(firmware/common/esp32_base.py). On top of it:
  * two DC motors, each a PWM pin (MOTOR_PWM_HZ, duty = |u|) and a direction
    pin (low: + effort): locomotion (+ drives away from the base, d grows) and
    joint rotation (+ increases the engaged joint's angle);
  * the wheel and the gear encoders on the ESP32's hardware pulse counter:
    `machine.Encoder(unit, phase_a, phase_b, phases=4, filter_ns=...)`
    (MicroPython 1.29, one PCNT unit each), read with `value()`;
  * the hall switch on `Pin.irq`: at each magnet arriving (the active edge) the
    handler stores the wheel count in a preallocated ring (array 'i', HALL_RING
    slots) and advances an index: no allocation in the handler (the bound
    method it calls is made once, here). hall_edges() hands the ring's new
    entries over, oldest first; on a ring overrun the oldest are dropped;
  * the gripper servo (SERVO_FREQ_HZ, GRIP_OPEN_US / GRIP_CLOSED_US).
outputs_off() stops both motors (duty 0): the worm gears hold the joints; the
gripper keeps its pulse (it holds what it grips).
"""

from array import array

import machine
from esp32_base import Esp32Base


class MaHal(Esp32Base):
    def __init__(self, cfg) -> None:
        Esp32Base.__init__(self, cfg)
        pin = machine.Pin
        f = cfg.MOTOR_PWM_HZ
        self._loco = machine.PWM(pin(cfg.LOCO_PWM_PIN), freq=f, duty_u16=0)
        self._loco_dir = pin(cfg.LOCO_DIR_PIN, pin.OUT, value=0)
        self._rot = machine.PWM(pin(cfg.ROT_PWM_PIN), freq=f, duty_u16=0)
        self._rot_dir = pin(cfg.ROT_DIR_PIN, pin.OUT, value=0)
        self._wheel = machine.Encoder(cfg.WHEEL_PCNT, pin(cfg.WHEEL_ENC_A, pin.IN),
                                      pin(cfg.WHEEL_ENC_B, pin.IN), phases=4,
                                      filter_ns=cfg.ENC_FILTER_NS)
        self._gear = machine.Encoder(cfg.GEAR_PCNT, pin(cfg.GEAR_ENC_A, pin.IN),
                                     pin(cfg.GEAR_ENC_B, pin.IN), phases=4,
                                     filter_ns=cfg.ENC_FILTER_NS)
        self._wheel_value = self._wheel.value      # bound once: the IRQ allocates nothing
        self._ring = array("i", [0] * cfg.HALL_RING)
        self._n = cfg.HALL_RING
        self._w = 0                                # edges written (the IRQ) ...
        self._r = 0                                # ... and handed over
        self._low = cfg.HALL_ACTIVE_LOW
        self._hall = pin(cfg.HALL_PIN, pin.IN, pin.PULL_UP)
        trig = pin.IRQ_FALLING if self._low else pin.IRQ_RISING
        self._hall.irq(handler=self._on_hall, trigger=trig, hard=True)
        self._grip_open_ns = cfg.GRIP_OPEN_US * 1000
        self._grip_closed_ns = cfg.GRIP_CLOSED_US * 1000
        self._grip = machine.PWM(pin(cfg.GRIP_PIN), freq=cfg.SERVO_FREQ_HZ,
                                 duty_ns=self._grip_closed_ns)
        self._isense_pin = getattr(cfg, "ROT_ISENSE_PIN", None)   # None: the firmware never reads it
        if self._isense_pin is not None:
            self._isense = machine.ADC(pin(self._isense_pin), atten=machine.ADC.ATTN_11DB)
            self._iscale = cfg.ROT_ISENSE_FULL / 65535.0

    # ------------------------------------------------------------ hall IRQ
    def _on_hall(self, p) -> None:
        self._ring[self._w % self._n] = self._wheel_value()
        self._w += 1

    def hall_edges(self) -> list:
        w = self._w
        r = self._r
        if w - r > self._n:
            r = w - self._n
        out = []
        while r < w:
            out.append(self._ring[r % self._n])
            r += 1
        self._r = w
        return out

    def hall_level(self) -> int:
        v = self._hall.value()
        return 1 if (v == 0) == self._low else 0

    # ------------------------------------------------------------ encoders
    def wheel_count(self) -> int:
        return self._wheel.value()

    def rot_load(self) -> float:
        """The rotation driver's current sense, in effort units (the stall current = 1)."""
        return self._isense.read_u16() * self._iscale

    def gear_count(self) -> int:
        return self._gear.value()

    # ------------------------------------------------------------ outputs
    def loco(self, u: float) -> None:
        _drive(self._loco, self._loco_dir, u)

    def rot(self, u: float) -> None:
        _drive(self._rot, self._rot_dir, u)

    def grip(self, open_: bool) -> None:
        self._grip.duty_ns(self._grip_open_ns if open_ else self._grip_closed_ns)

    def outputs_off(self) -> None:
        self._loco.duty_u16(0)
        self._rot.duty_u16(0)


def _drive(pwm, direction, u: float) -> None:
    """Effort u in [-1, 1] as duty |u| and the direction pin (low: +)."""
    if u > 1.0:
        u = 1.0
    elif u < -1.0:
        u = -1.0
    direction.value(1 if u < 0 else 0)
    pwm.duty_u16(int(abs(u) * 65535))
