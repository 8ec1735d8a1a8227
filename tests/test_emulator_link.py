"""`armbridge emulate --link P` owns P: a second emulator is refused with one
line naming the owner, a dead owner's link is taken over with a note, and an
emulator removes only a link that is still its own."""
import os
import signal
import subprocess
import sys
import time

import pytest
import serial

from armbridge.emulator.board import EmulatedBoard
from armbridge.emulator.pty import lock_path
from armbridge.errors import ArmbridgeError
from armbridge.link import protocol as P

pytestmark = pytest.mark.hil


def emulate(link, *args):
    """`armbridge emulate esp32 --link LINK` as a user runs it (cli.main: errors are one line)."""
    code = "from armbridge.cli import main; main()"
    return subprocess.Popen([sys.executable, "-c", code, "emulate", "esp32", "--link", str(link), "--quiet",
                             "--speed", "2", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def stop(proc, sig=signal.SIGINT):
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        return proc.communicate(timeout=60)  # it ends at once: a hang guard
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def hello_ok(path) -> bool:
    with serial.Serial(str(path), 115200, timeout=0.05) as s:
        s.reset_input_buffer()
        s.write(P.encode(1, "HELLO", P.PROTOCOL_VERSION, 9, 1))
        buf = b""
        end = time.monotonic() + 60  # the answer comes at once: a hang guard
        while time.monotonic() < end:
            buf += s.read(512)
            if b" OK 1 " in buf:
                return True
    return False


def test_a_second_emulator_is_refused_and_the_first_keeps_its_link(tmp_path):
    link = tmp_path / "arm"
    first = emulate(link)
    try:
        line = first.stdout.readline()
        assert line.startswith("esp32 emulator on /dev/pts/"), line + stop(first)[1]
        port = line.split()[3]
        assert os.path.realpath(link) == port
        assert open(lock_path(str(link))).read().strip() == str(first.pid)

        second = emulate(link)
        out, err = second.communicate(timeout=60)
        assert second.returncode == 2 and out == ""
        assert err.count("\n") == 1 and "Traceback" not in err
        assert f"link {link}" in err and f"pid {first.pid}" in err, err

        assert os.path.realpath(link) == port  # untouched by the refused one
        assert hello_ok(link)                  # and the first still serves on it
    finally:
        out, err = stop(first)
    assert first.returncode == 0, err
    assert not os.path.lexists(link) and not os.path.exists(lock_path(str(link)))


def test_a_dead_owners_link_is_taken_over_with_a_note(tmp_path):
    link = tmp_path / "arm"
    dead = emulate(link)
    assert dead.stdout.readline().startswith("esp32 emulator on ")
    stop(dead, signal.SIGKILL)  # no clean-up at all: the link and the lock stay behind
    assert os.path.lexists(link) and open(lock_path(str(link))).read().strip() == str(dead.pid)

    heir = emulate(link)
    try:
        line = heir.stdout.readline()
        assert line.startswith("esp32 emulator on /dev/pts/"), line + stop(heir)[1]
        note = heir.stdout.readline()
        assert note.startswith("note: ") and f"pid {dead.pid}" in note and str(link) in note
        assert os.path.realpath(link) == line.split()[3]
        assert open(lock_path(str(link))).read().strip() == str(heir.pid)
        assert hello_ok(link)
    finally:
        out, err = stop(heir)
    assert heir.returncode == 0, err
    assert not os.path.lexists(link)


def test_an_emulator_removes_only_its_own_link(tmp_path):
    link = str(tmp_path / "arm")
    emu = EmulatedBoard("esp32", speed=1, link=link).start()
    try:
        with pytest.raises(ArmbridgeError, match=rf"link {link} is owned by a running emulator \(pid {os.getpid()}"):
            EmulatedBoard("esp32", speed=1, link=link).start()
        assert os.path.realpath(link) == emu.port
        os.unlink(link)
        os.symlink("/dev/null", link)  # someone else put their own link there meanwhile
    finally:
        emu.stop()
    assert os.readlink(link) == "/dev/null"
    assert not os.path.exists(lock_path(link))
    emu2 = EmulatedBoard("esp32", speed=1, link=link).start()  # the path is free again
    try:
        assert os.path.realpath(link) == emu2.port and emu2.link_note is None
    finally:
        emu2.stop()
    assert not os.path.lexists(link)
