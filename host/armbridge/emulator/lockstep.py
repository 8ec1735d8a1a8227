"""A lockstep emulator as a port, with no thread and no pty: runs repeat bit for bit.

`EmulatedBoard(..., speed=0).start()` runs the board in a thread of its own,
on a pty, as fast as it can; a coupled host holds it within HOST_LEAD_S of
its own last read. Where a host's line lands on the board's clock then
depends on how the two threads were scheduled (the same plan and seed gave
41.15 s / 1.80 mm, then 41.19 s / 0.91 mm: issue 21), so such a run cannot be
replayed. Here the host and the board take turns in one thread instead:

* sim time advances only while the host waits for the board: `read(n)` runs
  the board until it has sent a byte or the port's `timeout` has passed, in
  sim seconds (the wall clock plays no part);
* what the host writes reaches the board's UART at the sim time of the
  host's latest read (`EmulatedBoard.inject`), through the same paced, faulty
  lane as from a pty;
* the host's clock is the board's (`Port.clock` = `EmulatedBoard.now`), so
  its timers (retransmission, keep-alive, drain) run on sim time.

Given the plan, the seed and the host's own choices (its session number),
every byte on the link, every telemetry sample and the plant's truth are then
a function of those alone, on any machine at any load.

    emu = EmulatedBoard("masr_ma", speed=0, seed=3)
    port = lockstep_port(emu, "emu:masr_ma?speed=0&seed=3")
    client = BoardClient(port, robot, session=1)   # the host as over any port

`emulator.url.open_lockstep_port(url)` builds the board from an `emu:` url with speed 0.
"""
from __future__ import annotations

from typing import Any

from armbridge.errors import ArmbridgeError

BLOCKING_CAP_S = 3600.0  # a read with timeout None waits this long of sim time at most (a dead board)


class LockstepSerial:
    """The part of a pyserial object that `transport.Port` uses, over an EmulatedBoard
    that is not started (no thread, no pty): the board runs inside `read`."""

    def __init__(self, emu: Any, timeout: float | None = 0.1, baudrate: int = 115200) -> None:
        if emu.speed != 0:
            raise ArmbridgeError(f"a lockstep port needs an emulator at speed 0, not {emu.speed:g}")
        if emu.running:
            raise ArmbridgeError("a lockstep port runs the emulator itself: do not start() it")
        self.emu = emu
        self.timeout = timeout
        self.baudrate = baudrate
        self.is_open = True
        self._buf = bytearray()

    def _take(self) -> bool:
        """Move what the board has sent into the buffer -> True when it holds a byte."""
        self._buf += self.emu.read_output()
        return bool(self._buf)

    def _check(self) -> None:
        if not self.is_open:
            raise OSError("the lockstep port is closed")
        if self.emu.crash is not None and not self._buf:
            raise OSError("the emulated board crashed")

    def read(self, n: int = 1) -> bytes:
        """Up to n bytes; runs the board until it has sent one or `timeout` s of sim time have passed."""
        self._check()
        if not self._take():
            wait = BLOCKING_CAP_S if self.timeout is None else max(0.0, float(self.timeout))
            if wait > 0:
                self.emu.run_until(self._take, wait)
        out = bytes(self._buf[:n])
        del self._buf[:n]
        return out

    def write(self, data: bytes) -> int:
        """The bytes reach the board's UART now (the sim time of the latest read)."""
        self._check()
        data = bytes(data)
        self.emu.inject(data)
        return len(data)

    def flush(self) -> None:
        self._check()

    @property
    def in_waiting(self) -> int:
        self._check()
        self._take()
        return len(self._buf)

    def reset_input_buffer(self) -> None:
        self._take()
        self._buf.clear()

    def close(self) -> None:
        self.is_open = False


def lockstep_port(emu: Any, url: str, timeout: float | None = 0.1, baud: int = 115200):
    """A `transport.Port` over `emu` (speed 0, not started) that runs it in lockstep with
    its host: `.emulator` is emu, `.clock` its sim clock; close() stops it."""
    from armbridge.link.transport import Port

    return Port(LockstepSerial(emu, timeout, baud), url, emulator=emu, clock=emu.now)
