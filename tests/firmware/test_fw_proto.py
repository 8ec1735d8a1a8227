"""Codec tests against the shared vectors (tests/vectors/lines.json)."""

import proto
from fwutil import latin1, load_vectors, raises

V = load_vectors()


def _crc_field_has_letter(line: str) -> bool:
    i = line.rfind("*")
    for c in line[i + 1:i + 5]:
        if c in "abcdefABCDEF":
            return True
    return False


def test_vectors_version():
    assert V["version"] == proto.PROTO_VERSION
    assert V["max_command_line"] == proto.MAX_HOST_LINE
    assert V["max_board_line"] == proto.MAX_BOARD_LINE
    assert V["estop_byte"] == proto.ESTOP_BYTE


def test_crc_vectors():
    for case in V["crc"]:
        assert proto.crc16(latin1(case["data"])) == case["crc"], case
        assert proto.crc16(bytearray(latin1(case["data"]))) == case["crc"], case


def test_decode_good_vectors():
    for case in V["good"]:
        seq, verb, args = proto.decode(latin1(case["line"]), proto.MAX_BOARD_LINE)
        assert seq == case["seq"], case
        assert verb == case["verb"], case
        assert list(args) == case["args"], case


def test_encode_roundtrips_good_vectors():
    for case in V["good"]:
        data = proto.encode(case["seq"], case["verb"], case["args"])
        want = latin1(case["line"])
        if want.endswith(b"\r\n"):
            want = want[:-2] + b"\n"
        if not want.endswith(b"\n"):
            want = want + b"\n"
        assert data == want, (data, want)


def test_decode_bad_vectors():
    for case in V["bad"]:
        e = raises(proto.decode, latin1(case["line"]))
        assert e is not None, case
        assert (e.code, e.name) == (case["code"], case["name"]), (case, e.code)


def test_lower_case_crc_refused():
    data = b""
    for seq in range(1, 200):
        data = proto.encode(seq, "PING", [])
        if _crc_field_has_letter(data.decode()):
            break
    low = data[:-5] + data[-5:].lower()
    assert low != data
    e = raises(proto.decode, low)
    assert e is not None and e.code == proto.PARSE


def test_decode_accepts_str_bytearray_and_cr():
    line = proto.encode(42, "RATE", [10])
    assert proto.decode(line) == (42, "RATE", ["10"])
    assert proto.decode(bytearray(line)) == (42, "RATE", ["10"])
    assert proto.decode(line.decode()) == (42, "RATE", ["10"])
    assert proto.decode(line[:-1] + b"\r\n") == (42, "RATE", ["10"])


def test_length_bound_is_96_with_lf():
    body = "1 W 0 500 " + "1" * 60
    pad = 96 - len(body) - 6          # "*XXXX\n"
    ok = proto.encode(1, "W", ["0", "500", "1" * (60 + pad)])
    assert len(ok) == 96
    assert proto.decode(ok)[0] == 1
    long = proto.encode(1, "W", ["0", "500", "1" * (61 + pad)])
    assert len(long) == 97
    assert raises(proto.decode, long).code == proto.LONG
    assert raises(proto.decode, long[:-1]).code == proto.LONG   # LF not there: counted too


def test_star_inside_body_is_parse():
    body = b"1 PING a*b"
    line = body + ("*%04X\n" % proto.crc16(body)).encode()
    assert raises(proto.decode, line).code == proto.PARSE


def test_commands_vectors():
    n = V["command_joints"]
    for case in V["commands"]:
        if case["ok"]:
            assert proto.parse_command(case["verb"], case["args"], n) == case["values"], case
        else:
            e = raises(proto.parse_command, case["verb"], case["args"], n)
            assert e is not None, case
            assert (e.code, e.name) == (case["code"], case["name"]), (case, e.code)


def test_command_ranges():
    pc = proto.parse_command
    assert pc("W", ["0", "1", "1000000", "-1000000", "0"], 3) == [0, 1, 1000000, -1000000, 0]
    assert raises(pc, "W", ["0", "1", "1000001", "0", "0"], 3).code == proto.RANGE
    assert raises(pc, "W", ["0", "1", "-99999999999999999999", "0", "0"], 3).code == proto.RANGE
    assert raises(pc, "HELLO", ["65536"], 3).code == proto.RANGE
    assert raises(pc, "WDOG", ["10001"], 3).code == proto.RANGE
    assert pc("WDOG", ["10000"], 3) == [10000]
    assert pc("RATE", ["0"], 3) == [0]
    assert raises(pc, "GAIN", ["1", "1000001", "0", "0"], 3).code == proto.RANGE
    assert raises(pc, "GAIN", ["4", "1", "0", "0"], 3).code == proto.RANGE
    assert raises(pc, "PING", ["x"], 3).code == proto.ARGS
    assert raises(pc, "RATE", ["abc"], 3).code == proto.ARGS
    assert raises(pc, "RATE", ["-"], 3).code == proto.ARGS


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


def test_reader_line_of_95_plus_lf_passes_96_is_long():
    r = proto.LineReader(96)
    assert _items(r.feed(b"a" * 95 + b"\n")) == [["line", b"a" * 95]]
    assert _items(r.feed(b"a" * 96 + b"\n")) == [["error", 3, "LONG"]]
    assert _items(r.feed(b"b\n")) == [["line", b"b"]]


def test_reader_estop_during_long_line_is_silent():
    r = proto.LineReader(96)
    assert _items(r.feed(b"x" * 150 + b"\x98" + b"yy\nz\n")) == [["estop"], ["line", b"z"]]


def test_error_names():
    for code in range(1, 11):
        assert proto.ProtoError(code).name == proto.ERROR_NAMES[code]
    assert proto.ERROR_NAMES[proto.NOSESSION] == "NOSESSION"
    assert proto.ERROR_NAMES[proto.SEQ] == "SEQ"
