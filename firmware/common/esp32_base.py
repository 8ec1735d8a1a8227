"""What every ESP32 board's HAL shares over MicroPython's `machine`
(docs/architecture.md, "The HAL"): the clock, the link UART at UART_BAUD
(non-blocking reads), persistence in RTC memory (survives a reset, not a power
cycle), the chip's unique id and the filesystem. The 3R arm's HALs (firmware/esp32/hal_esp32.py,
hal_pca9685.py) and the MASR actuator's (firmware/masr_ma/hal_ma.py) add their
sensors and outputs.

Config names read here: UART_ID, UART_BAUD, UART_TX, UART_RX, UART_RXBUF.
"""

import time

import machine


class Esp32Base:
    """Clock, UART, RTC memory and files of an ESP32 board."""

    def __init__(self, cfg) -> None:
        self.cfg = cfg
        self._uart = machine.UART(cfg.UART_ID, baudrate=cfg.UART_BAUD, tx=cfg.UART_TX,
                                  rx=cfg.UART_RX, rxbuf=cfg.UART_RXBUF, timeout=0)
        self._rtc = machine.RTC()

    # ------------------------------------------------------------ time
    # (no annotations: the stubs type ticks as _TicksMs/_TicksUs, the HAL as int)
    def ticks_ms(self):
        return time.ticks_ms()

    def ticks_us(self):
        return time.ticks_us()

    def ticks_diff(self, a, b):
        return time.ticks_diff(a, b)

    # ------------------------------------------------------------ link
    def uart_read(self):
        n = self._uart.any()
        if n:
            return self._uart.read(n)
        return None

    def uart_write(self, data: bytes) -> None:
        self._uart.write(data)

    # ------------------------------------------------------------ persistence
    def load_persist(self) -> bytes:
        return self._rtc.memory()

    def save_persist(self, data: bytes) -> None:
        self._rtc.memory(data)

    # ------------------------------------------------------------ identity
    def uid(self) -> str:
        """The chip's unique id (its MAC on an ESP32), hex: names the board in IDENT."""
        return machine.unique_id().hex()

    # ------------------------------------------------------------ files
    def read_file(self, name: str):
        """A file of the board's filesystem (the IK weights), or None if missing."""
        try:
            with open(name, "rb") as f:
                return f.read()
        except OSError:
            return None

    def write_file(self, name: str, data: bytes) -> None:
        """Writes a file of the board's filesystem whole (the calibration, calstore.py)."""
        with open(name, "wb") as f:
            f.write(data)
