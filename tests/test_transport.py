"""open_port: serial devices, pyserial URLs and in-process emulators (emu:DEVICE)."""
import time

import pytest

from armbridge.emulator.board import Faults
from armbridge.errors import ArmbridgeError
from armbridge.link.transport import Port, open_port, parse_emu_url


def test_loop_url_round_trip():
    with open_port("loop://", timeout=0.2) as p:
        assert isinstance(p, Port) and p.emulator is None and p.baudrate == 115200
        assert p.write(b"1 PING*C9CF\n") == 12
        time.sleep(0.01)
        assert p.in_waiting == 12
        assert p.read(100) == b"1 PING*C9CF\n"


@pytest.mark.parametrize("url, reason", [
    ("/dev/does-not-exist-armbridge", "No such file"),
    ("foo://bar", "foo"),
    ("socket://127.0.0.1:1", "refused"),
])
def test_bad_urls_name_the_url(url, reason):
    with pytest.raises(ArmbridgeError) as err:
        open_port(url, timeout=0.1)
    assert url in str(err.value) and reason in str(err.value)


def test_empty_url():
    with pytest.raises(ArmbridgeError, match="emu:DEVICE"):
        open_port("  ")


def test_parse_emu_url():
    device, kw = parse_emu_url(
        "emu:esp32?speed=4&drop=0.01&corrupt=0.02&dup=0.03&delay=0.1:20&seed=7&reset_at=1.5,3&stall=2@0.5&lanes=rx"
    )
    assert device == "esp32"
    assert kw["speed"] == 4.0 and kw["seed"] == 7
    assert kw["faults"] == Faults(drop=0.01, corrupt=0.02, dup=0.03, delay=0.1, delay_ms=20.0,
                                  lanes=("rx",), reset_at=(1.5, 3.0), stall=((2, 0.5),))
    assert parse_emu_url("emu:esp32") == ("esp32", {})


@pytest.mark.parametrize("url, words", [
    ("emu:esp99", ["esp99", "esp32"]),
    ("emu:", ["emu:DEVICE"]),
    ("emu:esp32?drop=2", ["drop", "[0, 1]"]),
    ("emu:esp32?corrupt=x", ["corrupt", "[0, 1]"]),
    ("emu:esp32?bogus=1", ["bogus", "known"]),
    ("emu:esp32?speed=-1", ["speed"]),
    ("emu:esp32?stall=9", ["stall", "JOINT@SECONDS"]),
    ("emu:esp32?lanes=up", ["lanes", "up"]),
])
def test_bad_emu_urls(url, words):
    with pytest.raises(ArmbridgeError) as err:
        open_port(url)
    for w in words:
        assert w in str(err.value)


@pytest.mark.hil
def test_emu_url_runs_a_board_and_close_stops_it():
    p = open_port("emu:esp32?speed=4&seed=1", timeout=0.05)
    emu = p.emulator
    try:
        assert emu is not None and emu.running and emu.speed == 4.0
        proto = emu.modules["proto"]
        p.write(proto.encode(1, "HELLO", [11]))
        buf = b""
        end = time.monotonic() + 3
        while b" OK 1 " not in buf and time.monotonic() < end:
            buf += p.read(256)
        assert b" OK 1 32 arm3r 0.1.0 1 3 " in buf
    finally:
        p.close()
    assert not emu.running and emu.port is None
