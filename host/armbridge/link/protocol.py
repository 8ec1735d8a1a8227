"""Host codec of the armbridge line protocol v2 (spec: docs/protocol.md).

Pure functions over bytes. Verbs, argument ranges, error codes and constants
come from the one table, link/protodef.py; the board's codec
(firmware/common/proto.py) reads the same table (rendered as
firmware/common/protodef.py), and both are tested against tests/vectors/.
"""
from __future__ import annotations

import re
import zlib
from dataclasses import dataclass

import numpy as np

from armbridge.link import protodef as D
from armbridge.link.protodef import (  # noqa: F401  (re-exported: the codes users name)
    ARGS, CRC, FULL, LATCHED, LONG, NOSESSION, PARSE, PROTO, RANGE, REACH, SEQ, STALE, UNHOMED, VERB,
)

PROTOCOL_VERSION = D.PROTOCOL_VERSION
MAX_HOST_LINE = D.MAX_HOST_LINE
MAX_BOARD_LINE = D.MAX_BOARD_LINE
ESTOP_BYTE = bytes([D.ESTOP_BYTE])
SEQ_MOD = D.SEQ_MOD
RING = D.RING
EPOCH_MAX = D.EPOCH_MAX
MAX_EPOCH_COMMANDS = D.MAX_EPOCH_COMMANDS
ERROR_NAMES = D.ERROR_NAMES
COMMANDS = D.COMMANDS
READ_ONLY = D.READ_ONLY
STATES = D.STATES

_FRAME = re.compile(rb"([\x20-\x7e]*)\*([0-9A-F]{8})")
_BODY = re.compile(r"(0|[1-9][0-9]{0,4}) ([A-Z]{1,8})((?: [!-)+-~]+)*)")
_INT = re.compile(r"-?(0|[1-9][0-9]*)")
_MAX_DIGITS = len(str(D.EPOCH_MAX))  # no range in the table needs more digits


def crc32(data: bytes, epoch: int = 0) -> int:
    """CRC-32/ISO-HDLC (zlib's) of `data`, started from the link epoch (§1)."""
    return zlib.crc32(data, epoch)


def is_hello(body: bytes) -> bool:
    """True when the body's second field is HELLO: its CRC uses epoch 0 (§1)."""
    space = body.find(b" ")
    return space >= 0 and (body[space + 1:] == b"HELLO" or body.startswith(b"HELLO ", space + 1))


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


def encode(seq: int, verb: str, *args: object, epoch: int = 0) -> bytes:
    """One protocol line, CRC and LF included. The CRC starts from `epoch`,
    except for HELLO, which is always framed with epoch 0 (§1)."""
    if not 0 <= seq < SEQ_MOD:
        raise ValueError(f"seq {seq} outside 0..65535")
    body = " ".join([str(seq), verb, *map(str, args)]).encode("ascii")
    return b"%s*%08X\n" % (body, crc32(body, D.HELLO_EPOCH if verb == "HELLO" else epoch))


def decode(line: bytes, max_len: int = MAX_BOARD_LINE, epoch: int = 0) -> Line:
    """Checks length, framing, CRC and body grammar, in that order (§1). The CRC
    is checked from `epoch`, or from 0 when the body is a HELLO."""
    size = len(line) + (0 if line.endswith(b"\n") else 1)
    if size > max_len:
        raise ProtocolError(LONG, f"{size} bytes, the bound is {max_len}")
    if line.endswith(b"\n"):
        line = line[:-1]
    if line.endswith(b"\r"):
        line = line[:-1]
    frame = _FRAME.fullmatch(line)
    if frame is None:
        raise ProtocolError(PARSE, "not 'BODY*CRC' (8 upper-case hex digits) in printable ASCII")
    body, crc_field = frame.groups()
    want = crc32(body, D.HELLO_EPOCH if is_hello(body) else epoch)
    if want != int(crc_field, 16):
        raise ProtocolError(CRC, f"got {crc_field.decode()}, computed {want:08X}")
    return parse_body(body)


def parse_body(body: bytes) -> Line:
    """The grammar of a body whose frame and CRC were checked: 'SEQ VERB ARGS'."""
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


def _is_int(text: str) -> bool:
    return _INT.fullmatch(text) is not None and text != "-0"


def parse_int(text: str, lo: int, hi: int, what: str) -> int:
    """A protocol integer (no '+', no leading zeros, no '-0') within [lo, hi]."""
    if not _is_int(text):
        raise ProtocolError(ARGS, f"{what} {text!r} is not an integer")
    if len(text.lstrip("-")) > _MAX_DIGITS:  # beyond every range; int() of it may not even parse
        raise ProtocolError(RANGE, f"{what} {text[:12]}... outside [{lo}, {hi}]")
    value = int(text)
    if not lo <= value <= hi:
        raise ProtocolError(RANGE, f"{what} {value} outside [{lo}, {hi}]")
    return value


def command_args(verb: str, n_joints: int) -> list[tuple[str, int, int]]:
    """The argument specs of `verb` for an n-joint board, `q` expanded to n
    values (`q1`..`qn`) and `joint` bounded by n."""
    specs: list[tuple[str, int, int]] = []
    for name, lo, hi in COMMANDS[verb]:
        if name == "q":
            specs += [(f"q{j}", lo, hi) for j in range(1, n_joints + 1)]
        else:
            specs.append((name, lo, n_joints if name == "joint" else hi))
    return specs


def parse_command(verb: str, args: tuple[str, ...] | list[str], n_joints: int) -> list[int]:
    """Checks a command's arguments as a board does (§3), in the spec's order:
    verb (VERB), count (ARGS), the form of every argument (ARGS), each range in
    turn (RANGE), then the cross-argument rules (RANGE)."""
    if verb not in COMMANDS:
        raise ProtocolError(VERB, f"unknown verb {verb}")
    specs = command_args(verb, n_joints)
    if len(args) != len(specs):
        raise ProtocolError(ARGS, f"{verb} takes {len(specs)} arguments, got {len(args)}")
    for text, (name, _, _) in zip(args, specs):
        if not _is_int(text):
            raise ProtocolError(ARGS, f"{verb} {name} {text!r} is not an integer")
    values = [parse_int(text, lo, hi, f"{verb} {name}") for text, (name, lo, hi) in zip(args, specs)]
    names = [name for name, _, _ in specs]
    for a, b in D.ORDERED.get(verb, ()):
        low, high = values[names.index(a)], values[names.index(b)]
        if low > high:
            raise ProtocolError(RANGE, f"{verb} {a} {low} above {b} {high}")
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
    extra: tuple[int, ...] = ()  # a board's own columns after the 3n (docs/protocol.md §4), as sent


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
    state: str  # IDLE after a power on; a latched state survives a reset


BoardLine = Ok | Er | Telemetry | Event | Boot


def optional_id(text: str) -> int | None:
    return None if text == "-" else parse_int(text, 0, 65535, "id")


def parse_board_line(line: Line, joints: int | None = None) -> BoardLine:
    """Types a decoded board line; raises ProtocolError(ARGS) when malformed.

    `joints`: the board's n from HELLO, once known: a T line then holds 3n joint
    columns and the board's own extra columns after them (the MA's j_d, d_link,
    speed). Before HELLO (None) a T line must be exactly 3n columns."""
    a = line.args
    try:
        if line.verb == "OK":
            return Ok(line.seq, int(a[0]), int(a[1]), a[2:])
        if line.verb == "ER":
            seq = None if a[0] == "-" else int(a[0])
            return Er(line.seq, seq, int(a[1]), a[2], a[3:])
        if line.verb == "T":
            if joints is None:
                n, rem = divmod(len(a) - 4, 3)
                if rem or n < 1:
                    raise ValueError("joint columns")
            else:
                n = joints
                if n < 1 or len(a) < 4 + 3 * n:
                    raise ValueError(f"{len(a) - 4} columns, a board of {n} joints sends at least {3 * n}")
            ints = np.array([int(x) for x in a[4:4 + 3 * n]], dtype=float)
            return Telemetry(line.seq, int(a[0]), a[1], optional_id(a[2]), int(a[3]),
                             ints[:n] / 1000.0, ints[n:2 * n] / 1000.0, ints[2 * n:] / 1000.0,
                             tuple(int(x) for x in a[4 + 3 * n:]))
        if line.verb == "EV":
            return Event(line.seq, int(a[0]), a[1], a[2:])
        if line.verb == "BOOT":
            if len(a) != 4:
                raise ValueError(f"{len(a)} fields, BOOT has 4 (fw fwver proto state)")
            return Boot(line.seq, a[0], a[1], int(a[2]), a[3])
    except (IndexError, ValueError) as exc:
        raise ProtocolError(ARGS, f"{line.verb} line: {exc}") from None
    raise ProtocolError(VERB, f"unknown board line {line.verb}")
