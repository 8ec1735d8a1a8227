"""Boot entry on the ESP32: Esp32Hal + Board, poll() forever."""

import time

import config
from arm import Board
from hal_esp32 import Esp32Hal


def main() -> None:
    hal = Esp32Hal(config)
    try:
        board = Board(hal, config)
        while True:
            if not board.poll():
                time.sleep_ms(1)   # nothing arrived: yield a little
    finally:
        hal.outputs_off()


main()
