"""Writes lines.json, the protocol v2 test vectors shared by every codec.

Run from the repo root: python tests/vectors/make_vectors.py

Every "line" and "bytes" string stands for the bytes of its latin-1 encoding.
The vectors are the spec's statement, kept apart from the codecs on purpose:
the CRC here is the bit-by-bit textbook CRC-32 (not zlib/binascii, which the
codecs use), and the argument ranges below are written out from
docs/protocol.md §3 by hand, not read from link/protodef.py, so a wrong range
in the one table fails the vectors instead of being copied into them.
"""
import json
import pathlib

N = 3  # joints of the board the command vectors are checked for


def crc32(data: bytes, epoch: int = 0) -> int:
    """CRC-32/ISO-HDLC (reflected poly 0xEDB88320, init and final XOR 0xFFFFFFFF),
    continued from `epoch` as zlib.crc32(data, epoch) is."""
    crc = epoch ^ 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0xEDB88320 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


assert crc32(b"123456789") == 0xCBF43926


def framed(body: str, epoch: int = 0) -> str:
    """The line with the CRC from `epoch` (no HELLO rule: the caller says which)."""
    return f"{body}*{crc32(body.encode('latin-1'), epoch):08X}\n"


def line(body: str, epoch: int = 0) -> str:
    """A line as a correct sender frames it: HELLO always from epoch 0."""
    return framed(body, 0 if body.split(" ")[1:2] == ["HELLO"] else epoch)


def bad_crc(body: str) -> str:
    return f"{body}*{crc32(body.encode()) ^ 1:08X}\n"


E = 1234567  # an epoch for the seeded cases
crc = [
    {"data": "123456789", "epoch": 0, "crc": 0xCBF43926, "why": "the CRC-32 check value"},
    {"data": "", "epoch": 0, "crc": 0},
    {"data": "", "epoch": 5, "crc": 5, "why": "no data: the seed itself"},
    {"data": "123456789", "epoch": 1, "crc": crc32(b"123456789", 1)},
    {"data": "123456789", "epoch": 1073741823, "crc": crc32(b"123456789", 1073741823),
     "why": "the largest epoch"},
    {"data": "5 W 0 500 1571 -1571 0", "epoch": E, "crc": crc32(b"5 W 0 500 1571 -1571 0", E)},
    {"data": "1 HELLO 2 4242 1", "epoch": 0, "crc": crc32(b"1 HELLO 2 4242 1")},
]
assert crc[3]["crc"] != crc[0]["crc"], "the seed must change the CRC"

# decode(line, max_len, epoch) -> (seq, verb, args); max_len is the board bound
# (192) unless "max_len" says otherwise.
good = [
    {"line": line("0 PING"), "epoch": 0, "seq": 0, "verb": "PING", "args": []},
    {"line": line("1 HELLO 2 4242 1"), "epoch": 0, "seq": 1, "verb": "HELLO", "args": ["2", "4242", "1"]},
    {"line": line("1 HELLO 2 4242 8"), "epoch": 7, "seq": 1, "verb": "HELLO", "args": ["2", "4242", "8"],
     "why": "a HELLO is framed with epoch 0 whatever the receiver's epoch"},
    {"line": line("9 HELLO"), "epoch": 7, "seq": 9, "verb": "HELLO", "args": [],
     "why": "HELLO without arguments: still epoch 0 (parse_command refuses it later)"},
    {"line": line("65535 STAT", 1), "epoch": 1, "seq": 65535, "verb": "STAT", "args": []},
    {"line": line("5 W 0 500 1571 -1571 0", E), "epoch": E, "seq": 5, "verb": "W",
     "args": ["0", "500", "1571", "-1571", "0"]},
    {"line": line("6 PING", 1073741823), "epoch": 1073741823, "seq": 6, "verb": "PING", "args": [],
     "why": "the largest epoch"},
    {"line": line("2 HELLOX 1", 3), "epoch": 3, "seq": 2, "verb": "HELLOX", "args": ["1"],
     "why": "only the verb HELLO itself uses epoch 0"},
    {"line": line("7 OK 5 31"), "epoch": 0, "seq": 7, "verb": "OK", "args": ["5", "31"]},
    {"line": line("8 ER - 2 CRC"), "epoch": 0, "seq": 8, "verb": "ER", "args": ["-", "2", "CRC"]},
    {"line": line("9 T 10560 RUN - 32 1500 -1500 10 1520 -1520 8 300 -300 20"), "epoch": 0, "seq": 9,
     "verb": "T", "args": ["10560", "RUN", "-", "32", "1500", "-1500", "10", "1520", "-1520", "8",
                           "300", "-300", "20"]},
    {"line": line("10 BOOT arm3r 0.2.0 2 ESTOP"), "epoch": 0, "seq": 10, "verb": "BOOT",
     "args": ["arm3r", "0.2.0", "2", "ESTOP"]},
    {"line": line("3 CLR", 9).replace("\n", "\r\n"), "epoch": 9, "seq": 3, "verb": "CLR", "args": [],
     "why": "a CR before the LF is ignored"},
    {"line": line("4 RATE 50", 9).rstrip("\n"), "epoch": 9, "seq": 4, "verb": "RATE", "args": ["50"],
     "why": "decode also takes a line without its LF"},
]

# decode(line, 96, epoch) raises (code, name).
w = "12 W 3 500 1 2 3"
bad = [
    {"line": bad_crc("1 HELLO 2 4242 1"), "epoch": 0, "code": 2, "name": "CRC",
     "why": "one bit of the CRC flipped"},
    {"line": line("1 HELLO 2 4242 1").replace("4242", "4243", 1), "epoch": 0, "code": 2, "name": "CRC",
     "why": "payload changed"},
    {"line": line(w, 4), "epoch": 5, "code": 2, "name": "CRC",
     "why": "framed with an earlier epoch: a late copy from before a resync"},
    {"line": line(w, 0), "epoch": 5, "code": 2, "name": "CRC", "why": "framed with epoch 0 but not a HELLO"},
    {"line": line(w, 5), "epoch": 0, "code": 2, "name": "CRC", "why": "framed with an epoch the receiver has not"},
    {"line": framed("1 HELLO 2 4242 6", 5), "epoch": 5, "code": 2, "name": "CRC",
     "why": "a HELLO framed with the epoch instead of 0"},
    {"line": framed("1  HELLO 2 4242 6", 0), "epoch": 5, "code": 2, "name": "CRC",
     "why": "a double space: the second field is not HELLO, so the epoch applies (then PARSE)"},
    {"line": framed("1  HELLO 2 4242 6", 5), "epoch": 5, "code": 1, "name": "PARSE",
     "why": "double space, CRC right for the epoch: grammar"},
    {"line": line("1 hello 2 4242 1"), "epoch": 0, "code": 1, "name": "PARSE", "why": "lower-case verb"},
    {"line": line("1 PING")[:-1] + "0\n", "epoch": 0, "code": 1, "name": "PARSE", "why": "CRC field of 9 hex digits"},
    {"line": "1 PING*%04X\n" % (crc32(b"1 PING") & 0xFFFF), "epoch": 0, "code": 1, "name": "PARSE",
     "why": "a 4-digit CRC (a v1 line)"},
    {"line": "1 PING\n", "epoch": 0, "code": 1, "name": "PARSE", "why": "no CRC field"},
    {"line": "1 PING*12G45678\n", "epoch": 0, "code": 1, "name": "PARSE", "why": "non-hex CRC"},
    {"line": "1 PING*%08x\n" % crc32(b"1 PING"), "epoch": 0, "code": 1, "name": "PARSE",
     "why": "lower-case hex CRC"},
    {"line": "1 PING*+%07X\n" % (crc32(b"1 PING") & 0xFFFFFFF), "epoch": 0, "code": 1, "name": "PARSE",
     "why": "a sign in the CRC field"},
    {"line": "107 PING*-2363E02\n", "epoch": 0, "code": 1, "name": "PARSE",
     "why": "a minus sign in the CRC field: framing (PARSE), checked before the CRC (issue 21)"},
    {"line": "1 PING*-%07X\n" % ((1 << 32) - crc32(b"1 PING", 12)), "epoch": 12, "code": 1, "name": "PARSE",
     "why": "a minus sign whose 32-bit two's complement is the right CRC (from epoch 12): still PARSE"},
    {"line": line("01 PING"), "epoch": 0, "code": 1, "name": "PARSE", "why": "leading zero in seq"},
    {"line": line("65536 PING"), "epoch": 0, "code": 1, "name": "PARSE", "why": "seq out of range"},
    {"line": line("-1 PING"), "epoch": 0, "code": 1, "name": "PARSE", "why": "negative seq"},
    {"line": line("1 PING "), "epoch": 0, "code": 1, "name": "PARSE", "why": "trailing space"},
    {"line": line("1"), "epoch": 0, "code": 1, "name": "PARSE", "why": "no verb"},
    {"line": line("1 PINGPINGP"), "epoch": 0, "code": 1, "name": "PARSE", "why": "verb longer than 8"},
    {"line": line("1 PI1NG"), "epoch": 0, "code": 1, "name": "PARSE", "why": "digit in verb"},
    {"line": line("1 RATE 4\t2"), "epoch": 0, "code": 1, "name": "PARSE", "why": "control byte"},
    {"line": line("1 RATE 4\u00e92"), "epoch": 0, "code": 1, "name": "PARSE", "why": "non-ASCII byte"},
    {"line": "1 PING*%08X\u00e9\n" % crc32(b"1 PING"), "epoch": 0, "code": 1, "name": "PARSE",
     "why": "non-ASCII byte after the CRC"},
    {"line": "\n", "epoch": 0, "code": 1, "name": "PARSE", "why": "empty line"},
    {"line": "*00000000\n", "epoch": 0, "code": 1, "name": "PARSE", "why": "empty body (CRC of nothing is 0)"},
    {"line": line("1 W 0 500 " + " ".join(["1000"] * 20)), "epoch": 0, "code": 3, "name": "LONG",
     "why": "longer than 96 bytes"},
]


# ---------------------------------------------------------------- command arguments
# parse_command(verb, args, n) -> values, or raises the error named. Ranges as
# docs/protocol.md §3 states them ("joint" is 1..n, "q" n joint values).
SPEC = {
    "HELLO": [("proto", 1, 65535), ("session", 1, 65535), ("epoch", 1, 2 ** 30 - 1)],
    "LIM": [("joint", 1, None)],
    "W": [("id", 0, 65535), ("dur", 1, 60000), ("q", -1000000, 1000000)],
    "HOLD": [], "RESUME": [], "CLR": [],
    "RATE": [("hz", 0, 100)],
    "GAIN": [("joint", 1, None), ("kp", 0, 1000000), ("ki", 0, 1000000), ("kd", 0, 1000000)],
    "SETLIM": [("joint", 1, None), ("min", -1000000, 1000000), ("max", -1000000, 1000000),
               ("vmax", 1, 1000000)],
    "WDOG": [("ms", 50, 10000)],
    "STAT": [], "PING": [],
    "X": [("id", 0, 65535), ("dur", 1, 60000), ("x", -1000000, 1000000), ("y", -1000000, 1000000),
          ("theta", -10000, 10000)],
    "XY": [("id", 0, 65535), ("dur", 1, 60000), ("x", -1000000, 1000000), ("y", -1000000, 1000000)],
    "PEN": [("down", 0, 1)],
    "PENPOS": [("up_us", 500, 2500), ("down_us", 500, 2500), ("settle_ms", 0, 2000)],
    "CAL": [("joint", 1, None), ("us_a", 500, 2500), ("a", -1000000, 1000000), ("us_b", 500, 2500),
            ("b", -1000000, 1000000)],
    "MV": [("id", 0, 65535), ("d", 0, 1000000)],
    "ROT": [("id", 0, 65535), ("joint", 1, None), ("angle", -1000000, 1000000)],
    "GRIP": [("id", 0, 65535), ("open", 0, 1)],
    "HOME": [("id", 0, 65535)],
    "END": [("id", 0, 65535)],
    "DBAND": [("joint", 1, None), ("mrad", 0, 1000)],
    "BEND": [("joint", 1, None), ("adc_a", 0, 1023), ("a", -1000000, 1000000), ("adc_b", 0, 1023),
             ("b", -1000000, 1000000)],
    "MODBUS": [("addr", 1, 247)],
    "IDENT": [],
    "CALID": [("id", 1, 2 ** 30 - 1)],
    "RELAY": [("joint", 1, None), ("amp", 1, 1000), ("hyst", 0, 1000), ("cycles", 1, 50)],
    "MAG": [("joint", 1, None), ("pos", 0, 1000000), ("win", 0, 10000)],
    "WHEEL": [("nm", 1, 1000000)],
}
# value i <= value j, else RANGE (docs/protocol.md §3: SETLIM's min <= max, CAL's us_a <= us_b)
ORDER = {"SETLIM": (1, 2), "CAL": (1, 3), "BEND": (1, 3)}
# A valid value for each argument (SETLIM's min/max and CAL's pulses must stay ordered).
TYPICAL = {"proto": 2, "session": 4242, "epoch": 1, "joint": 2, "id": 7, "dur": 500, "q": 0,
           "hz": 25, "kp": 2000, "ki": 0, "kd": 50, "min": -3000, "max": 3000, "vmax": 2000, "ms": 1000,
           "x": 76000, "y": 190000, "theta": 0, "down": 1, "us_a": 1000, "a": -785, "us_b": 2000, "b": 2356,
           "d": 400, "angle": -453, "open": 1, "mrad": 35, "adc_a": 100, "adc_b": 900, "addr": 1,
           "amp": 300, "hyst": 5, "cycles": 4, "pos": 120000, "win": 1500, "nm": 16000,
           "up_us": 1200, "down_us": 1700, "settle_ms": 150}


def expanded(verb: str, n: int) -> list:
    """[(name, lo, hi)] with "q" as n values and "joint" bounded by n."""
    out = []
    for name, lo, hi in SPEC[verb]:
        if name == "q":
            out += [(f"q{j}", lo, hi) for j in range(1, n + 1)]
        else:
            out.append((name, lo, n if hi is None else hi))
    return out


def typical(verb: str, n: int) -> list:
    return [min(2, n) if name == "joint" else TYPICAL["q" if name.startswith("q") else name]
            for name, _, _ in expanded(verb, n)]


commands = []


def case(verb, values_or_args, n=N, error=None, why="", values=None):
    args = [str(v) for v in values_or_args]
    if error is None and values is None:
        values = [int(a) for a in args]
    commands.append({"verb": verb, "args": args, "n": n, "error": error,
                     "values": values if error is None else None, "why": why})


for verb in SPEC:
    for n in (N, 1, 6) if any(name in ("q", "joint") for name, _, _ in SPEC[verb]) else (N,):
        base = typical(verb, n)
        case(verb, base, n, why="typical values")
        case(verb, base + [1], n, "ARGS", "one argument too many")
        if base:
            case(verb, base[:-1], n, "ARGS", "one argument too few")
        for i, (name, lo, hi) in enumerate(expanded(verb, n)):
            for value, error, what in ((lo, None, "lower bound"), (hi, None, "upper bound"),
                                       (lo - 1, "RANGE", "below the lower bound"),
                                       (hi + 1, "RANGE", "above the upper bound")):
                args = list(base)
                args[i] = value
                if verb in ORDER and error is None and args[ORDER[verb][0]] > args[ORDER[verb][1]]:
                    error, what = "RANGE", what + ", so out of order"
                case(verb, args, n, error, f"{name} {what} ({value})")
    base = typical(verb, N)
    if base:
        for form in ("+1", "01", "-0", "1.5", "", "-", "1e3", "0x1", "1_0", "--1", " 1", "\u0661"):
            args = [str(v) for v in base]
            args[-1] = form
            case(verb, args, N, "ARGS", f"last argument {form!r} is not an integer")
        args = [str(v) for v in base]
        args[0] = "01"
        case(verb, args, N, "ARGS", "first argument not an integer")
        if len(base) > 1:
            args = [str(v) for v in base]
            args[0], args[1] = "99999999", "+1"
            case(verb, args, N, "ARGS", "every form is checked before any range")
            args = [str(v) for v in base]
            args[0] = "9" * 40
            case(verb, args, N, "RANGE", "a 40-digit number is out of range, not an error of form")

case("SETLIM", [2, 500, 500, 100], why="min == max: a locked joint")
case("SETLIM", [2, 501, 500, 100], error="RANGE", why="min above max")
case("SETLIM", [2, -1000000, 1000000, 1000000], why="the widest range")
case("SETLIM", [2, 1000000, -1000000, 1], error="RANGE", why="min above max at the extremes")
case("SETLIM", [2, 501, 500, 0], error="RANGE", why="vmax out of range and min above max")
case("CAL", [1, 1500, 0, 1500, 1000], why="us_a == us_b passes the codec (the board refuses it)")
case("CAL", [1, 2000, 0, 1000, 1000], error="RANGE", why="us_a above us_b")
case("X", [0, 1, -1000000, 1000000, -10000], why="Cartesian values at their bounds")
case("HELLO", [3, 4242, 1], why="another proto passes parse_command; the session answers PROTO")
case("HELLO", [2, 4242, 2 ** 30], error="RANGE", why="epoch beyond 2^30-1 (a MicroPython small int)")
case("W", [0, 1, 1000000, -1000000, 0], why="joint values at both bounds")
case("LIM", [1], n=0, error="RANGE", why="a board with no joints has no joint 1")
case("W", [0, 1], n=0, why="a board with no joints: W is id and duration")
for verb in ("JUMP", "OK", "ER", "hello", "", "W2"):
    case(verb, [], error="VERB", why="not a command verb")

# Byte streams as a board's receiver sees them: what comes out, in order.
# "line" items are complete lines (LF stripped), "error" items framing errors,
# "estop" the out-of-band byte. Bytes are given as latin-1 text.
p1, p2 = line("1 PING", 1), line("2 STAT", 1)
streams = [
    {"bytes": p1 + p2, "out": [["line", p1[:-1]], ["line", p2[:-1]]], "why": "two lines"},
    {"bytes": p1[:4] + "\x98" + p1[4:] + p2, "out": [["estop"], ["line", p2[:-1]]],
     "why": "e-stop mid-line acts at once; the rest of that line is dropped silently"},
    {"bytes": p1 + "\x98" + p2, "out": [["line", p1[:-1]], ["estop"], ["line", p2[:-1]]],
     "why": "e-stop between lines drops nothing"},
    {"bytes": "\x98", "out": [["estop"]], "why": "e-stop alone"},
    {"bytes": "\x98\x98" + p2, "out": [["estop"], ["estop"], ["line", p2[:-1]]], "why": "two e-stops"},
    {"bytes": "x" * 200 + "\n" + p2, "out": [["error", 3, "LONG"], ["line", p2[:-1]]],
     "why": "overlong line discarded up to its LF, one error"},
    {"bytes": "x" * 95 + "\n" + "y" * 96 + "\n", "out": [["line", "x" * 95], ["error", 3, "LONG"]],
     "why": "95 bytes and the LF fit in 96; 96 and the LF do not"},
    {"bytes": "x" * 150 + "\x98" + "yy\n" + p2, "out": [["estop"], ["line", p2[:-1]]],
     "why": "e-stop during an overlong line: no LONG error, the rest dropped silently"},
    {"bytes": p1[:-1], "out": [], "why": "no LF yet: nothing"},
    {"bytes": "\n\n" + p2, "out": [["error", 1, "PARSE"], ["error", 1, "PARSE"], ["line", p2[:-1]]],
     "why": "empty lines are errors"},
]

# docs/protocol.md §12, the example session, with real CRCs: [side, line, the
# epoch its receiver checks it with]. A second host process then connects with
# a new session: its first HELLO's epoch (1) is not newer than the board's, the
# board answers STALE with its epoch, the host retries at once with epoch 2.
example = [
    ["host", line("1 HELLO 2 4242 1"), 1],
    ["board", line("1 OK 1 32 arm3r 0.2.0 2 3 32 25 1000 - - IDLE"), 0],
    ["host", line("2 LIM 1", 1), 1],
    ["board", line("2 OK 2 32 1 -3142 3142 3000"), 0],
    ["host", line("3 LIM 2", 1), 1],
    ["board", line("3 OK 3 32 2 -2618 2618 3000"), 0],
    ["host", line("4 LIM 3", 1), 1],
    ["board", line("4 OK 4 32 3 -2618 2618 3000"), 0],
    ["host", line("5 W 0 500 1571 -1571 0", 1), 1],
    ["board", line("5 OK 5 31"), 0],
    ["board", line("6 EV 10532 START 0"), 0],
    ["board", line("7 T 10560 RUN - 32 1500 -1500 10 1520 -1520 8 300 -300 20"), 0],
    ["board", line("8 EV 11032 DONE 0 32"), 0],
    ["host", line("1 HELLO 2 777 1"), 2],
    ["board", line("9 ER 1 11 STALE 1"), 0],
    ["host", line("2 HELLO 2 777 2"), 2],
    ["board", line("10 OK 2 32 arm3r 0.2.0 2 3 32 25 1000 - - IDLE"), 0],
    ["host", line("3 PING", 2), 2],
    ["board", line("11 OK 3 32 12007"), 0],
]

out = {"version": 2, "max_host_line": 96, "max_board_line": 192, "estop_byte": 0x98,
       "crc": crc, "good": good, "bad": bad, "commands": commands, "streams": streams,
       "example": example}
path = pathlib.Path(__file__).with_name("lines.json")
path.write_text(json.dumps(out, indent=1, ensure_ascii=True) + "\n")
print(f"wrote {path}: {len(good)} good, {len(bad)} bad lines, {len(commands)} command cases")
