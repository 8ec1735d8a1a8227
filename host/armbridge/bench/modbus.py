"""The Modbus RTU round trip to the pump board (docs/benchmarks.md, docs/modbus.md).

    modbus_round_trip("modbus:/dev/ttyUSB0?addr=1", n=200)

Two requests, each timed from the call to the last reply byte read (retries
included and counted), on the port's clock: the wall clock for a device, the
emulator's simulated time for `modbus:emu:...` (cycle-exact in simavr, whatever
the host's load; `clock` in the result says which):

* one register: FC4 of input register 12 (the state);
* a full set-point write: FC16 of holding 0..2 with the set points the board already
  has (input 3..5, read once first), so the arm does not move.

The floor at 115200 baud is the bytes on the wire (8 + 7 characters for the read,
15 + 8 for the write, 11 bits each) plus two t3.5 silences (1.75 ms each): the
board's before it answers, and ours after its reply before the next request.
`wire_ms` gives it, to set the measured numbers beside.
"""
from __future__ import annotations

import statistics
import time
from typing import Any

from armbridge.link.modbus import t35_s

READ_BYTES = (8, 7)  # request, reply: FC4 of one register
WRITE_BYTES = (15, 8)  # FC16 of three registers


def wire_ms(request: int, reply: int, baud: int = 115200) -> float:
    """Characters on the wire plus the two t3.5 silences of one request cycle, in ms."""
    return ((request + reply) * 11.0 / baud + 2 * t35_s(baud)) * 1000.0


def _summary(times_ms: list[float]) -> dict[str, float]:
    s = sorted(times_ms)
    return {"median_ms": statistics.median(s), "p95_ms": s[min(len(s) - 1, int(0.95 * len(s)))],
            "min_ms": s[0], "max_ms": s[-1]}


def modbus_round_trip(port_url: str, n: int = 200) -> dict[str, Any]:
    """Time n one-register reads and n full set-point writes on the board at `port_url`
    (a modbus: url); returns both summaries, the wire floor and the retries."""
    from armbridge.link.transport import open_port

    with open_port(port_url) as port:
        master = getattr(port, "master", None)
        if master is None:
            from armbridge.errors import ArmbridgeError

            raise ArmbridgeError(f"{port_url} is not a modbus: port")
        here = master.read_input(3, 3)  # the set points now: written back unchanged
        now = port.clock if port.clock is not None else time.perf_counter
        reads, writes = [], []
        for _ in range(n):
            t0 = now()
            master.read_input(12, 1)
            reads.append((now() - t0) * 1000.0)
        for _ in range(n):
            t0 = now()
            master.write_registers(0, here)
            writes.append((now() - t0) * 1000.0)
        baud = master.baud
        return {"port": port_url, "n": n, "baud": baud, "clock": "wall" if port.clock is None else "emulator",
                "read_one": _summary(reads),
                "write_setpoints": _summary(writes), "wire_read_ms": wire_ms(*READ_BYTES, baud),
                "wire_write_ms": wire_ms(*WRITE_BYTES, baud), "retries": master.stats.retries,
                "timeouts": master.stats.timeouts}
