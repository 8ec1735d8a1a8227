"""Line protocol codec, version 1 (docs/protocol.md), for MicroPython and CPython.

crc16, encode, decode, LineReader (framing and the out-of-band e-stop byte) and
parse_command (argument checks of the host -> board commands). Pure: no I/O.
"""

try:
    from micropython import const
except ImportError:  # CPython (emulator, tests)
    def const(x):  # type: ignore[no-redef,misc]
        return x

PROTO_VERSION = const(1)
MAX_HOST_LINE = const(96)   # bytes, LF included, host -> board
MAX_BOARD_LINE = const(192)  # bytes, LF included, board -> host
ESTOP_BYTE = const(0x98)
JOINT_ABS_MAX = const(1000000)  # joint values are within +-1e6 milli-units

# Error codes (docs/protocol.md section 5)
PARSE = const(1)
CRC = const(2)
LONG = const(3)
VERB = const(4)
ARGS = const(5)
RANGE = const(6)
SEQ = const(7)
FULL = const(8)
LATCHED = const(9)
NOSESSION = const(10)

ERROR_NAMES = {
    1: "PARSE", 2: "CRC", 3: "LONG", 4: "VERB", 5: "ARGS",
    6: "RANGE", 7: "SEQ", 8: "FULL", 9: "LATCHED", 10: "NOSESSION",
}

_LF = const(0x0A)
_CR = const(0x0D)
_SP = const(0x20)
_STAR = const(0x2A)


class ProtoError(Exception):
    """A refused line or command: `code` (int), `name` (str), optional `detail`."""

    def __init__(self, code: int, name: str = "", detail: str = "") -> None:
        if not name:
            name = ERROR_NAMES.get(code, "ERR")
        super().__init__(code, name)
        self.code = code
        self.name = name
        self.detail = detail


# ---------------------------------------------------------------- CRC-16/CCITT-FALSE

def _make_table() -> list:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_TABLE = _make_table()


def crc16(data, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of bytes/bytearray (poly 0x1021, init 0xFFFF)."""
    table = _TABLE
    for b in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[((crc >> 8) ^ b) & 0xFF]
    return crc


# ---------------------------------------------------------------- encode / decode

def encode(seq, verb: str, args=()) -> bytes:
    """One line `seq verb args*CRC\\n`; args may be ints or strings."""
    parts = [str(seq), verb]
    for a in args:
        parts.append(str(a))
    body = " ".join(parts).encode()
    return body + ("*%04X\n" % crc16(body)).encode()


def _hexval(b: int) -> int:
    if 0x30 <= b <= 0x39:
        return b - 0x30
    if 0x41 <= b <= 0x46:
        return b - 0x41 + 10
    return -1


def _is_upper_word(s: str, max_len: int) -> bool:
    if not 1 <= len(s) <= max_len:
        return False
    for c in s:
        if not "A" <= c <= "Z":
            return False
    return True


def _parse_seq(s: str) -> int:
    n = len(s)
    if n == 0 or n > 5:
        return -1
    for c in s:
        if not "0" <= c <= "9":
            return -1
    if n > 1 and s[0] == "0":
        return -1
    v = int(s)
    return v if v <= 0xFFFF else -1


def decode(line, max_len: int = MAX_HOST_LINE):
    """Parse one line (bytes/bytearray/str, with or without LF) -> (seq, verb, args).

    Checks in the order of protocol section 1: LONG, framing PARSE, CRC, body PARSE.
    Raises ProtoError.
    """
    if isinstance(line, str):
        line = line.encode()
    n = len(line)
    if n and line[n - 1] == _LF:
        n -= 1
    if n + 1 > max_len:
        raise ProtoError(LONG)
    if n and line[n - 1] == _CR:
        n -= 1
    # framing: printable bytes, "*" and four upper-case hex digits at the end
    if n < 5 or line[n - 5] != _STAR:
        raise ProtoError(PARSE)
    for i in range(n):
        b = line[i]
        if b < 0x20 or b > 0x7E:
            raise ProtoError(PARSE)
    want = 0
    for i in range(n - 4, n):
        h = _hexval(line[i])
        if h < 0:
            raise ProtoError(PARSE)
        want = (want << 4) | h
    body = bytes(line[:n - 5])
    if crc16(body) != want:
        raise ProtoError(CRC)
    parts = body.decode().split(" ")
    if len(parts) < 2:
        raise ProtoError(PARSE)
    seq = _parse_seq(parts[0])
    if seq < 0 or not _is_upper_word(parts[1], 8):
        raise ProtoError(PARSE)
    args = parts[2:]
    for a in args:
        if not a or "*" in a:
            raise ProtoError(PARSE)
    return seq, parts[1], args


# ---------------------------------------------------------------- byte stream reader

_NORMAL = const(0)
_DROP_LONG = const(1)    # overlong: discard to LF, then one LONG error
_DROP_SILENT = const(2)  # e-stop arrived mid-line: discard to LF silently


class LineReader:
    """Splits a byte stream into lines; handles the e-stop byte and overlong lines.

    feed(data) -> list of items, in stream order:
      ("line", bytes)       a complete line, LF stripped (a CR before it is kept)
      ("error", code, name) a framing error of the stream (LONG, empty line PARSE)
      ("estop",)            the e-stop byte; any partial line is dropped to its LF
    """

    def __init__(self, max_len: int = MAX_HOST_LINE) -> None:
        self.max_len = max_len
        self.buf = bytearray()
        self.mode = _NORMAL

    def reset(self) -> None:
        self.buf = bytearray()
        self.mode = _NORMAL

    def feed(self, data) -> list:
        out = []
        limit = self.max_len - 1  # room for the LF
        for b in data:
            if b == ESTOP_BYTE:
                out.append(("estop",))
                if self.buf or self.mode != _NORMAL:
                    self.mode = _DROP_SILENT
                    self.buf = bytearray()
            elif b == _LF:
                self._end_line(out)
            elif self.mode != _NORMAL:
                pass
            elif len(self.buf) >= limit:
                self.mode = _DROP_LONG
                self.buf = bytearray()
            else:
                self.buf.append(b)
        return out

    def _end_line(self, out: list) -> None:
        if self.mode == _DROP_LONG:
            out.append(("error", LONG, "LONG"))
        elif self.mode == _NORMAL:
            if self.buf:
                out.append(("line", bytes(self.buf)))
            else:
                out.append(("error", PARSE, "PARSE"))
        self.buf = bytearray()
        self.mode = _NORMAL


# ---------------------------------------------------------------- command arguments

# Argument kinds: each a (lo, hi) range; "J" stands for a joint index 1..n,
# "Q" for n joint values.
_J = "J"
_Q16 = (0, 0xFFFF)
_GAIN = (0, 1000000)
_JV = (-JOINT_ABS_MAX, JOINT_ABS_MAX)

COMMANDS = {
    "HELLO": ((1, 0xFFFF),),
    "LIM": (_J,),
    "W": (_Q16, (1, 60000), "Q"),
    "HOLD": (),
    "RESUME": (),
    "CLR": (),
    "RATE": ((0, 100),),
    "GAIN": (_J, _GAIN, _GAIN, _GAIN),
    "SETLIM": (_J, _JV, _JV, (1, JOINT_ABS_MAX)),
    "WDOG": ((50, 10000),),
    "STAT": (),
    "PING": (),
}

READ_ONLY = ("STAT", "LIM", "PING")


def _is_int_form(s: str) -> bool:
    """Decimal integer: optional "-", no "+", no leading zeros, no "-0"."""
    if s and s[0] == "-":
        s = s[1:]
        if s == "0":
            return False
    if not s:
        return False
    for c in s:
        if not "0" <= c <= "9":
            return False
    return s == "0" or s[0] != "0"


def _to_int(s: str) -> int:
    # longer than 8 characters is beyond every range (|v| <= 1e6): avoid big ints
    if len(s) > 8:
        return 1 << 28 if s[0] != "-" else -(1 << 28)
    return int(s)


def parse_command(verb: str, args, n_joints: int) -> list:
    """Checks a command's arguments -> list of ints. Raises ProtoError VERB/ARGS/RANGE."""
    spec = COMMANDS.get(verb)
    if spec is None:
        raise ProtoError(VERB)
    ranges: list = []
    for kind in spec:
        if kind == "Q":
            for _ in range(n_joints):
                ranges.append(_JV)
        elif kind == _J:
            ranges.append((1, n_joints))
        else:
            ranges.append(kind)
    if len(args) != len(ranges):
        raise ProtoError(ARGS)
    for a in args:
        if not _is_int_form(a):
            raise ProtoError(ARGS)
    values = []
    for i in range(len(args)):
        v = _to_int(args[i])
        lo, hi = ranges[i]
        if v < lo or v > hi:
            raise ProtoError(RANGE)
        values.append(v)
    if verb == "SETLIM" and values[1] > values[2]:
        raise ProtoError(RANGE)
    return values
