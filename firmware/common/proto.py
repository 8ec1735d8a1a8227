"""Line protocol codec, version 2 (docs/protocol.md), for MicroPython and CPython.

encode, decode (length, framing, CRC-32 seeded by the link epoch, grammar),
LineReader (framing and the out-of-band e-stop byte) and parse_command (argument
checks of the host -> board commands). Verbs, ranges, codes and constants come
from the one table, `protodef` (generated from host/armbridge/link/protodef.py).
Pure: no I/O. The work per line stays in C builtins (binascii.crc32, min/max,
bytes.find/split, int); Python loops run only over the 8 hex digits and the
arguments.
"""

import binascii

import protodef
from protodef import (  # noqa: F401  (re-exported: the names the session layer uses)
    ARGS, CRC, ERROR_NAMES, ESTOP_BYTE, FULL, LATCHED, LONG, MAX_BOARD_LINE, MAX_HOST_LINE,
    NOSESSION, PARSE, PROTO, PROTOCOL_VERSION, RANGE, READ_ONLY, SEQ, STALE, VERB,
)

try:
    from micropython import const
except ImportError:  # CPython (emulator, tests)
    def const(x):  # type: ignore[no-redef,misc]
        return x

COMMANDS = protodef.COMMANDS
_HELLO_EPOCH = const(0)
_LF = const(0x0A)
_CR = const(0x0D)
_STAR = const(0x2A)


class ProtocolError(Exception):
    """A refused line or command: `code` (int), `name` (str), optional `detail`."""

    def __init__(self, code: int, name: str = "", detail: str = "") -> None:
        if not name:
            name = ERROR_NAMES.get(code, "ERR")
        super().__init__(code, name)
        self.code = code
        self.name = name
        self.detail = detail


def crc32(data, epoch: int = 0) -> int:
    """CRC-32/ISO-HDLC of bytes/bytearray, started from the link epoch."""
    return binascii.crc32(data, epoch)


def is_hello(body) -> bool:
    """True when the body's second field is HELLO: its CRC uses epoch 0."""
    sp = body.find(b" ")
    return sp >= 0 and body[sp + 1:sp + 7] in (b"HELLO", b"HELLO ")


# ---------------------------------------------------------------- encode / decode

def encode(seq, verb: str, args=(), epoch: int = 0) -> bytes:
    """One line `seq verb args*CRC\\n`; args may be ints or strings. The CRC
    starts from `epoch`, except for HELLO (always epoch 0)."""
    parts = [str(seq), verb]
    for a in args:
        parts.append(str(a))
    body = " ".join(parts).encode()
    if verb == "HELLO":
        epoch = _HELLO_EPOCH
    return body + ("*%08X\n" % binascii.crc32(body, epoch)).encode()


def _canonical_int(s: str, base: int = 10):
    """int(s) when s is exactly how the protocol writes that number (decimal:
    no "+", no leading zeros, no "-0", no spaces or "_"; hex: 8 upper-case
    digits, no sign: "-2363E02" is PARSE, docs/protocol.md section 1), else
    None. The round trip through C's int() and str() replaces a Python loop
    over the characters (the hot path of every line)."""
    try:
        v = int(s, base)
    except ValueError:
        return None
    if base == 16:
        return v if v >= 0 and "%08X" % v == s else None
    return v if str(v) == s else None


def _parse_seq(s: str) -> int:
    v = _canonical_int(s) if len(s) <= 5 else None
    return v if v is not None and 0 <= v <= 0xFFFF else -1


def _is_upper_word(s: str) -> bool:
    return 1 <= len(s) <= 8 and s.isalpha() and s.isupper()


def decode(line, max_len: int = MAX_HOST_LINE, epoch: int = 0):
    """Parse one line (bytes/bytearray/str, with or without LF) -> (seq, verb, args).

    Checks in the order of protocol section 1: LONG, framing PARSE, CRC (from
    `epoch`, or 0 for a HELLO body), body PARSE. Raises ProtocolError.
    """
    if isinstance(line, str):
        line = line.encode()
    n = len(line)
    if n and line[n - 1] == _LF:
        n -= 1
    if n + 1 > max_len:
        raise ProtocolError(LONG)
    if n and line[n - 1] == _CR:
        n -= 1
    # framing: printable bytes, "*" and eight upper-case hex digits at the end
    if n < 9 or line[n - 9] != _STAR:
        raise ProtocolError(PARSE)
    data = bytes(line[:n])
    if min(data) < 0x20 or max(data) > 0x7E:
        raise ProtocolError(PARSE)
    body = data[:n - 9]
    want = _canonical_int(data[n - 8:].decode(), 16)
    if want is None:
        raise ProtocolError(PARSE)
    if is_hello(body):
        epoch = _HELLO_EPOCH
    if binascii.crc32(body, epoch) != want:
        raise ProtocolError(CRC)
    parts = body.decode().split(" ")
    if len(parts) < 2:
        raise ProtocolError(PARSE)
    seq = _parse_seq(parts[0])
    if seq < 0 or not _is_upper_word(parts[1]):
        raise ProtocolError(PARSE)
    args = parts[2:]
    for a in args:
        if not a or "*" in a:
            raise ProtocolError(PARSE)
    return seq, parts[1], args


# ---------------------------------------------------------------- byte stream reader

_NORMAL = const(0)
_DROP_LONG = const(1)    # overlong: discard to LF, then one LONG error
_DROP_SILENT = const(2)  # e-stop arrived mid-line: discard to LF silently
_ESTOP = bytes([ESTOP_BYTE])


class LineReader:
    """Splits a byte stream into lines; handles the e-stop byte and overlong lines.

    feed(data) -> list of items, in stream order:
      ("line", bytes)       a complete line, LF stripped (a CR before it is kept)
      ("error", code, name) a framing error of the stream (LONG, empty line PARSE)
      ("estop",)            the e-stop byte; any partial line is dropped to its LF
    The data is cut at LF and e-stop bytes with bytes.find, not byte by byte.
    """

    def __init__(self, max_len: int = MAX_HOST_LINE) -> None:
        self.max_len = max_len
        self.buf = bytearray()
        self.mode = _NORMAL

    def reset(self) -> None:
        self.buf = bytearray()
        self.mode = _NORMAL

    def feed(self, data) -> list:
        out: list = []
        data = bytes(data)
        i = 0
        end = len(data)
        stop = data.find(_ESTOP)
        while i < end:
            lf = data.find(b"\n", i)
            if 0 <= stop < i:
                stop = data.find(_ESTOP, i)
            cut = lf if stop < 0 or (0 <= lf < stop) else stop
            self._take(data[i:end if cut < 0 else cut])
            if cut < 0:
                break
            if cut == stop:
                out.append(("estop",))
                if self.buf or self.mode != _NORMAL:
                    self.mode = _DROP_SILENT
                    self.buf = bytearray()
            else:
                self._end_line(out)
            i = cut + 1
        return out

    def _take(self, piece) -> None:
        if self.mode != _NORMAL or not piece:
            return
        if len(self.buf) + len(piece) > self.max_len - 1:  # no room left for the LF
            self.mode = _DROP_LONG
            self.buf = bytearray()
        else:
            self.buf.extend(piece)

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

def _ranges(verb: str, n_joints: int) -> list:
    """[(name, lo, hi)] of verb's arguments for an n-joint board: "q" expanded
    to n joint values, "joint" bounded by n."""
    out = []
    for spec in COMMANDS[verb]:
        name = spec[0]
        if name == "q":
            for _ in range(n_joints):
                out.append(spec)
        elif name == "joint":
            out.append((name, 1, n_joints))
        else:
            out.append(spec)
    return out


def parse_command(verb: str, args, n_joints: int) -> list:
    """Checks a command's arguments -> list of ints, in the spec's order: verb
    (VERB), count (ARGS), every argument's form (ARGS), each range in turn
    (RANGE), the cross-argument rules (RANGE). Raises ProtocolError."""
    if verb not in COMMANDS:
        raise ProtocolError(VERB)
    ranges = _ranges(verb, n_joints)
    if len(args) != len(ranges):
        raise ProtocolError(ARGS)
    values = []
    for a in args:
        v = _canonical_int(a)
        if v is None:
            raise ProtocolError(ARGS)
        values.append(v)
    for i in range(len(values)):
        spec = ranges[i]
        if values[i] < spec[1] or values[i] > spec[2]:
            raise ProtocolError(RANGE, "", _arg_name(verb, i))
    rules = protodef.ORDERED.get(verb)
    if rules:
        for low, high in rules:
            a = _index(ranges, low)
            b = _index(ranges, high)
            if values[a] > values[b]:
                raise ProtocolError(RANGE, "", low)
    return values


def _arg_name(verb: str, i: int) -> str:
    """The detail of a RANGE error: the joint number of a joint value, else
    the argument's name."""
    spec = COMMANDS[verb]
    if i >= len(spec) - 1 and spec[-1][0] == "q":
        return str(i - len(spec) + 2)
    return spec[i][0]


def _index(ranges: list, name: str) -> int:
    for i in range(len(ranges)):
        if ranges[i][0] == name:
            return i
    return -1
