"""Boot entry on the MA's ESP32: MaHal + Board, poll() forever."""

import time

import config
import micropython
from hal_ma import MaHal
from ma import Board


def main() -> None:
    micropython.alloc_emergency_exception_buf(100)   # a traceback from the hall IRQ, if any
    hal = MaHal(config)
    try:
        board = Board(hal, config)
        while True:
            if not board.poll():
                time.sleep_ms(1)   # nothing arrived: yield a little
    finally:
        hal.outputs_off()


main()
