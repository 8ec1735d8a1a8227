"""The emulated board's UART: a byte link paced at the baud rate, with seeded fault injection.

Two lanes, each a FIFO on the emulator's clock (seconds):

* ``rx``: host -> firmware. A byte that arrives from the host at time t becomes
  readable by the firmware at ``max(t, previous byte's time) + 1/B`` where
  B = baud / 10 bytes/s (8N1: start + 8 data + stop bits; 11,520 bytes/s at 115200).
* ``tx``: firmware -> host. A byte the firmware writes at t leaves the board at
  the same pace, ``max(t, previous) + 1/B``. A board whose chip is simulated
  (simavr) sets this lane's byte time to the chip's own (`Lane.set_byte_time`):
  its UART runs at the rate its baud divisor gives, not exactly at `baud`.

Faults (`LinkFaults`) are applied per byte as it enters a lane, in this order:
drop (the byte vanishes), corrupt (ONE random bit of the byte is flipped, a
single-bit error as UART noise makes; docs/protocol.md section 2 explains why
the e-stop byte 0x98 survives single-bit errors of line bytes), duplicate (the
byte is sent twice), delay (the byte is held ``delay_ms`` extra; a UART is a
FIFO, so the bytes behind it wait too). The e-stop byte takes the same path as
any other byte. Every lane has its own seeded RNG and counts what it injected.
"""
from __future__ import annotations

import random
from collections import deque
from dataclasses import dataclass

LANES = ("rx", "tx")


@dataclass(frozen=True)
class LinkFaults:
    """Byte fault rates (probability per byte, each in [0, 1]) and the extra delay."""

    drop: float = 0.0
    corrupt: float = 0.0
    dup: float = 0.0
    delay: float = 0.0
    delay_ms: float = 0.0

    def __post_init__(self) -> None:
        for name in ("drop", "corrupt", "dup", "delay"):
            r = getattr(self, name)
            if not 0.0 <= r <= 1.0:
                raise ValueError(f"{name} rate {r} is outside [0, 1]")
        if self.delay_ms < 0:
            raise ValueError(f"delay_ms {self.delay_ms} is negative")

    @property
    def active(self) -> bool:
        return bool(self.drop or self.corrupt or self.dup or (self.delay and self.delay_ms))


class Lane:
    """One direction of the UART: a paced FIFO with fault injection."""

    def __init__(self, name: str, bytes_per_s: float, faults: LinkFaults | None, seed: int) -> None:
        self.name = name
        self.byte_time = 1.0 / bytes_per_s
        self.faults = faults if faults is not None and faults.active else None
        self._rng = random.Random(f"armbridge-uart:{seed}:{name}")
        self._q: deque[tuple[float, int]] = deque()
        self._last = float("-inf")
        self.counters = {"bytes": 0, "drop": 0, "corrupt": 0, "dup": 0, "delay": 0}
        self._last_eol: float | None = None  # delivery time of the latest line end
        self.longest_line_gap = 0.0  # s between two line ends delivered: what a board's watchdog sees

    def set_byte_time(self, seconds: float) -> None:
        """Pace the bytes that enter from now on at `seconds` a byte (those queued keep their times)."""
        if not seconds > 0:
            raise ValueError(f"byte time {seconds} is not positive")
        self.byte_time = float(seconds)

    def push(self, data: bytes, t: float) -> None:
        """Bytes that enter the lane at time t (s)."""
        f = self.faults
        bt = self.byte_time
        c = self.counters
        for b in data:
            c["bytes"] += 1
            extra = 0.0
            copies = 1
            if f is not None:
                r = self._rng
                if f.drop and r.random() < f.drop:
                    c["drop"] += 1
                    continue
                if f.corrupt and r.random() < f.corrupt:
                    b ^= 1 << r.randrange(8)
                    c["corrupt"] += 1
                if f.dup and r.random() < f.dup:
                    copies = 2
                    c["dup"] += 1
                if f.delay and f.delay_ms and r.random() < f.delay:
                    extra = f.delay_ms / 1000.0
                    c["delay"] += 1
            for _ in range(copies):
                start = t + extra
                if start < self._last:
                    start = self._last
                self._last = start + bt
                self._q.append((self._last, b))

    def pop(self, now: float) -> bytes:
        """Bytes whose time has come by `now`."""
        q = self._q
        if not q or q[0][0] > now:
            return b""
        out = bytearray()
        while q and q[0][0] <= now:
            t, b = q.popleft()
            if b == 0x0A:
                self._eol(t)
            out.append(b)
        return bytes(out)

    def pop_timed(self, now: float) -> list[tuple[float, int]]:
        """Like pop, with each byte's time: [(t, byte), ...]."""
        q = self._q
        out = []
        while q and q[0][0] <= now:
            item = q.popleft()
            if item[1] == 0x0A:
                self._eol(item[0])
            out.append(item)
        return out

    def _eol(self, t: float) -> None:
        if self._last_eol is not None and t - self._last_eol > self.longest_line_gap:
            self.longest_line_gap = t - self._last_eol
        self._last_eol = t

    @property
    def pending(self) -> int:
        return len(self._q)

    def next_time(self) -> float | None:
        return self._q[0][0] if self._q else None

    def next_mark(self, marks: bytes = b"\n\x98", scan: int = 256) -> float | None:
        """Time of the first queued byte that is in `marks` (looking at most `scan` bytes ahead)."""
        for i, (t, b) in enumerate(self._q):
            if b in marks:
                return t
            if i >= scan:
                return t
        return None

    def clear(self) -> int:
        """Drop everything queued (a UART reset); returns how many bytes were lost."""
        n = len(self._q)
        self._q.clear()
        self._last_eol = None  # the board restarts: its watchdog too
        return n


class PacedUart:
    """The board's UART at `baud` 8N1, both lanes paced, faults on the lanes named in `lanes`."""

    def __init__(
        self,
        baud: int = 115200,
        faults: LinkFaults | None = None,
        lanes: tuple[str, ...] = LANES,
        seed: int = 0,
    ) -> None:
        for name in lanes:
            if name not in LANES:
                raise ValueError(f"unknown lane {name!r}; lanes are {', '.join(LANES)}")
        self.baud = baud
        self.bytes_per_s = baud / 10.0
        self.rx = Lane("rx", self.bytes_per_s, faults if "rx" in lanes else None, seed)
        self.tx = Lane("tx", self.bytes_per_s, faults if "tx" in lanes else None, seed)

    # host side
    def host_write(self, data: bytes, t: float) -> None:
        self.rx.push(data, t)

    def host_read(self, now: float) -> bytes:
        return self.tx.pop(now)

    # firmware side
    def firmware_read(self, now: float) -> bytes:
        return self.rx.pop(now)

    def firmware_write(self, data: bytes, t: float) -> None:
        self.tx.push(data, t)

    @property
    def counters(self) -> dict[str, dict[str, int]]:
        return {"rx": dict(self.rx.counters), "tx": dict(self.tx.counters)}
