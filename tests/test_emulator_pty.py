"""The emulated ESP32 board over a real pseudo-terminal, driven with pyserial.

The host side here is a minimal v2 test client (tests/emu_host.py: the host
codec with a seq and the link epoch); the real host client lives in
armbridge.executor. The board runs in lockstep, coupled to this host
(`EmulatedBoard.couple`: its thread runs at most HOST_LEAD_S of sim time past
the host's latest read), and the host keeps its time on the sim clock (its
keep-alive, its waits), so nothing here depends on how fast the machine is: a
host starved of the CPU finds the board where it left it, not latched in WDOG.
Waits are bounded in sim time, and by wall time only as a hang guard: every
assertion is about what the board said and the emulator recorded.
"""
import os
import select
import time

import numpy as np
import pytest
import serial

from armbridge.emulator.board import EmulatedBoard
from armbridge.emulator.faults import Faults
from armbridge.emulator.pty import open_pty
from armbridge.link import protocol as P
from emu_host import Codec, done_ev, is_reply

pytestmark = pytest.mark.hil

SPEED = 0  # lockstep, coupled to the host below
HANG_S = 120.0  # wall-clock guard of every wait: only a hang reaches it


def started(emu):
    """Start the emulator's thread on its pty and couple it to this test's host."""
    emu.start()
    emu.couple()
    return emu


class Host:
    def __init__(self, emu, port=None):
        self.emu = emu
        self.codec = Codec()
        self.ser = serial.Serial(port or emu.port, 115200, timeout=0.01)
        self.lines = []
        self.raw = b""
        self._sent = emu.now()
        self.keepalive = True

    @property
    def seq(self):
        return self.codec.seq

    def close(self):
        self.ser.close()

    def write(self, data):
        self.ser.write(data)
        self._sent = self.emu.now()

    def send(self, verb, *args):
        self.write(self.codec.line(verb, *args))
        return self.codec.seq

    def hello(self, session, timeout=2.0):
        self.write(self.codec.hello(session))
        return self.wait_reply(self.codec.seq, timeout)

    def pump(self):
        if self.keepalive and self.emu.now() - self._sent > 0.25:  # the board's watchdog: 1 s of its time
            self.send("PING")
        self.emu.host_reading()  # as transport.Port.read does: the coupled board runs while its host reads
        data = self.ser.read(4096)
        self.raw += data
        self.lines += self.codec.feed(data)

    def _until(self, found, timeout, what):
        """pump() until found() returns a line, within `timeout` s of sim time."""
        end, guard = self.emu.now() + timeout, time.monotonic() + HANG_S
        while True:
            self.pump()
            line = found()
            if line is not None:
                return line
            assert self.emu.now() < end and time.monotonic() < guard, \
                f"no {what} within {timeout} s; last lines {self.lines[-4:]}"

    def wait(self, verb, pred=lambda a: True, timeout=3.0, start=0):
        return self._until(lambda: next((line for line in self.lines[start:] if line[1] == verb and pred(line[2])),
                                        None), timeout, verb)

    def request(self, verb, *args, timeout=2.0):
        return self.wait_reply(self.send(verb, *args), timeout)

    def wait_reply(self, seq, timeout=2.0):
        return self._until(lambda: next((line for line in self.lines if is_reply(line, seq)), None), timeout,
                           f"reply to {seq}")

    def run_for(self, seconds):
        """Let `seconds` of sim time pass, reading (and keeping the board alive) meanwhile."""
        end = self.emu.now() + seconds
        self._until(lambda: True if self.emu.now() >= end else None, seconds + 1.0, "time")


@pytest.fixture
def board():
    emu = started(EmulatedBoard("esp32", speed=SPEED))
    host = Host(emu)
    yield emu, host
    host.close()
    emu.stop()
    assert emu.crash is None, emu.crash


def test_open_pty_is_raw_and_named():
    p = open_pty()
    try:
        assert os.path.exists(p.name) and p.name.startswith("/dev/pts/")
        s = serial.Serial(p.name, 115200, timeout=0.2)
        s.write(b"abc\n")
        got, end = b"", time.monotonic() + HANG_S  # the kernel hands the bytes over at once: a hang guard
        while got != b"abc\n" and len(got) < 4 and time.monotonic() < end:
            if select.select([p.master], [], [], 0.05)[0]:
                got += os.read(p.master, 100)
        assert got == b"abc\n"
        os.write(p.master, b"x\r\n")
        assert s.read(3) == b"x\r\n"  # raw: no CR/LF translation
        s.close()
        time.sleep(0.02)
        try:
            echoed = os.read(p.master, 100)
        except BlockingIOError:
            echoed = b""
        assert echoed == b""  # no echo
    finally:
        p.close()


def test_hello_waypoints_telemetry_done(board):
    emu, h = board
    ok = h.hello(4242)
    assert ok[1] == "OK" and ok[2][2:] == ["arm3r", "0.1.0", "2", "3", "32", "25", "1000", "-", "-", "IDLE"]
    assert h.request("LIM", 2)[2][2:] == ["2", "-3142", "0", "3000"]
    targets = [(2000, -1000, 500), (1000, -2000, -500), (1800, -1300, 200)]
    assert h.request("W", 1, 300, *targets[0])[1] == "OK"
    h.wait("EV", done_ev(1))  # the queue is empty: the arm holds waypoint 1 however late the host looks
    assert emu.positions() == pytest.approx(np.array(targets[0]) / 1000, abs=0.03)
    for i, q in enumerate(targets[1:], start=2):
        assert h.request("W", i, 300, *q)[1] == "OK"
    last = h.wait("EV", done_ev(3))
    h.wait("T", lambda a: int(a[0]) >= int(last[2][0]) + 300)
    assert emu.positions() == pytest.approx(np.array(targets[2]) / 1000, abs=0.01)
    tel = [line for line in h.lines if line[1] == "T"]
    assert len(tel) >= 10
    q_meas = np.array([int(x) for x in tel[-1][2][4:7]]) / 1000
    assert q_meas == pytest.approx(np.array(targets[2]) / 1000, abs=0.01)
    assert [(i, v) for _, i, v in emu.executed] == [(i + 1, q) for i, q in enumerate(targets)]
    # Opening the port can catch a line the board was half-way through sending:
    # only lines after the HELLO reply must all decode.
    first = next(i for i, line in enumerate(h.lines) if line[1] == "OK")
    bad = [line for line in h.lines[first:] if line[1] == "BAD"]
    assert not bad, (bad, [line for line in h.lines[:first] if line[1] == "BAD"])


def test_bad_lines_get_error_replies_and_the_board_keeps_running(board):
    """Garbage, an overlong line, a bad CRC, an unknown verb, a waypoint out of
    range: each gets its error reply over the pty, nothing moves, and the board
    answers normally afterwards."""
    emu, h = board
    assert h.hello(77)[1] == "OK"
    q0 = emu.positions()

    def error_after(data):
        start = len(h.lines)
        h.write(data)
        return h.wait("ER", start=start)[2]

    assert error_after(b"\x01\xffgarbage\n")[:3] == ["-", "1", "PARSE"]
    assert error_after(b"9" * 300 + b"\n")[:3] == ["-", "3", "LONG"]
    good = P.encode(h.seq + 1, "PING", epoch=h.codec.epoch)  # built, not sent: the seq is not used up
    assert error_after(good[:-9] + b"00000000\n")[:3] == ["-", "2", "CRC"]
    stale = P.encode(h.seq + 1, "PING", epoch=h.codec.epoch - 1)  # the same line in an earlier epoch
    assert error_after(stale)[:3] == ["-", "2", "CRC"]
    assert h.request("JUMP")[2][1:3] == ["4", "VERB"]
    assert h.request("W", 1, 100, 5000, 0, 0)[2][1:3] == ["6", "RANGE"]
    assert h.request("W", 2, 100, 1000)[2][1:3] == ["5", "ARGS"]
    assert h.request("PING")[1] == "OK"
    h.run_for(0.2)
    assert emu.positions() == pytest.approx(q0, abs=0.01)
    assert emu.executed == [] and emu.state == "IDLE" and emu.crash is None


def test_reset_mid_motion_prints_boot_and_keeps_done(board):
    emu, h = board
    h.hello(99)
    h.request("W", 1, 200, 2000, -1000, 500)
    h.request("W", 2, 3000, 500, -2500, -1000)
    h.wait("EV", lambda a: a[1] == "DONE" and a[2] == "1")  # waypoint 2 starts in this tick
    mark = len(h.raw)
    emu.reset()
    h.keepalive = False
    # A reset cuts the line on the wire, so BOOT may arrive glued to a partial
    # line (as on a real board); look for it in the byte stream.
    h._until(lambda: True if b" BOOT arm3r 0.1.0 2 IDLE*" in h.raw[mark:] else None, 3.0, "BOOT")
    assert len(emu.resets) == 1 and len(emu.boots) == 2
    assert emu.outputs_off_at[-1] == pytest.approx(emu.resets[-1])
    h.keepalive = True
    hello = h.hello(99)
    assert hello[2][-3:] == ["1", "-", "IDLE"]  # done 1 survived the reset; nothing queued in the new boot
    assert [(i, v) for _, i, v in emu.executed] == [(1, (2000, -1000, 500))]


def test_estop_with_full_queue_latches_until_clr(board):
    emu, h = board
    h.hello(5)
    # 20 s waypoints: none finishes while the host fills the queue, however slow the host
    replies = [h.request("W", i, 20000, 1571 + (300 if i % 2 == 0 else -300), -1571, 0) for i in range(33)]
    assert all(r[1] == "OK" for r in replies), [r for r in replies if r[1] != "OK"]
    st = h.request("STAT")
    assert st[2][1] == "0" and st[2][2] == "RUN"  # queue full
    assert emu.hal.outputs_enabled
    mark = len(h.lines)
    h.write(b"\x98")
    h.wait("EV", lambda a: a[1] == "ESTOP", start=mark)
    assert len(emu.estop_byte_at) == 1
    latency = emu.outputs_off_at[-1] - emu.estop_byte_at[-1]
    assert 0 <= latency <= 0.010, latency
    h.run_for(0.3)
    assert emu.state == "ESTOP" and not emu.hal.outputs_enabled
    assert emu.hal.efforts[-1][0] < emu.estop_byte_at[-1]  # nothing written since
    assert h.request("W", 100, 100, 1571, -1571, 0)[2][1:3] == ["9", "LATCHED"]
    assert not emu.hal.outputs_enabled
    h.request("CLR")
    h.wait("EV", lambda a: a[1] == "CLEAR")
    h.run_for(0.05)
    assert emu.state == "IDLE" and emu.hal.outputs_enabled


def test_watchdog_when_host_goes_silent(board):
    emu, h = board
    h.hello(6)
    for i in range(4):
        h.request("W", i, 1000, 1571 + 400 * (-1) ** i, -1571, 0)
    h.keepalive = False
    t0 = emu.now()  # at most HOST_LEAD_S past the board taking in the last line (its reply was read)
    ev = h.wait("EV", lambda a: a[1] == "WDOG", timeout=2.0)
    assert emu.state == "WDOG"
    t_wdog = int(ev[2][0]) / 1000.0  # the board's clock is the sim's
    assert 1.0 - emu.HOST_LEAD_S - 0.011 <= t_wdog - t0 <= 1.0 + 0.011
    assert emu.hal.efforts[-1][1] == (0.0, 0.0, 0.0)
    assert len(emu.executed) < 4


def test_port_survives_host_close_and_symlink(tmp_path):
    link = str(tmp_path / "arm0")
    with started(EmulatedBoard("esp32", speed=SPEED, link=link)) as emu:
        assert os.path.realpath(link) == emu.port
        h = Host(emu, port=link)
        assert h.hello(1)[1] == "OK"
        h.close()
        time.sleep(0.1)
        h = Host(emu, port=link)
        h.ser.reset_input_buffer()
        assert h.hello(1)[1] == "OK"
        h.close()
    assert not os.path.lexists(link)


def test_link_faults_over_pty_are_counted():
    """PINGs one at a time, each waiting for its answer (or for the next line when
    a fault ate it), until both lanes have carried 500 bytes and met every fault
    kind: what ends the loop is the emulator's counters, not a clock."""
    kinds = ("drop", "dup", "corrupt")

    def enough(c):
        return all(c[lane]["bytes"] > 500 and all(c[lane][k] > 0 for k in kinds) for lane in ("rx", "tx"))

    with started(EmulatedBoard("esp32", speed=SPEED, faults=Faults(drop=0.02, dup=0.02, corrupt=0.02),
                               seed=3)) as emu:
        h = Host(emu)
        h.keepalive = False
        for _ in range(400):
            if enough(emu.counters):
                break
            seq, start = h.send("PING"), len(h.lines)
            end = emu.now() + 0.5  # a lost line gets no answer: the next PING after 0.5 s of sim time
            while not any(is_reply(line, seq) or line[1] in ("ER", "BAD") for line in h.lines[start:]):
                if emu.now() > end:
                    break
                h.pump()
        c = emu.counters
    assert enough(c), c
    for lane in ("rx", "tx"):
        for kind in kinds:
            assert c[lane][kind] < c[lane]["bytes"] * 0.06
    assert emu.state != "ESTOP"
    assert any(line[1] == "OK" for line in h.lines) and any(line[1] in ("ER", "BAD") for line in h.lines)


def _run_cli(*args):
    import signal
    import subprocess
    import sys

    code = "import typer; from armbridge.emulator.command import emulate_cmd; typer.run(emulate_cmd)"
    # Ctrl-C as at a terminal: a run started in the background (`make test &`)
    # would hand the child an ignored SIGINT, which Python then keeps.
    return subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def test_cli_serves_a_board_until_ctrl_c(tmp_path):
    import signal

    link = str(tmp_path / "arm")
    proc = _run_cli("esp32", "--link", link, "--speed", "2", "--drop", "0", "--seed", "4", "--quiet")
    try:
        first = proc.stdout.readline()
        assert first.startswith("esp32 emulator on /dev/pts/") and f"(link {link})" in first
        port = first.split()[3]
        assert os.path.realpath(link) == port
        s = serial.Serial(link, 115200, timeout=0.05)
        s.write(P.encode(1, "HELLO", P.PROTOCOL_VERSION, 3, 1))
        buf = b""
        end = time.monotonic() + HANG_S  # the reply comes at once: a hang guard
        while b" OK 1 32 arm3r" not in buf and time.monotonic() < end:
            buf += s.read(512)
        s.close()
        assert b" OK 1 32 arm3r" in buf
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=HANG_S)  # it ends at once: a hang guard
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "host->board:" in out and "board->host:" in out and "resets: 0" in out
    assert not os.path.lexists(link)


def test_ptmx_fallback_gives_a_working_pty():
    from armbridge.emulator.pty import _open_via_ptmx

    master, slave, name = _open_via_ptmx()
    try:
        assert os.path.exists(name)
        s = serial.Serial(name, 115200, timeout=0.2)
        os.write(master, b"hi\n")
        assert s.read(3) == b"hi\n"
        s.close()
    finally:
        os.close(master)
        os.close(slave)
