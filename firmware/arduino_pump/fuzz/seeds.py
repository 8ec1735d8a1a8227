"""Seed inputs for the fuzz targets, from the shared protocol vectors
(tests/vectors/lines.json) and a few hand-made sessions and Modbus frames.

  usage: python3 seeds.py lines.json OUTDIR      -> OUTDIR/<target>/<name> files

The layouts are the targets' (their header comments): codec = 4-byte epoch (LE),
a flags byte (bit 0 board line, bits 1..3 joints), the line; session = 8-byte
operations; modbus = flags byte, then (gap/16us, byte) pairs; board = a mode byte
(0 raw bytes, 1 CRC-framed line bodies split at LF, 2 one Modbus frame), the rest.
tests/fuzz_codecs.py reads the codec and session layouts too.
"""
import json
import os
import struct
import sys
import zlib

HELLO_EPOCH = 0


def latin1(s: str) -> bytes:
    return bytes(ord(c) for c in s)


def encode(seq: int, verb: str, args, epoch: int) -> bytes:
    body = " ".join([str(seq), verb] + [str(a) for a in args]).encode("utf-8", "surrogatepass")
    crc = zlib.crc32(body, HELLO_EPOCH if verb == "HELLO" else epoch)
    return body + b"*%08X\n" % crc


def codec_input(line: bytes, epoch: int, board: bool = False, joints: int = 3) -> bytes:
    return struct.pack("<I", epoch & 0x3FFFFFFF) + bytes([(1 if board else 0) | (joints & 7) << 1]) + line


def codec_seeds(v: dict) -> list:
    out = []
    for c in v["good"]:
        out.append(codec_input(latin1(c["line"]), c["epoch"]))
    for c in v["bad"]:
        out.append(codec_input(latin1(c["line"]), c["epoch"]))
    for c in v["streams"]:
        out.append(codec_input(latin1(c["bytes"]), 0))
    for side, text, epoch in v["example"]:
        out.append(codec_input(latin1(text), epoch, board=side == "board"))
    for c in v["commands"]:   # every argument check, through a line that decodes
        out.append(codec_input(encode(1, c["verb"], c["args"], 7), 7, joints=c["n"]))
    for verb, args in BOARD_LINES:   # each kind of board line, for the host's parse_board_line
        for joints in (0, 3):
            out.append(codec_input(encode(9, verb, args, 0), 0, board=True, joints=joints))
    return out


BOARD_LINES = [("OK", [7, 31]), ("OK", [8, 30, "arm3r", "0.2.0"]), ("ER", [7, 7, "SEQ", 8]), ("ER", ["-", 1, "PARSE"]),
               ("T", [1234, "RUN", 5, 31, 100, 200, 300, 110, 210, 310, 5, -5, 0]),
               ("T", [1234, "IDLE", "-", 32, 1, 2, 3, 1, 2, 3, 0, 0, 0, 17, -3]),
               ("EV", [1234, "DONE", 5]), ("EV", [99, "LATCH", "FOLLOW:2"]), ("BOOT", ["arduino_pump", "0.2.0", 2, "IDLE"])]


# ------------------------------------------------------------------ sessions
HELLO, READ, WRITE, RESET = 0, 1, 2, 3


def op(kind: int, seq: int = 0, sid: int = 4242, depoch: int = 1, proto: int = 2, code: int = 0,
       rel: bool = False) -> bytes:
    b0 = kind | (0x80 if rel else 0) | (0x40 if proto == 2 else 0)
    return struct.pack("<BHHbBB", b0, seq & 0xFFFF if not rel else (seq & 0xFF), sid, depoch, proto & 0xFF, code)


def session_seeds() -> list:
    opened = op(HELLO, 1)
    return [
        opened + op(WRITE, 0, rel=True) * 3 + op(WRITE, -1, rel=True) + op(READ, -2, rel=True)
        + op(WRITE, 5, rel=True) + op(WRITE, -40, rel=True),                     # EXEC, REPLAY, FRESH, SEQERR
        opened + op(HELLO, 1, depoch=0) + op(HELLO, 2, depoch=0) + op(HELLO, 3, depoch=-1)
        + op(HELLO, 4, depoch=5) + op(HELLO, 5, proto=1),                        # FRESH copy, STALE, BADPROTO
        opened + op(WRITE, 0, rel=True) + op(RESET) + op(WRITE, 0, rel=True) + op(READ, 9)
        + op(HELLO, 1, depoch=1) + op(WRITE, 0, rel=True),                       # reset: NOSESSION, RESYNC
        opened + op(WRITE, 0, rel=True) + op(HELLO, 7, sid=1, depoch=1) + op(WRITE, 0, rel=True),   # NEW
        op(READ, 3) + op(WRITE, 3) + opened + op(WRITE, 0, rel=True, code=8) * 34 + op(WRITE, -33, rel=True)
        + op(WRITE, -32, rel=True) + op(READ, -33, rel=True),                    # the ring's edge
        op(HELLO, 65535) + op(WRITE, 0) + op(WRITE, 1),                           # seq wraps
    ]


# ------------------------------------------------------------------ Modbus RTU
ADDR = 7
FRAMES = [
    [ADDR, 3, 0, 0, 0, 39], [ADDR, 4, 0, 0, 0, 46], [ADDR, 4, 0, 17, 0, 2], [ADDR, 6, 0, 36, 0, 4],
    [ADDR, 6, 0, 12, 0x03, 0xE9], [ADDR, 16, 0, 0, 0, 3, 6, 0, 1, 0, 2, 0, 3],
    [ADDR, 16, 0, 100, 0, 5, 10, 0, 1, 0, 20, 0, 1, 0, 2, 0xFF, 0xFE],
    [0, 16, 0, 100, 0, 5, 10, 0, 1, 0, 20, 0, 1, 0, 2, 0, 3], [0, 6, 0, 36, 0, 1],
    [ADDR, 5, 0, 1, 0xFF, 0], [ADDR, 3, 0xFF, 0xFF, 0, 2], [ADDR, 3, 0, 0, 0, 126], [ADDR, 3, 0, 100, 0, 5],
]


def modbus_input(frames, flags: int = 1) -> bytes:
    out = bytearray([flags])
    for f in frames:
        for i, b in enumerate(f):
            out += bytes([120 if i == 0 else 5, b])   # 1920 us before a frame (>= t3.5), 80 us inside
    return bytes(out)


def modbus_seeds() -> list:
    out = [modbus_input([f]) for f in FRAMES]
    out += [modbus_input([FRAMES[6]], flags) for flags in (3, 5)]   # latched; a full queue
    out += [modbus_input(FRAMES[:4]), modbus_input([FRAMES[0]], 0)]  # several frames; CRC not fixed
    return out


# ------------------------------------------------------------------ the whole board
def board_seeds(v: dict) -> list:
    out = [b"\0" + latin1(c["bytes"]) for c in v["streams"]]
    out += [b"\0" + latin1(c["line"]) for c in v["good"]]
    seen, bodies = set(), []
    for c in v["commands"]:   # one command per verb and outcome, as a line body
        if c["n"] == 3 and (c["verb"], c["error"]) not in seen:
            seen.add((c["verb"], c["error"]))
            bodies.append(" ".join(["2", c["verb"]] + c["args"]))
    out += [b"\1" + b.encode("utf-8", "surrogatepass") for b in bodies]
    out += [b"\1" + b"\n".join(x.encode() for x in script) for script in (
        ["2 W 0 500 100 200 300", "3 W 1 500 0 0 0", "4 HOLD", "5 RESUME", "6 STAT"],
        ["2 SETLIM 1 0 100 50", "3 W 7 100 50 50 50", "4 STAT"],
        ["2 BEND 1 100 0 900 500", "3 DBAND 2 0", "4 GAIN 3 9000 1 1"],
        ["2 WDOG 50", "3 W 1 60000 524 960 1047"], ["2 CLR", "3 RATE 100"], ["2 MODBUS 7"])]
    out += [b"\2" + bytes(f) for f in FRAMES if f[0] == ADDR]   # the target writes its own address in
    return out


def main(argv: list) -> int:
    if len(argv) != 3:
        print("usage: seeds.py lines.json OUTDIR", file=sys.stderr)
        return 2
    with open(argv[1]) as f:
        v = json.load(f)
    sets = {"codec": codec_seeds(v), "session": session_seeds(), "modbus": modbus_seeds(), "board": board_seeds(v)}
    for target, inputs in sets.items():
        d = os.path.join(argv[2], target)
        os.makedirs(d, exist_ok=True)
        for old in os.listdir(d):
            os.remove(os.path.join(d, old))
        for i, data in enumerate(inputs):
            with open(os.path.join(d, "seed-%04d" % i), "wb") as f:
                f.write(data)
    print("seeds: " + ", ".join("%s %d" % (t, len(x)) for t, x in sets.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
