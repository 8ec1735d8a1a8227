"""Converts tests/vectors/lines.json into the line format the native firmware tests
read (firmware/arduino_pump/tests/test_codec.cpp), so the C++ side needs no JSON
parser. Every string is hex, prefixed "x" (so "x" is the empty string): line and
stream strings as latin-1 bytes (as tests/firmware/fwutil.latin1), command arguments
as UTF-8 (what a C board receives).

  meta VERSION MAX_HOST MAX_BOARD ESTOP
  crc xDATA EPOCH CRC
  good xLINE EPOCH SEQ xVERB NARGS xARG...
  bad xLINE EPOCH CODE
  cmd xVERB N CODE NARGS xARG... NVALUES VALUE...      (CODE 0: accepted)
  stream xBYTES NITEMS ITEM...                         (L:xLINE, E:CODE, S: e-stop)
  example host|board xLINE EPOCH

usage: python3 vectors2txt.py lines.json out.txt
"""
import json
import sys

CODES = {"PARSE": 1, "CRC": 2, "LONG": 3, "VERB": 4, "ARGS": 5, "RANGE": 6, "SEQ": 7, "FULL": 8,
         "LATCHED": 9, "NOSESSION": 10, "STALE": 11, "PROTO": 12, "REACH": 13, "UNHOMED": 14}


def lat(s: str) -> str:
    return "x" + bytes(ord(c) for c in s).hex()


def utf(s: str) -> str:
    return "x" + s.encode("utf-8").hex()


def convert(v: dict) -> list:
    out = ["meta %d %d %d %d" % (v["version"], v["max_host_line"], v["max_board_line"], v["estop_byte"])]
    for c in v["crc"]:
        out.append("crc %s %d %d" % (lat(c["data"]), c["epoch"], c["crc"]))
    for c in v["good"]:
        out.append("good %s %d %d %s %d %s" % (lat(c["line"]), c["epoch"], c["seq"], lat(c["verb"]),
                                              len(c["args"]), " ".join(lat(a) for a in c["args"])))
    for c in v["bad"]:
        out.append("bad %s %d %d" % (lat(c["line"]), c["epoch"], c["code"]))
    for c in v["commands"]:
        code = 0 if c["error"] is None else CODES[c["error"]]
        vals = c["values"] or []
        out.append("cmd %s %d %d %d %s %d %s" % (utf(c["verb"]), c["n"], code, len(c["args"]),
                                                " ".join(utf(a) for a in c["args"]), len(vals),
                                                " ".join(str(x) for x in vals)))
    for c in v["streams"]:
        items = []
        for it in c["out"]:
            if it[0] == "line":
                items.append("L:" + lat(it[1]))
            elif it[0] == "error":
                items.append("E:%d" % it[1])
            else:
                items.append("S")
        out.append("stream %s %d %s" % (lat(c["bytes"]), len(items), " ".join(items)))
    for side, text, epoch in v["example"]:
        out.append("example %s %s %d" % (side, lat(text), epoch))
    return out


def main(argv: list) -> int:
    if len(argv) != 3:
        print("usage: vectors2txt.py lines.json out.txt", file=sys.stderr)
        return 2
    with open(argv[1]) as f:
        lines = convert(json.load(f))
    with open(argv[2], "w") as f:
        f.write("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
