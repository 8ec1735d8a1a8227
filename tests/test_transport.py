"""open_port: serial devices, pyserial URLs and the scheme table (emu:DEVICE);
exclusive ports; one line with one hint for every port error."""
import os
import subprocess
import sys
import time

import pytest
import serial

from armbridge.errors import ArmbridgeError
from armbridge.link import transport
from armbridge.link.transport import SCHEMES, Port, PortError, PortGone, open_port, port_scheme


@pytest.fixture
def pty_name():
    """A real pseudo-terminal: the slave's name (a serial device as far as open_port can tell)."""
    master, slave = os.openpty()
    fds = [master, slave]
    yield os.ttyname(slave), fds
    for fd in fds:
        try:
            os.close(fd)
        except OSError:
            pass


def one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text and text, text
    return text


def test_loop_url_round_trip():
    with open_port("loop://", timeout=0.2) as p:
        assert isinstance(p, Port) and p.emulator is None and p.clock is None and p.baudrate == 115200
        assert p.write(b"1 PING*C9CF\n") == 12
        p.flush()
        assert p.read(12) == b"1 PING*C9CF\n"


@pytest.mark.parametrize("url, scheme", [
    ("emu:esp32?speed=2", "emu"), ("socket://h:1", "socket"), ("LOOP://", "loop"),
    ("/dev/ttyUSB0", None), ("COM3", None), ("ttyUSB0", None),
])
def test_port_scheme(url, scheme):
    assert port_scheme(url) == scheme


def test_the_scheme_table_names_openers_by_import_path():
    assert SCHEMES["emu"] == "armbridge.emulator.url:open_emu_port"
    code = ("import sys, armbridge.link.transport; "
            "print(sorted(m for m in sys.modules if m.startswith('armbridge.emulator')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"  # importing the transport pulls in no emulator code


def opener_for_test(url, baud, timeout):
    return Port(serial.serial_for_url("loop://", baudrate=baud, timeout=timeout), url)


def test_a_new_scheme_is_one_table_entry(monkeypatch):
    monkeypatch.setitem(SCHEMES, "mem", f"{__name__}:opener_for_test")
    with open_port("mem:anything", baud=9600, timeout=0.2) as p:
        assert p.url == "mem:anything" and p.baudrate == 9600
        p.write(b"x\n")
        assert p.read(2) == b"x\n"


@pytest.mark.parametrize("url, words, usage", [
    ("  ", ["empty port", "emu:DEVICE"], True),
    ("/dev/does-not-exist-armbridge", ["no such device /dev/does-not-exist-armbridge", "plugged in"], True),
    ("/etc/passwd", ["/etc/passwd is not a serial device (a regular file)"], True),
    ("/tmp", ["/tmp is not a serial device (a directory)"], True),
    ("/dev/null", ["/dev/null is not a serial device"], True),
    ("foo:bar", ["unknown port kind 'foo:'", "pyserial URL"], True),
    ("foo://bar", ["unknown port kind", "'foo' not known", "emu:DEVICE"], True),
    ("socket://127.0.0.1:1", ["socket://127.0.0.1:1", "refused", "server running"], False),
])
def test_port_errors_are_one_line_with_one_hint(url, words, usage):
    with pytest.raises(PortError) as err:
        open_port(url, timeout=0.1)
    text = one_line(err.value)
    for w in words:
        assert w in text, text
    assert err.value.usage is usage
    assert isinstance(err.value, ArmbridgeError)


def test_a_busy_port_names_its_holder(pty_name):
    name, _ = pty_name
    first = open_port(name)
    try:
        with pytest.raises(PortError) as err:
            open_port(name)
        text = one_line(err.value)
        assert text.startswith(f"port {name} is busy: ") and f"(pid {os.getpid()})" in text
        assert "pytest" in text or "py.test" in text or "python" in text  # this process's command line
        assert not err.value.usage
        # The first holder is unharmed.
        first.write(b"hello\n")
        assert os.read(pty_name[1][0], 100) == b"hello\n"
    finally:
        first.close()
    with open_port(name) as again:  # released on close
        assert again.is_open


def test_a_port_held_by_another_process_names_its_pid_and_command(pty_name):
    name, _ = pty_name
    code = ("import sys; from armbridge.link.transport import open_port; p = open_port(sys.argv[1]); "
            "print('held', flush=True); sys.stdin.read(); p.close()")
    holder = subprocess.Popen([sys.executable, "-c", code, name], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(PortError) as err:
            open_port(name)
        text = one_line(err.value)
        assert f"(pid {holder.pid})" in text and "open_port(sys.argv[1])" in text, text
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)  # it exits at once: a hang guard
    with open_port(name):
        pass  # the holder exited: free again


def test_a_port_another_program_locked_is_busy(pty_name):
    """pyserial's exclusive=True (an flock on the device) from a program that is not armbridge."""
    name, _ = pty_name
    other = serial.Serial(name, exclusive=True)
    try:
        with pytest.raises(PortError) as err:
            open_port(name)
        text = one_line(err.value)
        assert text == f"port {name} is busy: another program has it open (fuser -v {name} names it)"
    finally:
        other.close()
    with open_port(name):
        pass  # and the failed attempt left no lock file held


def test_a_symlink_to_a_held_device_is_busy_too(pty_name, tmp_path):
    name, _ = pty_name
    link = tmp_path / "arm0"
    link.symlink_to(name)
    with open_port(name):
        with pytest.raises(PortError, match=f"port {link} is busy"):
            open_port(str(link))


def test_a_port_that_goes_away_mid_run_says_unplugged(pty_name):
    name, fds = pty_name
    p = open_port(name, timeout=0.05)
    try:
        p.write(b"x")
        for fd in fds:  # the other end vanishes, as a USB adapter does when pulled
            os.close(fd)
        fds.clear()
        for what, call in (("read", lambda: p.read(10)), ("write", lambda: p.write(b"1 PING\n")),
                           ("poll", lambda: p.in_waiting)):
            with pytest.raises(PortGone) as err:
                call()
            text = one_line(err.value)
            assert text.startswith(f"the port {name} went away: unplugged? ({what}: "), text
    finally:
        p.close()  # closing a port that went away is quiet


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
    with pytest.raises(PortError) as err:
        open_port(url)
    assert err.value.usage  # the url is wrong: bad input, nothing ran
    text = one_line(err.value)
    for w in words:
        assert w in text


@pytest.mark.hil
def test_emu_url_runs_a_board_and_close_stops_it():
    p = open_port("emu:esp32?speed=4&seed=1", timeout=0.05)
    emu = p.emulator
    try:
        assert emu is not None and emu.running and emu.speed == 4.0
        assert callable(p.clock)  # the board's time scale, for the session's timers
        t0 = p.clock()
        p.write(b"\n")
        buf = b""
        end = time.monotonic() + 60  # a hang guard: the board talks at once
        while b" BOOT " not in buf and b" PARSE" not in buf and time.monotonic() < end:
            buf += p.read(256)
        # Its BOOT line, or its answer to the empty line: which one depends on the race between the
        # board's boot and the port's opening (pyserial empties the input when it opens a port; a
        # line sent before the board booted is not heard), never on whether the board runs.
        assert (b" BOOT " in buf or b" ER - " in buf) and p.clock() >= t0
        assert len(emu.boots) == 1
    finally:
        p.close()
    assert not emu.running and emu.port is None


def test_lock_files_live_in_a_private_directory():
    d = transport.lock_dir()
    assert d.is_dir() and (d.stat().st_mode & 0o077) == 0
