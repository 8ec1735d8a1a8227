"""`emu:DEVICE?...` URLs: parsed into emulator arguments (one clear error per
bad part), and opened as a port whose clock runs on the emulator's time scale."""
import pytest

from armbridge.emulator.faults import Faults
from armbridge.emulator.url import PARAMETERS, open_emu_port, parse_emu_url
from armbridge.errors import ArmbridgeError
from armbridge.link.transport import PortError
from armbridge.link.transport import Port
from emu_host import Codec, is_reply


def test_parse_every_parameter():
    device, kw = parse_emu_url(
        "emu:esp32?speed=4&seed=3&plant=random&link=/tmp/a&interpreter=cpython&drop=0.01&corrupt=0.001&dup=0"
        "&delay=0.01:20&lanes=rx&reset_at=2.5,5&stall=2@4,1@6")
    assert device == "esp32"
    assert kw == {"speed": 4.0, "seed": 3, "plant": "random", "link": "/tmp/a", "interpreter": "cpython",
                  "faults": Faults(drop=0.01, corrupt=0.001, dup=0.0, delay=0.01, delay_ms=20.0, lanes=("rx",),
                                   reset_at=(2.5, 5.0), stall=((2, 4.0), (1, 6.0)))}
    assert parse_emu_url("emu:esp32") == ("esp32", {})
    assert parse_emu_url("emu:esp32?delay=0.5&delay_ms=3")[1]["faults"] == Faults(delay=0.5, delay_ms=3.0)


@pytest.mark.parametrize("url, words", [
    ("emu:", ["emu:DEVICE"]),
    ("emu:esp99", ["'esp99'", "esp32"]),
    ("emu:esp32?drop=2", ["'emu:esp32?drop=2'", "drop", "[0, 1]"]),
    ("emu:esp32?corrupt=x", ["corrupt", "[0, 1]"]),
    ("emu:esp32?bogus=1", ["'bogus'", "known", *PARAMETERS]),
    ("emu:esp32?speed=-1", ["speed", ">= 0"]),
    ("emu:esp32?speed=fast", ["speed", "not a number"]),
    ("emu:esp32?seed=1.5", ["seed", "integer"]),
    ("emu:esp32?plant=true", ["plant", "'true'", "nominal, random"]),
    ("emu:esp32?stall=9", ["stall", "JOINT@SECONDS"]),
    ("emu:esp32?lanes=up", ["lanes", "'up'"]),
    ("emu:esp32?reset_at=1,-2", ["reset_at", ">= 0"]),
    ("emu:esp32?delay=0.1:x", ["delay", "not a number"]),
    ("emu:esp32?interpreter=pypy", ["interpreter", "cpython, micropython"]),
    ("emu:esp32?drop", ["bad port"]),
])
def test_bad_urls_are_one_line_naming_the_part(url, words):
    with pytest.raises(ArmbridgeError) as exc:
        parse_emu_url(url)
    msg = str(exc.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, (w, msg)


def test_open_emu_port_gives_a_port_on_the_emulators_time_scale():
    port = open_emu_port("emu:esp32?speed=0&seed=2", timeout=0.05)  # lockstep in the host's thread: sim time only
    emu = port.emulator
    try:
        assert isinstance(port, Port) and not emu.running and emu.speed == 0 and emu.port is None  # no thread, no pty
        assert port.clock == emu.now
        t0 = port.clock()
        codec = Codec()
        port.reset_input_buffer()
        port.write(codec.hello(7))
        lines: list = []
        for _ in range(200):  # reads of at most 0.05 s each
            lines += codec.feed(port.read(4096))
            if any(is_reply(line, codec.seq) for line in lines):
                break
        assert any(is_reply(line, codec.seq) and line[1] == "OK" for line in lines), lines[-3:]
        assert port.clock() > t0 and port.clock() <= emu.now()  # sim seconds, as the board counts them
    finally:
        port.close()
    assert not emu.running and emu.port is None


def test_a_paced_port_clock_follows_the_board_and_never_runs_backwards():
    """The host's clock on a paced emulator: at most a tick ahead of the board's
    clock (so host timers cannot run out early when a starved emulator lags),
    never backwards, and still running once the emulator's thread has stopped
    (so a host's timeouts still fire)."""
    import time

    port = open_emu_port("emu:esp32?speed=8", timeout=0.05)
    emu = port.emulator
    tick = emu.tick_us / 1e6
    samples = []
    try:
        for _ in range(100):
            t = port.clock()
            samples.append((t, emu.clock.t))  # the board's clock, read after the host's
            time.sleep(0.001)
    finally:
        port.close()
    times = [t for t, _ in samples]
    assert times == sorted(times) and times[-1] > times[0]
    assert all(t <= board + tick + 1e-9 for t, board in samples)
    after = port.clock()
    time.sleep(0.01)
    assert port.clock() > after


def test_a_url_that_fails_to_start_leaves_nothing_behind(tmp_path):
    (tmp_path / "arm").write_text("a file, not a link")
    with pytest.raises(PortError, match="not a symlink") as exc:
        open_emu_port(f"emu:esp32?link={tmp_path / 'arm'}")
    assert exc.value.exit_code == 1  # a port that cannot be had, not a bad command line
    assert (tmp_path / "arm").read_text() == "a file, not a link" and not (tmp_path / "arm.lock").exists()
