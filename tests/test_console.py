"""`armbridge board`: the console against the emulated board, as real processes,
on every port kind (a pty device, a pyserial socket:// URL, emu:)."""
from __future__ import annotations

import json
import os
import select
import signal
import socket
import subprocess
import threading
import time

import pytest
import serial
from cli_procs import ARMBRIDGE, Proc, default_signals, emulated_board

from armbridge.link import protocol as P
from armbridge.robots import get_robot

pytestmark = pytest.mark.hil


@pytest.fixture
def board(tmp_path):
    yield from emulated_board(tmp_path)


def console(*args: str, stdin=subprocess.DEVNULL) -> subprocess.CompletedProcess:
    return subprocess.run([ARMBRIDGE, "board", *args], capture_output=True, text=True, timeout=120, stdin=stdin)


def ok_json(*args: str) -> dict:
    r = console(*args, "--json", "-")
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)                       # stdout carries the JSON alone


def estop(link: str) -> None:
    """The e-stop byte, written as any serial terminal would."""
    with serial.Serial(link, 115200) as s:
        s.write(P.ESTOP_BYTE)
        s.flush()


def wait_state(link: str, state: str) -> dict:
    end = time.monotonic() + 60  # a hang guard: each `board state` is a process that may start slowly
    while True:
        st = ok_json("state", "--port", link)
        if st["state"] == state or time.monotonic() > end:
            return st
        time.sleep(0.05)


def test_info_names_the_board_and_its_limits(board):
    _, link = board
    d = ok_json("info", "--port", link)
    arm = get_robot("arm3r")
    assert (d["fw"], d["protocol"], d["joints"], d["queue"], d["watchdog_ms"], d["state"]) == \
        ("arm3r", 2, 3, 32, 1000, "IDLE")
    assert [(j["min_mrad"], j["max_mrad"], j["vmax_mrad_s"]) for j in d["limits"]] == \
        list(zip(P.to_milli(arm.q_min), P.to_milli(arm.q_max), P.to_milli(arm.v_max)))
    r = console("info", "--port", link)
    assert r.returncode == 0 and "arm3r 0.1.0" in r.stdout and "joint limits" in r.stdout


def test_state_ping_and_rate(board):
    _, link = board
    st = ok_json("state", "--port", link)
    assert st["state"] == "IDLE" and not st["latched"] and st["board_time_s"] > 0
    p = ok_json("ping", "--port", link, "-c", "3")
    assert p["count"] == 3 and len(p["rtt_ms"]) == 3 and 0 < p["min_ms"] <= p["mean_ms"] <= p["max_ms"]
    r = console("rate", "7", "--port", link)
    assert r.returncode == 0 and "telemetry rate 7 Hz" in r.stdout
    assert ok_json("info", "--port", link)["rate_hz"] == 7  # the board keeps it across sessions
    r = console("rate", "500", "--port", link)
    assert r.returncode == 2 and "less than or equal to 100" in r.stderr


def test_clear_after_an_estop(board):
    emu, link = board
    estop(link)
    emu.wait_for(" ESTOP*")
    st = wait_state(link, "ESTOP")
    assert st["state"] == "ESTOP" and st["latched"]
    r = console("state", "--port", link)
    assert "latched: `armbridge board clear --port" in r.stdout
    # Without a terminal to ask on, and without --yes: refused, nothing sent.
    r = console("clear", "--port", link)
    assert r.returncode == 2 and "pass --yes" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert ok_json("state", "--port", link)["state"] == "ESTOP"
    r = console("clear", "--port", link, "--yes")
    assert r.returncode == 0 and "cleared ESTOP: the board is IDLE" in r.stdout, r.stderr
    emu.wait_for(" CLEAR*")
    assert ok_json("state", "--port", link)["state"] == "IDLE"
    r = console("clear", "--port", link, "--yes")
    assert r.returncode == 0 and "nothing to clear: the board is IDLE" in r.stdout
    # nothing latched: nothing to confirm, even without a terminal or --yes
    r = console("clear", "--port", link)
    assert r.returncode == 0 and "nothing to clear: the board is IDLE" in r.stdout, r.stderr


def test_json_to_a_file_keeps_the_table(board, tmp_path):
    _, link = board
    out = tmp_path / "sub" / "state.json"
    r = console("state", "--port", link, "--json", str(out))
    assert r.returncode == 0, r.stderr
    assert "state IDLE" in r.stdout and json.loads(out.read_text())["state"] == "IDLE"
    r = console("ping", "--port", link, "-c", "2", "--json=-")
    assert r.returncode == 0 and json.loads(r.stdout)["count"] == 2 and "PING 1" not in r.stdout + r.stderr


def _on_a_terminal(args: list[str], answer: bytes) -> tuple[int, str]:
    """Run with stdin and stdout on a pty, as at a terminal; answer the prompt."""
    master, slave = os.openpty()
    try:
        p = subprocess.Popen([ARMBRIDGE, "board", *args], stdin=slave, stdout=slave, stderr=slave,
                             preexec_fn=default_signals)
        out = b""
        end = time.monotonic() + 60
        while b"Clear it?" not in out and b"nothing to clear" not in out and time.monotonic() < end:
            if select.select([master], [], [], 0.2)[0]:
                out += os.read(master, 4096)
        os.write(master, answer)
        rc = p.wait(timeout=60)
        while select.select([master], [], [], 0.2)[0]:
            try:
                out += os.read(master, 4096)
            except OSError:
                break
        return rc, out.decode(errors="replace")
    finally:
        os.close(master)
        os.close(slave)


def test_clear_asks_at_a_terminal(board):
    emu, link = board
    estop(link)
    assert wait_state(link, "ESTOP")["state"] == "ESTOP"
    rc, out = _on_a_terminal(["clear", "--port", link], b"n\n")
    assert "The board is latched in ESTOP. Clear it?" in out and rc == 1 and "not cleared" in out
    assert ok_json("state", "--port", link)["state"] == "ESTOP"
    rc, out = _on_a_terminal(["clear", "--port", link], b"y\n")
    assert rc == 0 and "cleared ESTOP: the board is IDLE" in out, out
    assert ok_json("state", "--port", link)["state"] == "IDLE"


def test_monitor_shows_telemetry_and_events_until_ctrl_c(board):
    emu, link = board
    mon = Proc("board", "monitor", "--port", link, "--rate", "20")
    try:
        mon.wait_for("arm3r 0.1.0 on ")
        first = mon.wait_for("  T IDLE ")
        assert len(first.split()) == 1 + 6 + 2 * 4  # time, T state done - free n, q x3, target x3
        estop(link)  # a serial terminal beside the monitor: the board's event shows up live
        mon.wait_for("EV ESTOP")
        mon.wait_for("  T ESTOP ")
        mon.p.send_signal(signal.SIGINT)
        rc, err = mon.finish()
    finally:
        mon.stop()
    assert rc == 0, err  # Ctrl-C is how a monitor ends
    summary = mon.lines[-1]
    assert summary.startswith("monitor stopped: ") and "telemetry samples" in summary
    samples = int(summary.split()[2])
    assert samples >= 2 and samples == sum(1 for line in mon.lines if "  T " in line), mon.lines


def test_monitor_draws_a_live_view_on_a_terminal(board):
    _, link = board
    master, slave = os.openpty()
    try:
        p = subprocess.Popen([ARMBRIDGE, "board", "monitor", "--port", link, "--rate", "20"], stdin=slave,
                             stdout=slave, stderr=slave, preexec_fn=default_signals)
        out = b""
        end = time.monotonic() + 60
        while b"set point (rad)" not in out and time.monotonic() < end:
            if select.select([master], [], [], 0.2)[0]:
                out += os.read(master, 65536)
        p.send_signal(signal.SIGINT)
        rc = p.wait(timeout=30)
        while select.select([master], [], [], 0.2)[0]:
            try:
                out += os.read(master, 65536)
            except OSError:
                break
    finally:
        os.close(master)
        os.close(slave)
    text = out.decode(errors="replace")
    assert "set point (rad)" in text and "Ctrl-C stops" in text and "board time" in text
    assert rc == 0 and "monitor stopped: " in text


def test_the_console_works_on_an_emu_url():
    d = ok_json("info", "--port", "emu:esp32?seed=2")
    assert d["fw"] == "arm3r" and d["joints"] == 3


class SocketBridge:
    """socket://127.0.0.1:PORT relayed to the emulator's pty: a pyserial URL to a real board."""

    def __init__(self, link: str) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.link = link
        self.stop = threading.Event()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        conn, _ = self.server.accept()
        fd = os.open(self.link, os.O_RDWR | os.O_NOCTTY)
        try:
            while not self.stop.is_set():
                ready = select.select([conn, fd], [], [], 0.05)[0]
                if conn in ready:
                    data = conn.recv(4096)
                    if not data:
                        break
                    os.write(fd, data)
                if fd in ready:
                    conn.sendall(os.read(fd, 4096))
        finally:
            os.close(fd)
            conn.close()
            self.server.close()


def test_the_console_works_on_a_pyserial_url(board):
    _, link = board
    bridge = SocketBridge(link)
    try:
        d = ok_json("info", "--port", f"socket://127.0.0.1:{bridge.port}")
    finally:
        bridge.stop.set()
    assert d["fw"] == "arm3r" and d["state"] == "IDLE" and len(d["limits"]) == 3


def test_port_trouble_is_one_line_with_the_documented_exit_code(board, tmp_path):
    _, link = board
    r = console("state", "--port", "/dev/does-not-exist-armbridge")
    assert r.returncode == 2 and r.stderr.strip() == (
        "error: no such device /dev/does-not-exist-armbridge: is the board plugged in? "
        "(ls /dev/serial/by-id lists those that are)")
    r = console("info", "--port", "emu:esp99")
    assert r.returncode == 2 and "esp99" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    # Busy: a monitor holds the port; a second console is told who.
    mon = Proc("board", "monitor", "--port", link)
    try:
        mon.wait_for("arm3r 0.1.0 on ")
        r = console("state", "--port", link)
        assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1
        assert f"port {link} is busy: 'armbridge board monitor --port {link}' (pid {mon.p.pid}) holds it" in r.stderr
    finally:
        mon.stop()
    # Nobody answers.
    master, slave = os.openpty()
    try:
        r = console("state", "--port", os.ttyname(slave), "--timeout", "0.5")
    finally:
        os.close(master)
        os.close(slave)
    assert r.returncode == 1 and "no answer to HELLO" in r.stderr and len(r.stderr.strip().splitlines()) == 1
