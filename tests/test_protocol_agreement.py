"""The host codec and the firmware codec agree on every input (issue 9 §5).

Hypothesis feeds random verbs, argument lists and joint counts to both
parse_command functions and random, possibly damaged, lines with random epochs
to both decoders: each pair must give the same values or the same error code.
The shared vectors pin the rules; this finds the cases nobody wrote down.
The firmware codec runs under CPython here (tests/firmware covers MicroPython).
"""
import importlib
import pathlib
import sys

from hypothesis import given, settings
from hypothesis import strategies as st

from armbridge.link import protocol as host
from armbridge.link import protodef as D

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _load_firmware_codec():
    """firmware/common/proto.py (and the protodef it imports), without leaving
    the flat names in sys.modules or the folder on sys.path."""
    folder = str(ROOT / "firmware" / "common")
    names = ("proto", "protodef")
    saved = {n: sys.modules.pop(n) for n in names if n in sys.modules}
    sys.path.insert(0, folder)
    try:
        return importlib.import_module("proto")
    finally:
        sys.path.remove(folder)
        for n in names:
            sys.modules.pop(n, None)
        sys.modules.update(saved)


fw = _load_firmware_codec()


def host_command(verb, args, n):
    try:
        return "ok", host.parse_command(verb, args, n)
    except host.ProtocolError as err:
        return "error", err.code


def fw_command(verb, args, n):
    try:
        return "ok", fw.parse_command(verb, list(args), n)
    except fw.ProtocolError as err:
        return "error", err.code


def host_decode(line, max_len, epoch):
    try:
        got = host.decode(line, max_len, epoch=epoch)
        return "ok", (got.seq, got.verb, list(got.args))
    except host.ProtocolError as err:
        return "error", err.code


def fw_decode(line, max_len, epoch):
    try:
        seq, verb, args = fw.decode(line, max_len, epoch)
        return "ok", (seq, verb, list(args))
    except fw.ProtocolError as err:
        return "error", err.code


BOUNDS = sorted({b + d for specs in D.COMMANDS.values() for _, lo, hi in specs
                 for b in (lo, hi) for d in (-1, 0, 1)})
numbers = st.one_of(st.sampled_from(BOUNDS), st.integers(-2 ** 31, 2 ** 31)).map(str)
forms = st.one_of(st.sampled_from(["+1", "01", "-0", "1.5", "", "-", "1e3", " 1", "9" * 30, "-" + "9" * 11]),
                  st.text(max_size=6), st.from_regex(r"-?[0-9]{1,12}", fullmatch=True))
arguments = st.lists(st.one_of(numbers, numbers, forms), max_size=12)
verbs = st.one_of(st.sampled_from(sorted(D.COMMANDS)), st.sampled_from(["OK", "ER", "JUMP", "hello", ""]),
                  st.from_regex(r"[A-Z]{1,8}", fullmatch=True))


@st.composite
def command_cases(draw):
    verb = draw(verbs)
    n = draw(st.integers(0, 8))
    if verb in D.COMMANDS and draw(st.booleans()):
        # the right count, mostly in range, so that forms, ranges and rules are reached
        args = []
        for name, lo, hi in D.COMMANDS[verb]:
            inside = st.integers(lo, max(n, 1) if name == "joint" else hi).map(str)
            args += draw(st.lists(st.one_of(inside, inside, inside, inside, numbers, forms),
                                  min_size=n if name == "q" else 1, max_size=n if name == "q" else 1))
    else:
        args = draw(arguments)
    return verb, args, n


@given(command_cases())
@settings(max_examples=1000, deadline=None)
def test_parse_command_agrees(case):
    verb, args, n = case
    assert host_command(verb, args, n) == fw_command(verb, args, n)


epochs = st.one_of(st.just(0), st.integers(1, D.EPOCH_MAX), st.sampled_from([1, 2, D.EPOCH_MAX]))
line_args = st.lists(st.one_of(numbers, st.from_regex(r"[!-)+-~]{1,5}", fullmatch=True)), max_size=10)


@st.composite
def damaged_lines(draw):
    seq = draw(st.integers(0, 65535))
    verb = draw(st.one_of(st.sampled_from(sorted(D.COMMANDS) + ["OK", "T", "BOOT"]),
                          st.from_regex(r"[A-Z]{1,8}", fullmatch=True)))
    epoch = draw(epochs)
    line = bytearray(host.encode(seq, verb, *draw(line_args), epoch=epoch))
    for _ in range(draw(st.integers(0, 3))):
        kind = draw(st.sampled_from(["flip", "drop", "dup", "insert", "cut"]))
        if not line:
            break
        pos = draw(st.integers(0, len(line) - 1))
        if kind == "flip":
            line[pos] ^= 1 << draw(st.integers(0, 7))
        elif kind == "drop":
            del line[pos]
        elif kind == "dup":
            line.insert(pos, line[pos])
        elif kind == "insert":
            line.insert(pos, draw(st.sampled_from([0x0D, 0x20, 0x2A, 0x30, 0x41, 0x61, 0x7F, 0x98, 0xE9])))
        else:
            del line[pos:]
    receiver = draw(st.one_of(st.just(epoch), epochs))
    return bytes(line), receiver


@given(damaged_lines(), st.sampled_from([D.MAX_HOST_LINE, D.MAX_BOARD_LINE]))
@settings(max_examples=1000, deadline=None)
def test_decode_agrees_on_damaged_lines(case, max_len):
    line, epoch = case
    assert host_decode(line, max_len, epoch) == fw_decode(line, max_len, epoch)


@given(st.binary(max_size=120), epochs)
@settings(max_examples=300, deadline=None)
def test_decode_agrees_on_random_bytes(data, epoch):
    assert host_decode(data, D.MAX_HOST_LINE, epoch) == fw_decode(data, D.MAX_HOST_LINE, epoch)


@given(st.integers(0, 65535), verbs.filter(bool), line_args, epochs)
@settings(max_examples=200, deadline=None)
def test_encoders_agree(seq, verb, args, epoch):
    assert host.encode(seq, verb, *args, epoch=epoch) == fw.encode(seq, verb, args, epoch)
