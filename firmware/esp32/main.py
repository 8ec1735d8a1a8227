"""Boot entry on the ESP32: the HAL of the rig config SERVOS names + Board, poll() forever."""

import time

import config
from arm import Board


def make_hal(cfg):
    """The HAL of the rig: "effort" (hal_esp32.Esp32Hal) or "pca9685"
    (hal_pca9685.Pca9685Hal); only that rig's modules are imported."""
    rig = getattr(cfg, "SERVOS", "effort")
    if rig == "pca9685":
        from hal_pca9685 import Pca9685Hal
        return Pca9685Hal(cfg)
    if rig == "effort":
        from hal_esp32 import Esp32Hal
        return Esp32Hal(cfg)
    raise ValueError("config SERVOS is %r; known rigs: effort, pca9685" % (rig,))


def main() -> None:
    hal = make_hal(config)
    try:
        board = Board(hal, config)
        while True:
            if not board.poll():
                time.sleep_ms(1)   # nothing arrived: yield a little
    finally:
        hal.outputs_off()


main()
