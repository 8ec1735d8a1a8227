"""Writes lines.json, the protocol test vectors shared by every codec.

Every "line" and "bytes" string stands for the bytes of its latin-1 encoding.
Run from the repo root: python tests/vectors/make_vectors.py
The CRC here is the bit-by-bit textbook form, independent of the table-driven
codecs under test. Every case says what it checks; the expected values are
written out by hand, only the CRCs are computed.
"""
import json
import pathlib


def crc16(data: bytes) -> int:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def line(body: str) -> str:
    return f"{body}*{crc16(body.encode('latin-1')):04X}\n"


assert "%04X" % crc16(b"1 PING") != "%04x" % crc16(b"1 PING"), "the lower-case case needs a hex letter"


def bad_crc(body: str) -> str:
    return f"{body}*{(crc16(body.encode()) ^ 0x0001):04X}\n"


crc = [
    {"data": "123456789", "crc": 0x29B1},
    {"data": "", "crc": 0xFFFF},
    {"data": "1 HELLO 4242", "crc": crc16(b"1 HELLO 4242")},
]

good = [
    {"line": line("0 PING"), "seq": 0, "verb": "PING", "args": []},
    {"line": line("1 HELLO 4242"), "seq": 1, "verb": "HELLO", "args": ["4242"]},
    {"line": line("65535 STAT"), "seq": 65535, "verb": "STAT", "args": []},
    {"line": line("5 W 0 500 1571 -1571 0"), "seq": 5, "verb": "W",
     "args": ["0", "500", "1571", "-1571", "0"]},
    {"line": line("7 OK 5 31"), "seq": 7, "verb": "OK", "args": ["5", "31"]},
    {"line": line("8 ER - 2 CRC"), "seq": 8, "verb": "ER", "args": ["-", "2", "CRC"]},
    {"line": line("9 T 10560 RUN - 32 1500 -1500 10 1520 -1520 8 300 -300 20"), "seq": 9,
     "verb": "T", "args": ["10560", "RUN", "-", "32", "1500", "-1500", "10", "1520", "-1520", "8",
                           "300", "-300", "20"]},
    {"line": line("10 BOOT arm3r 0.1.0 1"), "seq": 10, "verb": "BOOT", "args": ["arm3r", "0.1.0", "1"]},
    {"line": line("3 CLR").replace("\n", "\r\n"), "seq": 3, "verb": "CLR", "args": [],
     "why": "a CR before the LF is ignored"},
    {"line": line("4 RATE 50").rstrip("\n"), "seq": 4, "verb": "RATE", "args": ["50"],
     "why": "decode also takes a line without its LF"},
]

w = "12 W 3 500 1 2 3"
bad = [
    {"line": bad_crc("1 HELLO 4242"), "code": 2, "name": "CRC", "why": "one bit of the CRC flipped"},
    {"line": line("1 HELLO 4242").replace("4242", "4243", 1), "code": 2, "name": "CRC", "why": "payload changed"},
    {"line": line("1 hello 4242"), "code": 1, "name": "PARSE", "why": "lower-case verb"},
    {"line": line("1 HELLO 4242")[:-1] + "0\n", "code": 1, "name": "PARSE",
     "why": "CRC field of 5 hex digits"},
    {"line": "1 HELLO 4242\n", "code": 1, "name": "PARSE", "why": "no CRC field"},
    {"line": "1 HELLO 4242*12G4\n", "code": 1, "name": "PARSE", "why": "non-hex CRC"},
    {"line": f"1 PING*{crc16(b'1 PING'):04x}\n", "code": 1, "name": "PARSE",
     "why": "lower-case hex CRC"},
    {"line": line("01 PING"), "code": 1, "name": "PARSE", "why": "leading zero in seq"},
    {"line": line("65536 PING"), "code": 1, "name": "PARSE", "why": "seq out of range"},
    {"line": line("-1 PING"), "code": 1, "name": "PARSE", "why": "negative seq"},
    {"line": line("1  PING"), "code": 1, "name": "PARSE", "why": "double space"},
    {"line": line("1 PING "), "code": 1, "name": "PARSE", "why": "trailing space"},
    {"line": line("1"), "code": 1, "name": "PARSE", "why": "no verb"},
    {"line": line("1 PINGPINGP"), "code": 1, "name": "PARSE", "why": "verb longer than 8"},
    {"line": line("1 PI1NG"), "code": 1, "name": "PARSE", "why": "digit in verb"},
    {"line": line("1 HELLO 42\t42"), "code": 1, "name": "PARSE", "why": "control byte"},
    {"line": line("1 HELLO 42\u00e942"), "code": 1, "name": "PARSE", "why": "non-ASCII byte"},
    {"line": "\n", "code": 1, "name": "PARSE", "why": "empty line"},
    {"line": "*FFFF\n", "code": 1, "name": "PARSE", "why": "empty body"},
    {"line": line("1 W 0 500 " + " ".join(["1000"] * 20)), "code": 3, "name": "LONG",
     "why": "longer than 96 bytes"},
]

# Commands a board validates once the line is well formed, for a 3-joint board.
# Joint-limit checks depend on the board's configuration and are firmware tests.
commands = [
    {"verb": "W", "args": ["3", "500", "1", "2", "3"], "ok": True, "values": [3, 500, 1, 2, 3]},
    {"verb": "W", "args": ["65535", "60000", "-3142", "0", "3142"], "ok": True,
     "values": [65535, 60000, -3142, 0, 3142]},
    {"verb": "W", "args": ["3", "500", "1", "2"], "ok": False, "code": 5, "name": "ARGS", "why": "2 joints for 3"},
    {"verb": "W", "args": ["3", "500", "1", "2", "3", "4"], "ok": False, "code": 5, "name": "ARGS", "why": "4 joints for 3"},
    {"verb": "W", "args": ["3", "500", "1.5", "2", "3"], "ok": False, "code": 5, "name": "ARGS", "why": "fraction"},
    {"verb": "W", "args": ["3", "500", "+1", "2", "3"], "ok": False, "code": 5, "name": "ARGS", "why": "plus sign"},
    {"verb": "W", "args": ["3", "500", "01", "2", "3"], "ok": False, "code": 5, "name": "ARGS", "why": "leading zero"},
    {"verb": "W", "args": ["3", "500", "-0", "2", "3"], "ok": False, "code": 5, "name": "ARGS", "why": "minus zero"},
    {"verb": "W", "args": ["3", "0", "1", "2", "3"], "ok": False, "code": 6, "name": "RANGE", "why": "zero duration"},
    {"verb": "W", "args": ["3", "60001", "1", "2", "3"], "ok": False, "code": 6, "name": "RANGE", "why": "duration too long"},
    {"verb": "W", "args": ["65536", "500", "1", "2", "3"], "ok": False, "code": 6, "name": "RANGE", "why": "id too large"},
    {"verb": "W", "args": ["3", "500", "1000000000", "2", "3"], "ok": False, "code": 6, "name": "RANGE",
     "why": "joint value beyond +-1e6 milli-units"},
    {"verb": "HELLO", "args": ["4242"], "ok": True, "values": [4242]},
    {"verb": "HELLO", "args": ["0"], "ok": False, "code": 6, "name": "RANGE", "why": "session 0 is reserved"},
    {"verb": "HELLO", "args": [], "ok": False, "code": 5, "name": "ARGS", "why": "no session"},
    {"verb": "LIM", "args": ["3"], "ok": True, "values": [3]},
    {"verb": "LIM", "args": ["4"], "ok": False, "code": 6, "name": "RANGE", "why": "joint 4 of 3"},
    {"verb": "LIM", "args": ["0"], "ok": False, "code": 6, "name": "RANGE", "why": "joints count from 1"},
    {"verb": "RATE", "args": ["100"], "ok": True, "values": [100]},
    {"verb": "RATE", "args": ["101"], "ok": False, "code": 6, "name": "RANGE", "why": "above 100 Hz"},
    {"verb": "GAIN", "args": ["1", "2000", "0", "50"], "ok": True, "values": [1, 2000, 0, 50]},
    {"verb": "GAIN", "args": ["1", "-1", "0", "50"], "ok": False, "code": 6, "name": "RANGE", "why": "negative gain"},
    {"verb": "SETLIM", "args": ["2", "-3000", "0", "2000"], "ok": True, "values": [2, -3000, 0, 2000]},
    {"verb": "SETLIM", "args": ["2", "0", "-3000", "2000"], "ok": False, "code": 6, "name": "RANGE", "why": "min above max"},
    {"verb": "SETLIM", "args": ["2", "-3000", "0", "0"], "ok": False, "code": 6, "name": "RANGE", "why": "zero speed"},
    {"verb": "WDOG", "args": ["49"], "ok": False, "code": 6, "name": "RANGE", "why": "below 50 ms"},
    {"verb": "WDOG", "args": ["500"], "ok": True, "values": [500]},
    {"verb": "HOLD", "args": [], "ok": True, "values": []},
    {"verb": "HOLD", "args": ["1"], "ok": False, "code": 5, "name": "ARGS", "why": "HOLD takes nothing"},
    {"verb": "RESUME", "args": [], "ok": True, "values": []},
    {"verb": "CLR", "args": [], "ok": True, "values": []},
    {"verb": "STAT", "args": [], "ok": True, "values": []},
    {"verb": "PING", "args": [], "ok": True, "values": []},
    {"verb": "JUMP", "args": [], "ok": False, "code": 4, "name": "VERB", "why": "unknown verb"},
    {"verb": "OK", "args": ["1", "2"], "ok": False, "code": 4, "name": "VERB", "why": "a reply is no command"},
]

# Byte streams as a board's receiver sees them: what comes out, in order.
# "line" items are complete lines (LF stripped), "error" items framing errors,
# "estop" the out-of-band byte. Bytes are given as latin-1 text.
p1, p2 = line("1 PING"), line("2 STAT")
streams = [
    {"bytes": p1 + p2, "out": [["line", p1[:-1]], ["line", p2[:-1]]], "why": "two lines"},
    {"bytes": p1[:4] + "\x98" + p1[4:] + p2, "out": [["estop"], ["line", p2[:-1]]],
     "why": "e-stop mid-line acts at once; the rest of that line is dropped silently"},
    {"bytes": p1 + "\x98" + p2, "out": [["line", p1[:-1]], ["estop"], ["line", p2[:-1]]],
     "why": "e-stop between lines drops nothing"},
    {"bytes": "\x98", "out": [["estop"]], "why": "e-stop alone"},
    {"bytes": "x" * 200 + "\n" + p2, "out": [["error", 3, "LONG"], ["line", p2[:-1]]],
     "why": "overlong line discarded up to its LF, one error"},
    {"bytes": p1[:-1], "out": [], "why": "no LF yet: nothing"},
    {"bytes": "\n\n" + p2, "out": [["error", 1, "PARSE"], ["error", 1, "PARSE"], ["line", p2[:-1]]],
     "why": "empty lines are errors"},
]

out = {"version": 1, "max_command_line": 96, "max_board_line": 192, "estop_byte": 0x98,
       "crc": crc, "good": good, "bad": bad, "commands": commands, "command_joints": 3,
       "streams": streams}
path = pathlib.Path(__file__).with_name("lines.json")
path.write_text(json.dumps(out, indent=1, ensure_ascii=True) + "\n")
print(f"wrote {path}")
