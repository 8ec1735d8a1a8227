"""Firmware codec (firmware/common/proto.py) against the shared vectors
(tests/vectors/lines.json). Runs under CPython and under the MicroPython
WebAssembly interpreter (tests/mpy/run_tests.mjs), so no pytest here."""

import proto
import protodef
from fwutil import latin1, load_vectors, raises

V = load_vectors()
CODES = {}
for _code in proto.ERROR_NAMES:
    CODES[proto.ERROR_NAMES[_code]] = _code


def test_vectors_version():
    assert V["version"] == proto.PROTOCOL_VERSION == 2
    assert V["max_host_line"] == proto.MAX_HOST_LINE
    assert V["max_board_line"] == proto.MAX_BOARD_LINE
    assert V["estop_byte"] == proto.ESTOP_BYTE


def test_crc_vectors():
    for case in V["crc"]:
        data = latin1(case["data"])
        assert proto.crc32(data, case["epoch"]) == case["crc"], case
        assert proto.crc32(bytearray(data), case["epoch"]) == case["crc"], case


def test_decode_good_vectors():
    for case in V["good"]:
        seq, verb, args = proto.decode(latin1(case["line"]), proto.MAX_BOARD_LINE, case["epoch"])
        assert (seq, verb, list(args)) == (case["seq"], case["verb"], case["args"]), case


def test_encode_gives_the_good_vectors():
    for case in V["good"]:
        data = proto.encode(case["seq"], case["verb"], case["args"], case["epoch"])
        want = latin1(case["line"])
        if want.endswith(b"\r\n"):
            want = want[:-2] + b"\n"
        if not want.endswith(b"\n"):
            want = want + b"\n"
        assert data == want, (data, want)


def test_decode_bad_vectors():
    for case in V["bad"]:
        e = raises(proto.decode, latin1(case["line"]), proto.MAX_HOST_LINE, case["epoch"])
        assert e is not None, case
        assert (e.code, e.name) == (case["code"], case["name"]), (case, e.code)


def test_commands_vectors():
    for case in V["commands"]:
        if case["error"] is None:
            got = proto.parse_command(case["verb"], case["args"], case["n"])
            assert got == case["values"], (case, got)
        else:
            e = raises(proto.parse_command, case["verb"], case["args"], case["n"])
            assert e is not None, case
            assert (e.code, e.name) == (CODES[case["error"]], case["error"]), (case, e.code)


def test_example_session_vectors():
    for side, text, epoch in V["example"]:
        if side == "host":
            seq, verb, args = proto.decode(latin1(text), proto.MAX_HOST_LINE, epoch)
            proto.parse_command(verb, args, 3)
        else:
            proto.decode(latin1(text), proto.MAX_BOARD_LINE)


def test_decode_accepts_str_bytearray_and_cr():
    line = proto.encode(42, "RATE", [10], 5)
    assert proto.decode(line, proto.MAX_HOST_LINE, 5) == (42, "RATE", ["10"])
    assert proto.decode(bytearray(line), proto.MAX_HOST_LINE, 5) == (42, "RATE", ["10"])
    assert proto.decode(line.decode(), proto.MAX_HOST_LINE, 5) == (42, "RATE", ["10"])
    assert proto.decode(line[:-1] + b"\r\n", proto.MAX_HOST_LINE, 5) == (42, "RATE", ["10"])


def test_length_bound_is_96_with_lf():
    body = "1 W 0 500 " + "1" * 60
    pad = 96 - len(body) - 10          # "*XXXXXXXX\n"
    ok = proto.encode(1, "W", ["0", "500", "1" * (60 + pad)])
    assert len(ok) == 96
    assert proto.decode(ok)[0] == 1
    long = proto.encode(1, "W", ["0", "500", "1" * (61 + pad)])
    assert len(long) == 97
    assert raises(proto.decode, long).code == proto.LONG
    assert raises(proto.decode, long[:-1]).code == proto.LONG   # LF not there: counted too


def test_star_inside_body_is_parse():
    body = b"1 PING a*b"
    line = body + ("*%08X\n" % proto.crc32(body)).encode()
    assert raises(proto.decode, line).code == proto.PARSE


def test_hello_rule():
    assert proto.encode(1, "HELLO", [2, 9, 3], 77) == proto.encode(1, "HELLO", [2, 9, 3])
    assert proto.is_hello(b"1 HELLO 2 3 4") and proto.is_hello(b"1 HELLO")
    assert not proto.is_hello(b"1 HELLOX 2") and not proto.is_hello(b"1  HELLO 2")
    assert not proto.is_hello(b"HELLO")


def test_range_detail_names_the_argument_or_joint():
    pc = proto.parse_command
    assert raises(pc, "W", ["0", "1", "0", "1000001", "0"], 3).detail == "2"
    assert raises(pc, "W", ["0", "0", "0", "0", "0"], 3).detail == "dur"
    assert raises(pc, "SETLIM", ["1", "5", "4", "1"], 3).detail == "min"
    assert raises(pc, "HELLO", ["2", "1", "1073741824"], 3).detail == "epoch"


def test_table_is_the_generated_one():
    assert proto.COMMANDS is protodef.COMMANDS
    assert proto.READ_ONLY == protodef.READ_ONLY == ("STAT", "LIM", "PING", "IDENT")
    assert protodef.ORDERED["SETLIM"] == (("min", "max"),)


def _feed_bytewise(reader, data):
    out = []
    for i in range(len(data)):
        out += reader.feed(data[i:i + 1])
    return out


def _items(out):
    return [list(x) for x in out]


def test_stream_vectors():
    for case in V["streams"]:
        want = []
        for item in case["out"]:
            if item[0] == "line":
                want.append(["line", latin1(item[1])])
            else:
                want.append(list(item))
        data = latin1(case["bytes"])
        assert _items(proto.LineReader().feed(data)) == want, case
        assert _items(_feed_bytewise(proto.LineReader(), data)) == want, case
        assert _items(proto.LineReader().feed(bytearray(data))) == want, case


def test_reader_keeps_state_across_chunks():
    r = proto.LineReader(96)
    assert _items(r.feed(b"a" * 60)) == []
    assert _items(r.feed(b"a" * 36)) == []
    assert _items(r.feed(b"\nb")) == [["error", 3, "LONG"]]
    assert _items(r.feed(b"\n")) == [["line", b"b"]]
    assert _items(r.feed(b"cd\x98ef\n\x98g\n")) == [["estop"], ["estop"], ["line", b"g"]]


def test_error_names():
    for code in range(1, 13):
        assert proto.ProtocolError(code).name == proto.ERROR_NAMES[code]
    assert proto.ERROR_NAMES[proto.STALE] == "STALE" and proto.STALE == 11
    assert proto.ERROR_NAMES[proto.PROTO] == "PROTO" and proto.PROTO == 12
