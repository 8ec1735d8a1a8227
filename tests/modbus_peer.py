"""A Modbus RTU peer for the host tests: pymodbus's own server (ModbusSerialServer,
SimDevice with an action) serving docs/modbus.md's register map from a small Python
model of the pump board, on a pty.

Two ptys joined by a bridge thread that paces bytes at the line's baud rate (one
11-bit character every 95 us at 115200) and can damage the board's next reply
(`corrupt_replies`) or swallow it (`drop_replies`): the host opens
`modbus:/dev/pts/A?addr=N` like a real device; the server runs in its own thread's
asyncio loop on /dev/pts/B (pymodbus servers must be created inside a running loop).

The model is the board's rules that the host depends on, not its physics: a waypoint
queue of QSIZE with free slots, the set point moving linearly to each waypoint over
its duration (time on the model's clock, advanced by the wall clock), done id, the
command register (HOLD/RESUME/CLR/ESTOP latch), limits checked on the window, and
exception codes as docs/modbus.md lists them.
"""
from __future__ import annotations

import asyncio
import os
import select
import threading
import time

from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer
from pymodbus.simulator import DataType, SimData, SimDevice

from armbridge.emulator.pty import open_pty

STATES = ("IDLE", "RUN", "HOLD", "ESTOP", "WDOG", "FAULT")
NONE = 0xFFFF
QSIZE = 4
FW = "arduino_pump"  # the contract's FW_NAME; PumpModel(fw=...) for another
LIMITS = [(0, 524, 500), (0, 960, 500), (0, 1047, 500)]  # soft3 (mrad, mrad/s)


def i16(reg: int) -> int:
    return reg - 65536 if reg >= 32768 else reg


class PumpModel:
    """The register map's behaviour (docs/modbus.md), with a linear set point."""

    def __init__(self, fw: str = FW) -> None:
        self.fw = fw
        self.t0 = time.monotonic()
        self.hold = [0] * 39
        for j, (lo, hi, v) in enumerate(LIMITS):
            self.hold[15 + j], self.hold[18 + j], self.hold[21 + j] = lo, hi, v
            self.hold[3 + j] = 2000
            self.hold[12 + j] = 70
        self.hold[37] = 1000
        self.q = [0.0, 0.0, 0.0]
        self.state = 0
        self.latch = 0
        self.queue: list[list[int]] = []  # id dur q1 q2 q3
        self.seg: tuple[float, list[float], list[int], int] | None = None  # start, from, to, id
        self.dur = 1
        self.next_start: float | None = None
        self.done = NONE
        self.queued = NONE
        self.commands: list[int] = []
        self.window_writes = 0
        self.lock = threading.Lock()
        self.ms_latched = 0

    def ms(self) -> int:
        return int((time.monotonic() - self.t0) * 1000)

    def step(self) -> None:
        """Run the queue up to now: each waypoint a straight segment over its duration,
        the next one starting where the last ended (at once when it was queued in time)."""
        now = self.ms()
        while True:
            if self.seg is None:
                if not self.queue or self.state in (2, 3, 4, 5):
                    if self.state == 1:
                        self.state = 0
                    self.next_start = None
                    return
                wid, dur, *q = self.queue.pop(0)
                start = self.next_start if self.next_start is not None else now
                self.seg = (start, list(self.q), [i16(x) for x in q], wid)
                self.dur = dur
                self.state = 1
            start, q0, q1, wid = self.seg
            f = (now - start) / self.dur
            if f < 1.0:
                self.q = [a + f * (b - a) for a, b in zip(q0, q1)]
                return
            self.q = [float(b) for b in q1]
            self.next_start = start + self.dur
            self.done = wid
            self.seg = None

    def input(self, addr: int) -> int | None:
        if 0 <= addr < 3:
            return int(round(self.q[addr])) & 0xFFFF
        if 3 <= addr < 6:
            return (self.seg[2][addr - 3] if self.seg else int(round(self.q[addr - 3]))) & 0xFFFF
        if 6 <= addr < 9:
            return (150 if self.state == 1 else 0) & 0xFFFF
        if 9 <= addr < 12:
            return 500
        table = {12: self.state, 13: self.latch, 14: self.done, 15: QSIZE - len(self.queue), 16: 0,
                 19: self.queued, 40: 0, 41: 3, 42: 0, 43: 2, 44: 3, 45: QSIZE}
        if addr == 17:
            self.ms_latched = self.ms()
            return (self.ms_latched >> 16) & 0xFFFF
        if addr == 18:
            return self.ms_latched & 0xFFFF
        if 32 <= addr < 40:
            name = self.fw.encode().ljust(16, b"\0")
            k = 2 * (addr - 32)
            return name[k] << 8 | name[k + 1]
        return table.get(addr)

    def write_window(self, regs: list[int]) -> ExcCodes | None:
        if self.state in (3, 4, 5):
            return ExcCodes.DEVICE_FAILURE
        wid, dur, *q = regs
        if wid == NONE or not 1 <= dur <= 60000:
            return ExcCodes.ILLEGAL_VALUE
        for j, v in enumerate(q):
            if not self.hold[15 + j] <= i16(v) <= self.hold[18 + j]:
                return ExcCodes.ILLEGAL_VALUE
        if len(self.queue) >= QSIZE:
            return ExcCodes.DEVICE_BUSY
        self.queue.append(list(regs))
        self.queued = wid
        self.window_writes += 1
        return None

    def write_holding(self, addr: int, value: int) -> ExcCodes | None:
        if addr == 36:
            if value == 1 and self.state == 1:
                self.state = 2
            elif value == 2 and self.state == 2:
                self.state = 0
            elif value == 3 and self.state in (3, 4, 5):
                self.state, self.latch, self.queue, self.seg = 0, 0, [], None
            elif value == 4:
                self.state, self.latch, self.queue, self.seg = 3, 1, [], None
            elif value not in (1, 2, 3, 5):
                return ExcCodes.ILLEGAL_VALUE
            self.commands.append(value)
            return None
        if 12 <= addr < 15 and value > 1000:
            return ExcCodes.ILLEGAL_VALUE
        if not 0 <= addr < 39:
            return ExcCodes.ILLEGAL_ADDRESS
        self.hold[addr] = value
        return None

    async def action(self, fc: int, start: int, address: int, count: int, registers: list[int],
                     values: list[int] | list[bool] | None) -> ExcCodes | None:
        """pymodbus's SimDevice hook: fill the registers a read returns, apply a write."""
        with self.lock:
            self.step()
            if fc == 4:
                for i in range(count):
                    v = self.input(address + i)
                    if v is None:
                        return ExcCodes.ILLEGAL_ADDRESS
                    registers[address + i - start] = v
                return None
            if fc == 3:
                for i in range(count):
                    a = address + i
                    if 100 <= a < 105:
                        registers[a - start] = NONE if not self.queue else self.queue[-1][a - 100]
                    elif a < 39:
                        registers[a - start] = 0 if a == 36 else self.hold[a]
                    else:
                        return ExcCodes.ILLEGAL_ADDRESS
                return None
            vals = [int(v) for v in (values or [])]
            if address == 100 and len(vals) == 5 and fc == 16:
                return self.write_window(vals)
            if address < 105 and address + len(vals) > 100:
                return ExcCodes.ILLEGAL_ADDRESS
            for i, v in enumerate(vals):
                if (ex := self.write_holding(address + i, v)) is not None:
                    return ex
            return None


class Peer:
    """pymodbus's server for `model` on a pty, reached at `.port_name` through a paced bridge."""

    def __init__(self, model: PumpModel, addr: int = 1, baud: int = 115200) -> None:
        self.model = model
        self.addr = addr
        self.char_s = 11.0 / baud
        self.host_pty = open_pty()
        self.board_pty = open_pty()
        self.port_name = self.host_pty.name
        self.corrupt_replies = 0
        self.drop_replies = 0
        self.requests: list[bytes] = []
        self._stop = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: ModbusSerialServer | None = None
        self._started = threading.Event()
        self._threads = [threading.Thread(target=self._serve, daemon=True),
                         threading.Thread(target=self._bridge, daemon=True)]

    def device(self) -> SimDevice:
        regs = DataType.REGISTERS
        hr = [SimData(0, count=39, values=0, datatype=regs), SimData(100, count=5, values=0, datatype=regs)]
        ir = [SimData(0, count=20, values=0, datatype=regs), SimData(32, count=14, values=0, datatype=regs)]
        bits = [SimData(0, count=1, values=False, datatype=DataType.BITS)]
        return SimDevice(self.addr, simdata=(bits, list(bits), hr, ir), action=self.model.action)

    def _serve(self) -> None:
        async def main() -> None:
            self._loop = asyncio.get_running_loop()
            self._server = ModbusSerialServer(self.device(), framer=FramerType.RTU, port=self.board_pty.name,
                                              baudrate=115200, broadcast_enable=True, ignore_missing_devices=True)
            await self._server.serve_forever(background=True)  # returns once it listens on its port
            self._started.set()
            await self._server.serving

        asyncio.run(main())

    def _pump(self, src: int, dst: int, pending: bytearray, reply: bool) -> None:
        try:
            data = os.read(src, 512)
        except (BlockingIOError, OSError):
            return
        if reply and data:
            if self.drop_replies:
                self.drop_replies -= 1
                return
            if self.corrupt_replies:
                self.corrupt_replies -= 1
                data = data[:-1] + bytes([data[-1] ^ 0x01])  # a bit flipped: the CRC fails
        elif data:
            self.requests.append(data)
        pending.extend(data)

    def _bridge(self) -> None:
        up, down = bytearray(), bytearray()
        a, b = self.host_pty.master, self.board_pty.master
        while not self._stop.is_set():
            r, _, _ = select.select([a, b], [], [], 0.01)
            if a in r:
                self._pump(a, b, up, reply=False)
            if b in r:
                self._pump(b, a, down, reply=True)
            for buf, dst in ((up, b), (down, a)):
                while buf:  # paced: one character time per byte
                    os.write(dst, bytes(buf[:1]))
                    del buf[:1]
                    t = time.perf_counter() + self.char_s
                    while time.perf_counter() < t:
                        pass

    def __enter__(self) -> "Peer":
        for t in self._threads:
            t.start()
        if not self._started.wait(60):  # the server listens on its port (a hang guard: it is at once)
            raise RuntimeError("the Modbus peer's server did not start")
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._loop is not None and self._server is not None:
            fut = asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop)
            try:
                fut.result(5)
            except Exception:  # noqa: BLE001 - the loop may be gone already
                pass
        for t in self._threads:
            t.join(5)
        self.host_pty.close()
        self.board_pty.close()
