"""Host codec against the shared vectors, plus property tests."""
import json
import re
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
    assert VECTORS["version"] == p.PROTOCOL_VERSION == 2
    assert VECTORS["max_host_line"] == p.MAX_HOST_LINE
    assert VECTORS["max_board_line"] == p.MAX_BOARD_LINE
    assert bytes([VECTORS["estop_byte"]]) == p.ESTOP_BYTE


@pytest.mark.parametrize("case", VECTORS["crc"], ids=lambda c: f"{c['data'] or 'empty'}@{c['epoch']}")
def test_crc(case):
    assert p.crc32(raw(case["data"]), case["epoch"]) == case["crc"]


@pytest.mark.parametrize("case", VECTORS["good"], ids=lambda c: c["line"].strip())
def test_good_lines(case):
    line = p.decode(raw(case["line"]), p.MAX_BOARD_LINE, epoch=case["epoch"])
    assert (line.seq, line.verb, list(line.args)) == (case["seq"], case["verb"], case["args"])


@pytest.mark.parametrize("case", VECTORS["good"], ids=lambda c: c["line"].strip())
def test_encode_gives_the_good_lines(case):
    want = raw(case["line"]).replace(b"\r\n", b"\n")
    want = want if want.endswith(b"\n") else want + b"\n"
    assert p.encode(case["seq"], case["verb"], *case["args"], epoch=case["epoch"]) == want


@pytest.mark.parametrize("case", VECTORS["bad"], ids=lambda c: c["why"])
def test_bad_lines(case):
    with pytest.raises(p.ProtocolError) as err:
        p.decode(raw(case["line"]), max_len=p.MAX_HOST_LINE, epoch=case["epoch"])
    assert (err.value.code, err.value.name) == (case["code"], case["name"])


@pytest.mark.parametrize("case", VECTORS["commands"],
                         ids=lambda c: f"{c['verb']} {' '.join(c['args'])} n={c['n']}: {c['why']}")
def test_commands(case):
    if case["error"] is None:
        assert p.parse_command(case["verb"], case["args"], case["n"]) == case["values"]
    else:
        with pytest.raises(p.ProtocolError) as err:
            p.parse_command(case["verb"], case["args"], case["n"])
        assert err.value.name == case["error"]
        assert err.value.code == {v: k for k, v in p.ERROR_NAMES.items()}[case["error"]]


def test_command_vectors_cover_every_verb_and_bound():
    """Every verb of the table, and both bounds of every argument, have vectors."""
    cases = VECTORS["commands"]
    assert {c["verb"] for c in cases} >= set(p.COMMANDS)
    for verb, specs in p.COMMANDS.items():
        for i, (name, lo, hi) in enumerate(specs):
            if name in ("q", "joint"):
                continue
            seen = {int(c["args"][i]) for c in cases if c["verb"] == verb and c["n"] == 3
                    and len(c["args"]) > i and re.fullmatch(r"-?[0-9]+", c["args"][i])}
            assert {lo - 1, lo, hi, hi + 1} <= seen, (verb, name)


def test_example_session_lines_decode():
    for side, text, epoch in VECTORS["example"]:
        line = p.decode(raw(text), p.MAX_HOST_LINE if side == "host" else p.MAX_BOARD_LINE, epoch=epoch)
        if side == "host":
            p.parse_command(line.verb, line.args, 3)
        else:
            p.parse_board_line(line)


@pytest.mark.parametrize("case", [s for s in VECTORS["streams"] if "\x98" not in s["bytes"]],
                         ids=lambda c: c["why"])
def test_streams_without_estop(case):
    """The host splitter cuts board output as the board cuts host input (the
    host never receives e-stop bytes, so those streams are the board's alone);
    an empty line is the decoder's PARSE."""
    splitter = p.LineSplitter(max_len=p.MAX_HOST_LINE)
    out = []
    for item in splitter.feed(raw(case["bytes"])):
        if item == b"\n":
            with pytest.raises(p.ProtocolError) as err:
                p.decode(item)
            item = err.value
        if isinstance(item, p.ProtocolError):
            out.append(["error", item.code, item.name])
        else:
            out.append(["line", item[:-1].decode("latin-1")])
    assert out == case["out"]


def test_hello_is_framed_with_epoch_zero():
    assert p.encode(1, "HELLO", 2, 4242, 9, epoch=77) == p.encode(1, "HELLO", 2, 4242, 9)
    assert p.is_hello(b"1 HELLO 2 3 4") and p.is_hello(b"1 HELLO")
    assert not p.is_hello(b"1 HELLOX 2") and not p.is_hello(b"1  HELLO 2") and not p.is_hello(b"HELLO")


verbs = st.from_regex(r"[A-Z]{1,8}", fullmatch=True)
args = st.lists(st.from_regex(r"[!-)+-~]{1,6}", fullmatch=True), max_size=8)


@given(seq=st.integers(0, 65535), verb=verbs, args=args, epoch=st.integers(0, p.EPOCH_MAX))
def test_round_trip(seq, verb, args, epoch):
    line = p.encode(seq, verb, *args, epoch=epoch)
    assert p.decode(line, epoch=epoch) == p.Line(seq, verb, tuple(args))


@given(seq=st.integers(0, 65535), verb=verbs.filter(lambda v: v != "HELLO"), args=args,
       epoch=st.integers(0, p.EPOCH_MAX), other=st.integers(0, p.EPOCH_MAX))
def test_another_epoch_fails_the_crc(seq, verb, args, epoch, other):
    """A line framed in one epoch never decodes in another: CRC-32 from two seeds
    differs for the same data (the seed enters the register linearly)."""
    line = p.encode(seq, verb, *args, epoch=epoch)
    if other != epoch:
        with pytest.raises(p.ProtocolError) as err:
            p.decode(line, epoch=other)
        assert err.value.name == "CRC"


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
    good = p.encode(seq, "W", 7, 500, *q, epoch=seq)
    damaged = bytearray(good[:-1])
    if pos < len(damaged):
        damaged[pos] ^= 1 << flip
    damaged = bytes(damaged[: len(damaged) - cut if cut < len(damaged) else 0])
    try:
        line = p.decode(damaged, epoch=seq)
    except p.ProtocolError:
        return
    assert line == p.Line(seq, "W", ("7", "500", *map(str, q)))


@given(n=st.integers(p.MAX_HOST_LINE, 400))
def test_overlong_lines_rejected(n):
    body = b"1 W " + b"9" * n
    with pytest.raises(p.ProtocolError) as err:
        p.decode(body + b"*00000000\n", p.MAX_HOST_LINE)
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
    boot = p.parse_board_line(p.decode(p.encode(3, "BOOT", "arm3r", "0.2.0", 2, "WDOG")))
    assert boot == p.Boot(3, "arm3r", "0.2.0", 2, "WDOG")
    with pytest.raises(p.ProtocolError) as err:
        p.parse_board_line(p.decode(p.encode(3, "BOOT", "arm3r", "0.1.0", 1)))
    assert err.value.name == "ARGS"


def test_milli_round_trip():
    q = np.array([np.pi, -np.pi / 2, 0.0001])
    assert p.to_milli(q) == [3142, -1571, 0]
    np.testing.assert_allclose(p.from_milli(["3142", "-1571"]), [3.142, -1.571])
