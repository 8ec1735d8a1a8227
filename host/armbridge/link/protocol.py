"""Host codec of the armbridge line protocol v1 (spec: docs/protocol.md).

Pure functions over bytes. The board's codec (firmware/common/proto.py) is a
separate MicroPython implementation; both are tested against tests/vectors/.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

PROTOCOL_VERSION = 1
MAX_COMMAND_LINE = 96  # bytes, LF included: host -> board
MAX_BOARD_LINE = 192  # bytes, LF included: board -> host
ESTOP_BYTE = b"\x98"
SEQ_MOD = 65536

PARSE, CRC, LONG, VERB, ARGS, RANGE, SEQ, FULL, LATCHED, NOSESSION = range(1, 11)
ERROR_NAMES = {
    PARSE: "PARSE", CRC: "CRC", LONG: "LONG", VERB: "VERB", ARGS: "ARGS", RANGE: "RANGE",
    SEQ: "SEQ", FULL: "FULL", LATCHED: "LATCHED", NOSESSION: "NOSESSION",
}

_FRAME = re.compile(rb"([\x20-\x7e]*)\*([0-9A-F]{4})")
_BODY = re.compile(r"(0|[1-9][0-9]{0,4}) ([A-Z]{1,8})((?: [!-)+-~]+)*)")
_INT = re.compile(r"-?(0|[1-9][0-9]*)")


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
        table.append(crc & 0xFFFF)
    return tuple(table)


_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final XOR."""
    crc = 0xFFFF
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _TABLE[(crc >> 8) ^ byte]
    return crc


class ProtocolError(Exception):
    """A line that is not valid protocol: `code`/`name` as in docs/protocol.md §5."""

    def __init__(self, code: int, message: str = ""):
        self.code = code
        self.name = ERROR_NAMES[code]
        super().__init__(f"{self.name}: {message}" if message else self.name)


@dataclass(frozen=True)
class Line:
    seq: int
    verb: str
    args: tuple[str, ...]


def encode(seq: int, verb: str, *args: object) -> bytes:
    """One protocol line, CRC and LF included."""
    if not 0 <= seq < SEQ_MOD:
        raise ValueError(f"seq {seq} outside 0..65535")
    body = " ".join([str(seq), verb, *map(str, args)]).encode("ascii")
    return b"%s*%04X\n" % (body, crc16(body))


def decode(line: bytes, max_len: int = MAX_BOARD_LINE) -> Line:
    """Checks length, framing, CRC and body grammar, in that order (§1)."""
    size = len(line) + (0 if line.endswith(b"\n") else 1)
    if size > max_len:
        raise ProtocolError(LONG, f"{size} bytes, the bound is {max_len}")
    if line.endswith(b"\n"):
        line = line[:-1]
    if line.endswith(b"\r"):
        line = line[:-1]
    frame = _FRAME.fullmatch(line)
    if frame is None:
        raise ProtocolError(PARSE, "not 'BODY*CRC' in printable ASCII")
    body, crc_field = frame.groups()
    if crc16(body) != int(crc_field, 16):
        raise ProtocolError(CRC, f"got {crc_field.decode()}, computed {crc16(body):04X}")
    match = _BODY.fullmatch(body.decode("ascii"))
    if match is None or int(match.group(1)) >= SEQ_MOD:
        raise ProtocolError(PARSE, "body is not 'SEQ VERB ARGS'")
    seq, verb, rest = match.groups()
    return Line(int(seq), verb, tuple(rest.split()))


class LineSplitter:
    """Cuts a byte stream into lines; an overlong line becomes one LONG error."""

    def __init__(self, max_len: int = MAX_BOARD_LINE):
        self.max_len = max_len
        self._buf = bytearray()
        self._overlong = False

    def feed(self, data: bytes) -> list[bytes | ProtocolError]:
        out: list[bytes | ProtocolError] = []
        start = 0
        while True:
            end = data.find(b"\n", start)
            piece = data[start:] if end < 0 else data[start:end]
            if not self._overlong:
                self._buf += piece
                if len(self._buf) >= self.max_len:
                    self._overlong, self._buf = True, bytearray()
            if end < 0:
                return out
            if self._overlong:
                out.append(ProtocolError(LONG, "line over the length bound"))
            else:
                out.append(bytes(self._buf) + b"\n")
            self._buf, self._overlong = bytearray(), False
            start = end + 1


def parse_int(text: str, lo: int, hi: int, what: str) -> int:
    """A protocol integer (no '+', no leading zeros, no '-0') within [lo, hi]."""
    if not _INT.fullmatch(text) or text == "-0":
        raise ProtocolError(ARGS, f"{what} {text!r} is not an integer")
    value = int(text)
    if not lo <= value <= hi:
        raise ProtocolError(RANGE, f"{what} {value} outside [{lo}, {hi}]")
    return value


# Host -> board commands: argument names and ranges (§3). `q` stands for n joint values.
JOINT_LIMIT = 1_000_000
COMMANDS: dict[str, tuple[tuple[str, int, int], ...]] = {
    "HELLO": (("session", 1, 65535),),
    "LIM": (("joint", 1, 0),),
    "W": (("id", 0, 65535), ("dur", 1, 60000), ("q", -JOINT_LIMIT, JOINT_LIMIT)),
    "HOLD": (),
    "RESUME": (),
    "CLR": (),
    "RATE": (("hz", 0, 100),),
    "GAIN": (("joint", 1, 0), ("kp", 0, 1_000_000), ("ki", 0, 1_000_000), ("kd", 0, 1_000_000)),
    "SETLIM": (("joint", 1, 0), ("min", -JOINT_LIMIT, JOINT_LIMIT), ("max", -JOINT_LIMIT, JOINT_LIMIT),
               ("vmax", 1, JOINT_LIMIT)),
    "WDOG": (("ms", 50, 10000),),
    "STAT": (),
    "PING": (),
}


def parse_command(verb: str, args: tuple[str, ...] | list[str], n_joints: int) -> list[int]:
    """Checks a command's arguments as a board does; a 'joint' upper bound of 0 means n."""
    if verb not in COMMANDS:
        raise ProtocolError(VERB, f"unknown verb {verb}")
    spec = COMMANDS[verb]
    names = [name for name, _, _ in spec for _ in range(n_joints if name == "q" else 1)]
    if len(args) != len(names):
        raise ProtocolError(ARGS, f"{verb} takes {len(names)} arguments, got {len(args)}")
    bounds = {name: (lo, hi or n_joints) for name, lo, hi in spec}
    values = [parse_int(a, *bounds[name], name) for a, name in zip(args, names)]
    if verb == "SETLIM" and values[1] >= values[2]:
        raise ProtocolError(RANGE, f"min {values[1]} not below max {values[2]}")
    return values


def to_milli(values) -> list[int]:
    """SI values (rad, m) to the protocol's integer milli-units."""
    return [int(v) for v in np.rint(np.asarray(values, dtype=float) * 1000.0)]


def from_milli(texts) -> np.ndarray:
    return np.array([int(t) for t in texts], dtype=float) / 1000.0


# Board -> host lines (§4).
@dataclass(frozen=True)
class Ok:
    bseq: int
    seq: int
    free: int
    payload: tuple[str, ...]


@dataclass(frozen=True)
class Er:
    bseq: int
    seq: int | None
    code: int
    name: str
    detail: tuple[str, ...]


@dataclass(frozen=True)
class Telemetry:
    bseq: int
    ms: int
    state: str
    done: int | None
    free: int
    q: np.ndarray  # measured, SI
    target: np.ndarray  # set point, SI
    effort: np.ndarray  # [-1, 1]


@dataclass(frozen=True)
class Event:
    bseq: int
    ms: int
    kind: str
    args: tuple[str, ...]


@dataclass(frozen=True)
class Boot:
    bseq: int
    fw: str
    version: str
    proto: int


BoardLine = Ok | Er | Telemetry | Event | Boot


def optional_id(text: str) -> int | None:
    return None if text == "-" else parse_int(text, 0, 65535, "id")


def parse_board_line(line: Line) -> BoardLine:
    """Types a decoded board line; raises ProtocolError(ARGS) when malformed."""
    a = line.args
    try:
        if line.verb == "OK":
            return Ok(line.seq, int(a[0]), int(a[1]), a[2:])
        if line.verb == "ER":
            seq = None if a[0] == "-" else int(a[0])
            return Er(line.seq, seq, int(a[1]), a[2], a[3:])
        if line.verb == "T":
            n, rem = divmod(len(a) - 4, 3)
            if rem or n < 1:
                raise ValueError("joint columns")
            ints = np.array([int(x) for x in a[4:]], dtype=float)
            return Telemetry(line.seq, int(a[0]), a[1], optional_id(a[2]), int(a[3]),
                             ints[:n] / 1000.0, ints[n:2 * n] / 1000.0, ints[2 * n:] / 1000.0)
        if line.verb == "EV":
            return Event(line.seq, int(a[0]), a[1], a[2:])
        if line.verb == "BOOT":
            return Boot(line.seq, a[0], a[1], int(a[2]))
    except (IndexError, ValueError) as exc:
        raise ProtocolError(ARGS, f"{line.verb} line: {exc}") from None
    raise ProtocolError(VERB, f"unknown board line {line.verb}")
