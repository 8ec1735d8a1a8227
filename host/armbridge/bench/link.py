"""`armbridge bench link`: the line protocol over a pty paced at 115200 baud 8N1.

Every measurement runs the real firmware in the emulator, paced to the wall
clock, through a real pseudo-terminal and the real executor client:

* throughput: 3-joint waypoints streamed under credit flow control, short
  enough (2 ms) that the board is never the bottleneck; waypoints/s and the
  share of the 11,520 bytes/s the host->board direction carries;
* acknowledgement round trip: PING -> OK, timed on the host;
* e-stop latency: with a full queue of moving waypoints, from the host writing
  the 0x98 byte to the board switching its outputs off (the emulator's record,
  mapped to the host clock) and to the ESTOP event reaching the host;
* soak: a long plan under 1% dropped, 1% corrupted and 1% duplicated bytes in
  both directions plus board resets; every waypoint must run exactly once, in
  order, by the board's own log.
"""
from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from armbridge.executor.client import BoardClient
from armbridge.link import protocol as P
from armbridge.link.transport import open_port
from armbridge.robots.catalog import get_robot

LINE_BYTES_PER_S = 115200 / 10  # 8N1: ten bit times a byte
ROBOT = "arm3r"


class CountingPort:
    """Counts the bytes the host writes; everything else goes to the port."""

    def __init__(self, port):
        self._port = port
        self.written = 0

    def write(self, data: bytes) -> int:
        self.written += len(data)
        return self._port.write(data)

    def __getattr__(self, name):
        return getattr(self._port, name)

    def __setattr__(self, name, value):
        if name in ("_port", "written"):
            object.__setattr__(self, name, value)
        else:
            setattr(self._port, name, value)


def wave(k: int, step_mrad: float, period: int = 400) -> np.ndarray:
    """(k, 3) mrad: a smooth back-and-forth around the middle of arm3r's ranges,
    at most `step_mrad` per waypoint on any joint."""
    robot = get_robot(ROBOT)
    mid = (robot.q_min + robot.q_max) / 2 * 1000
    amp = step_mrad * period / (2 * np.pi)
    phase = np.sin(2 * np.pi * np.arange(k)[:, None] / period + np.array([0.0, 1.0, 2.0]))
    return np.rint(mid + amp * phase).astype(int)


def percentiles(samples_s: list[float]) -> dict:
    a = np.asarray(samples_s) * 1000.0
    return {"n": int(a.size), "median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)),
            "max_ms": float(a.max())}


def _session(url: str, **client_kw) -> tuple[CountingPort, BoardClient]:
    port = CountingPort(open_port(url))
    client = BoardClient(port, get_robot(ROBOT), **client_kw)
    client.connect()
    return port, client


def throughput(waypoints: int, url: str = "emu:esp32") -> dict:
    port, client = _session(url)
    try:
        client.set_rate(0)  # the board->host lane carries only acks and events
        q = wave(waypoints, step_mrad=4.0)  # 4 mrad in 2 ms = 2 rad/s, under the 3 rad/s limit
        before = port.written
        t0 = time.monotonic()
        client.execute([2] * waypoints, q.tolist())
        elapsed = time.monotonic() - t0
        sent = port.written - before
        return {"waypoints": waypoints, "seconds": elapsed, "waypoints_per_s": waypoints / elapsed,
                "host_bytes_per_s": sent / elapsed, "line_capacity_used": sent / elapsed / LINE_BYTES_PER_S,
                "bytes_per_waypoint": sent / waypoints,
                "retransmitted": client.stats.waypoints_retransmitted}
    finally:
        port.close()


def round_trip(pings: int, url: str = "emu:esp32") -> dict:
    port, client = _session(url)
    try:
        client.set_rate(0)
        samples = []
        for _ in range(pings):
            t0 = time.perf_counter()
            client.command("PING")
            samples.append(time.perf_counter() - t0)
        return percentiles(samples)
    finally:
        port.close()


def estop_latency(trials: int, url: str = "emu:esp32") -> dict:
    events: list[float] = []

    def on_event(_t, ev: P.Event) -> None:
        if ev.kind == "ESTOP":
            events.append(time.monotonic())

    port, client = _session(url, on_event=on_event)
    emu = port.emulator
    board, host = [], []
    try:
        q = wave(40, step_mrad=20.0)
        for _ in range(trials):
            client.command("CLR")
            for i in range(32):  # fill the queue: 32 waypoints of 100 ms
                client.command("W", i, 100, *q[i])
            _wait(lambda: emu.state == "RUN", 2.0)
            time.sleep(0.05)
            off_before, events_before = len(emu.outputs_off_at), len(events)
            t0 = time.monotonic()
            client.estop()
            _wait(lambda: len(emu.outputs_off_at) > off_before and len(events) > events_before, 2.0,
                  pump=lambda: client.drain(0.002))
            board.append(emu.wall_time(emu.outputs_off_at[-1]) - t0)
            host.append(events[-1] - t0)
        return {"trials": trials, "byte_to_outputs_off": percentiles(board),
                "byte_to_event_at_host": percentiles(host)}
    finally:
        port.close()


def soak(seconds: float, url_faults: str, reset_every_s: float, chunk: int = 100) -> dict:
    """Plans of `chunk` waypoints back to back in one session until `seconds` of
    wall time have passed; the board's log must hold every id once, in order."""
    resets = ",".join(f"{t:g}" for t in np.arange(reset_every_s, seconds, reset_every_s))
    url = f"emu:esp32?{url_faults}" + (f"&reset_at={resets}" if resets else "")
    port, client = _session(url)
    emu = port.emulator
    q = wave(chunk, step_mrad=20.0).tolist()  # 20 mrad in 20 ms = 1 rad/s
    plans = 0
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            client.execute([20] * chunk, q, timeout=600)
            plans += 1
        # Ids run on across the plans of a session: the log must read 0, 1, 2, ...
        ids = [i for _, i, _ in emu.executed]
        expected = [i % 65536 for i in range(plans * chunk)]
        lost = sum((Counter(expected) - Counter(ids)).values())
        duplicated = sum((Counter(ids) - Counter(expected)).values())
        # The board logs the values it executed: an (id, values) pair the host did not
        # send, beyond the duplicates, is a waypoint run with a wrong value.
        sent = [tuple(int(x) for x in row) for row in q]  # q is in mrad already
        pairs = Counter((i % 65536, sent[i % chunk]) for i in range(plans * chunk))
        wrong = sum((Counter((i, v) for _, i, v in emu.executed) - pairs).values()) - duplicated
        elapsed = time.monotonic() - t0
        return {"seconds": elapsed, "plans": plans, "waypoints": plans * chunk,
                "executed": len(emu.executed), "lost": lost, "duplicated": duplicated, "wrong_value": wrong,
                "in_order": ids == expected, "resets": emu.counters["resets"],
                "resyncs": client.stats.resyncs, "retransmitted": client.stats.waypoints_retransmitted,
                "line_errors": client.stats.line_errors, "faults_injected": emu.counters}
    finally:
        port.close()


def _wait(pred: Callable[[], bool], timeout: float, pump: Callable[[], None] | None = None) -> None:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise TimeoutError("benchmark condition not reached")
        if pump is not None:
            pump()
        else:
            time.sleep(0.001)


@dataclass
class LinkBenchSize:
    waypoints: int
    pings: int
    estops: int
    soak_s: float
    reset_every_s: float


FULL = LinkBenchSize(waypoints=3000, pings=500, estops=30, soak_s=600, reset_every_s=60)
QUICK = LinkBenchSize(waypoints=300, pings=50, estops=5, soak_s=15, reset_every_s=7)
SOAK_FAULTS = "drop=0.01&corrupt=0.01&dup=0.01&seed=7"


def run(size: LinkBenchSize, progress: Callable[[str], None] = print) -> dict:
    progress(f"throughput: {size.waypoints} waypoints")
    result = {"throughput": throughput(size.waypoints)}
    progress(f"round trip: {size.pings} pings")
    result["round_trip"] = round_trip(size.pings)
    progress(f"e-stop: {size.estops} trials")
    result["estop"] = estop_latency(size.estops)
    progress(f"soak: {size.soak_s:g} s with {SOAK_FAULTS}, a reset every {size.reset_every_s:g} s")
    result["soak"] = soak(size.soak_s, SOAK_FAULTS, size.reset_every_s)
    result["size"] = size.__dict__
    return result
