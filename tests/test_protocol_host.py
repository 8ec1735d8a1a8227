"""Host codec against the shared vectors, plus property tests."""
import json
import pathlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbridge.link import protocol as p

VECTORS = json.loads((pathlib.Path(__file__).parent / "vectors" / "lines.json").read_text())


def raw(text: str) -> bytes:
    return text.encode("latin-1")


def test_constants_match_vectors():
    assert VECTORS["max_command_line"] == p.MAX_COMMAND_LINE
    assert VECTORS["max_board_line"] == p.MAX_BOARD_LINE
    assert bytes([VECTORS["estop_byte"]]) == p.ESTOP_BYTE


@pytest.mark.parametrize("case", VECTORS["crc"], ids=lambda c: c["data"] or "empty")
def test_crc(case):
    assert p.crc16(raw(case["data"])) == case["crc"]


@pytest.mark.parametrize("case", VECTORS["good"], ids=lambda c: c["line"].strip())
def test_good_lines(case):
    line = p.decode(raw(case["line"]), max_len=p.MAX_COMMAND_LINE if len(case["line"]) <= 96 else p.MAX_BOARD_LINE)
    assert (line.seq, line.verb, list(line.args)) == (case["seq"], case["verb"], case["args"])


@pytest.mark.parametrize("case", VECTORS["bad"], ids=lambda c: c["why"])
def test_bad_lines(case):
    with pytest.raises(p.ProtocolError) as err:
        p.decode(raw(case["line"]), max_len=p.MAX_COMMAND_LINE)
    assert (err.value.code, err.value.name) == (case["code"], case["name"])


@pytest.mark.parametrize("case", VECTORS["commands"], ids=lambda c: f"{c['verb']} {c.get('why', 'ok')}")
def test_commands(case):
    n = VECTORS["command_joints"]
    if case["ok"]:
        assert p.parse_command(case["verb"], case["args"], n) == case["values"]
    else:
        with pytest.raises(p.ProtocolError) as err:
            p.parse_command(case["verb"], case["args"], n)
        assert (err.value.code, err.value.name) == (case["code"], case["name"])


@pytest.mark.parametrize("case", [s for s in VECTORS["streams"] if "\x98" not in s["bytes"]],
                         ids=lambda c: c["why"])
def test_streams_without_estop(case):
    """The host splitter cuts board output as the board cuts host input (the
    host never receives e-stop bytes, so those streams are the board's alone)."""
    splitter = p.LineSplitter(max_len=p.MAX_COMMAND_LINE)
    out = []
    for item in splitter.feed(raw(case["bytes"])):
        if isinstance(item, p.ProtocolError):
            out.append(["error", item.code, item.name])
            continue
        try:
            p.decode(item, p.MAX_COMMAND_LINE)
            out.append(["line", item[:-1].decode("latin-1")])
        except p.ProtocolError as err:
            out.append(["error", err.code, err.name])
    assert out == case["out"]


verbs = st.from_regex(r"[A-Z]{1,8}", fullmatch=True)
args = st.lists(st.from_regex(r"[!-)+-~]{1,6}", fullmatch=True), max_size=8)


@given(seq=st.integers(0, 65535), verb=verbs, args=args)
def test_round_trip(seq, verb, args):
    line = p.encode(seq, verb, *args)
    assert p.decode(line) == p.Line(seq, verb, tuple(args))


@given(data=st.binary(max_size=300))
@settings(max_examples=500)
def test_random_bytes_never_crash(data):
    for item in p.LineSplitter().feed(data):
        if isinstance(item, bytes):
            try:
                p.decode(item)
            except p.ProtocolError:
                pass


@given(seq=st.integers(0, 65535), q=st.lists(st.integers(-3142, 3142), min_size=3, max_size=3),
       cut=st.integers(0, 60), flip=st.integers(0, 7), pos=st.integers(0, 60))
@settings(max_examples=500)
def test_damaged_waypoint_never_decodes_to_a_wrong_command(seq, q, cut, flip, pos):
    """Truncated or bit-flipped waypoint lines are rejected, never misread:
    whatever still decodes carries exactly the original payload."""
    good = p.encode(seq, "W", 7, 500, *q)
    damaged = bytearray(good[:-1])
    if pos < len(damaged):
        damaged[pos] ^= 1 << flip
    damaged = bytes(damaged[: len(damaged) - cut if cut < len(damaged) else 0])
    try:
        line = p.decode(damaged)
    except p.ProtocolError:
        return
    assert line == p.Line(seq, "W", ("7", "500", *map(str, q)))


@given(n=st.integers(p.MAX_COMMAND_LINE, 400))
def test_overlong_lines_rejected(n):
    body = b"1 W " + b"9" * n
    with pytest.raises(p.ProtocolError) as err:
        p.decode(body + b"*0000\n", p.MAX_COMMAND_LINE)
    assert err.value.name == "LONG"


def test_board_lines_typed():
    tel = p.parse_board_line(p.decode(p.encode(9, "T", 10560, "RUN", "-", 32, 1500, -1500, 10, 1520, -1520, 8, 300, -300, 20)))
    assert isinstance(tel, p.Telemetry) and tel.done is None and tel.free == 32
    np.testing.assert_allclose(tel.q, [1.5, -1.5, 0.01])
    np.testing.assert_allclose(tel.effort, [0.3, -0.3, 0.02])
    er = p.parse_board_line(p.decode(p.encode(8, "ER", "-", 2, "CRC")))
    assert er == p.Er(8, None, 2, "CRC", ())
    ok = p.parse_board_line(p.decode(p.encode(7, "OK", 5, 31)))
    assert ok == p.Ok(7, 5, 31, ())
    with pytest.raises(p.ProtocolError):
        p.parse_board_line(p.decode(p.encode(1, "T", 1, "RUN", "-", 32, 1, 2)))


def test_milli_round_trip():
    q = np.array([np.pi, -np.pi / 2, 0.0001])
    assert p.to_milli(q) == [3142, -1571, 0]
    np.testing.assert_allclose(p.from_milli(["3142", "-1571"]), [3.142, -1.571])
