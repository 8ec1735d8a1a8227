"""The HAL of the paper's rig (section 4.1, Table 1): positional hobby servos
behind a PCA9685 I2C servo controller (config SERVOS = "pca9685").

POSITIONAL = True: the board sends set points (write_positions, rad), not
efforts; the servos' own position loops follow them. The pulses come from the
PCA9685 at PCA9685_ADDR on I2C bus I2C_ID (SCL I2C_SCL, SDA I2C_SDA, I2C_FREQ)
at SERVO_FREQ_HZ, joint j on channel SERVO_CHANNELS[j], calibrated by
SERVO_CAL[j] (servos.py; CAL changes it in RAM), the pen-lift servo on
PEN_CHANNEL (None: none). outputs_off() puts every channel full off: the
servos go limp. The clock, the feedback pots (read_positions: ADC pins, as on
the effort rig), the UART, RTC memory and files are hal_esp32.ArmBase's (common/esp32_base.py).
"""

import time

import machine
from hal_esp32 import ArmBase
from pca9685 import Pca9685
from servos import ServoBank


class Pca9685Hal(ArmBase):
    POSITIONAL = True

    def __init__(self, cfg) -> None:
        ArmBase.__init__(self, cfg)
        i2c = machine.I2C(cfg.I2C_ID, scl=machine.Pin(cfg.I2C_SCL), sda=machine.Pin(cfg.I2C_SDA),
                          freq=cfg.I2C_FREQ)
        self.pca = Pca9685(i2c, cfg.PCA9685_ADDR, cfg.SERVO_FREQ_HZ, sleep_us=time.sleep_us)
        self.servos = ServoBank(self.pca, cfg)
        self.has_pen = self.servos.has_pen

    def write_positions(self, q: list) -> None:
        self.servos.write(q)

    def outputs_off(self) -> None:
        self.servos.off()

    def set_calibration(self, j0: int, us_a: int, mrad_a: int, us_b: int, mrad_b: int) -> None:
        self.servos.set_calibration(j0, us_a, mrad_a, us_b, mrad_b)

    def set_lead(self, j0: int, mrad: int) -> None:
        self.servos.set_lead(j0, mrad)

    def write_pen(self, down: bool) -> None:
        self.servos.pen(down)

    def set_pen_widths(self, up_us: int, down_us: int) -> None:
        self.servos.set_pen_widths(up_us, down_us)
