"""Pause and resume during a run (issue 25 §4): the protocol's HOLD and RESUME sent by the
streaming loop at the request of another thread (the keyboard's), on every engine: inline
(a lockstep emulator), a thread (a paced emulator), a child process (a pty from `armbridge
emulate esp32`); `armbridge run` on a pseudo-terminal, where space toggles the hold.

Truth is the board's: its HOLD / RESUME events and state, the set point frozen in its
telemetry while held, and the emulator's own log of executed waypoints (each exactly once,
in order). Nothing asserts a wall-clock time; the timeouts are hang guards."""
from __future__ import annotations

import fcntl
import json
import math
import os
import select
import shutil
import subprocess
import termios
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from cli_procs import ARMBRIDGE, default_signals, emulated_board

import armbridge.link.transport as transport
from armbridge.executor.client import BoardClient
from armbridge.executor.session import open_session
from armbridge.link import protocol as P
from armbridge.plans.format import make_plan, save_plan
from armbridge.robots import ARM3R, get_robot

MID = np.array([math.pi / 2, -math.pi / 2, 0.0])


def wave(k: int, dur_ms: int = 50) -> tuple[list[int], list[list[int]]]:
    """k waypoints dur_ms apart, a gentle wave around the middle of arm3r's ranges (mrad)."""
    t = 0.05 * np.arange(1, k + 1)
    q = MID + np.outer((1 - np.cos(2 * np.pi * 0.5 * t)) / 2, (0.3, 0.2, 0.3))
    return [dur_ms] * k, [P.to_milli(row) for row in q]


class Pauser:
    """Holds the run once `at` waypoints are done, and resumes it when the board has been
    held for `hold_s` of board time (seen in its telemetry); records what the board says."""

    def __init__(self, at: int, hold_s: float, from_thread: bool = False) -> None:
        self.at, self.hold_s, self.from_thread = at, hold_s, from_thread
        self.client = None
        self.samples: list[tuple[float, str, tuple[float, ...]]] = []
        self.events: list[tuple[float | None, str, tuple[str, ...]]] = []
        self.errors: list[str] = []
        self.held_at: float | None = None
        self.asked = self.resumed = False

    def _request(self, on: bool) -> None:
        if self.from_thread:  # as the keyboard's reader does: another thread
            t = threading.Thread(target=self.client.request_hold, args=(on,))
            t.start()
            t.join()
        else:
            self.client.request_hold(on)

    def on_progress(self, n: int) -> None:
        if n >= self.at and not self.asked:
            self.asked = True
            self._request(True)

    def on_telemetry(self, t: float, m: P.Telemetry) -> None:
        self.samples.append((t, m.state, tuple(np.round(m.target, 6))))
        if m.state == "HOLD" and self.held_at is None:
            self.held_at = t
        if self.held_at is not None and not self.resumed and t - self.held_at >= self.hold_s:
            self.resumed = True
            self._request(False)

    def on_event(self, t: float | None, ev: P.Event) -> None:
        self.events.append((t, ev.kind, tuple(ev.args)))

    def on_error(self, t: float | None, text: str) -> None:
        self.errors.append(text)

    def callbacks(self) -> dict:
        return {"on_telemetry": self.on_telemetry, "on_event": self.on_event, "on_error": self.on_error}

    def check(self, k: int) -> None:
        """The board reported HOLD then RESUME, once each; the set point stood still while held."""
        kinds = [e[1] for e in self.events if e[1] in ("HOLD", "RESUME")]
        assert kinds == ["HOLD", "RESUME"], (kinds, self.errors)
        held = [s for s in self.samples if s[1] == "HOLD"]
        assert len(held) >= 3, self.samples[-10:]
        assert len({s[2] for s in held}) == 1, "the set point moved while the board was held"
        assert held[-1][0] - held[0][0] >= 0.8 * self.hold_s
        done = [int(e[2][0]) for e in self.events if e[1] == "DONE"]
        assert done == sorted(set(done)) and done[-1] == k - 1, done  # never a waypoint twice


def executed(emu) -> list[tuple[int, tuple[int, ...]]]:
    return [(wid, values) for _, wid, values in emu.executed]


# ---------------------------------------------------------------- the client, every engine

# (a thread engine on a speed-0 board is not among them: that board runs as fast as the CPU lets it, so
# whether the hold lands before the plan's end would depend on the machine's load; a paced board's
# "auto" engine is the thread)
@pytest.mark.parametrize("url,engine", [("emu:esp32?speed=0", "inline"), ("emu:esp32", "auto")])
def test_a_hold_mid_plan_freezes_the_arm_and_the_plan_completes_after_resume(url, engine):
    k = 40
    durs, q = wave(k)
    p = Pauser(at=10, hold_s=1.0, from_thread=True)
    with open_session(url, ARM3R, rate_hz=50, engine=engine, calibration="ignore", **p.callbacks()) as c:
        p.client = c
        emu = c.port.emulator
        c.execute(durs, q, on_progress=p.on_progress)
        assert c.stat()[0] == "IDLE"
        assert executed(emu) == [(i, tuple(q[i])) for i in range(k)]  # every waypoint once, in order
        assert c.stats.waypoints_sent == k
    p.check(k)


def test_a_hold_longer_than_the_deadline_does_not_fail_the_run():
    k = 20
    durs, q = wave(k)  # 1 s of plan
    p = Pauser(at=5, hold_s=4.0)
    port = transport.open_port("emu:esp32?speed=0")
    try:
        c = BoardClient(port, ARM3R, **p.callbacks())
        p.client = c
        c.connect()
        c.set_rate(50)
        c.execute(durs, q, on_progress=p.on_progress, timeout=2.5)  # the hold alone is longer
        assert executed(port.emulator) == [(i, tuple(q[i])) for i in range(k)]
    finally:
        port.close()
    p.check(k)


@pytest.fixture
def board(tmp_path):
    yield from emulated_board(tmp_path)


def test_on_the_process_engine_a_hold_goes_out_of_band_mid_execute(board):
    """A board outside this process (another process's pty): the session runs in a child
    process; the hold crosses to it as a message its reader acts on at once."""
    emu, link = board
    k = 30
    durs, q = wave(k, 100)
    p = Pauser(at=8, hold_s=1.0, from_thread=True)
    with open_session(link, ARM3R, rate_hz=50, engine="process", calibration="ignore", **p.callbacks()) as c:
        p.client = c
        c.execute(durs, q, on_progress=p.on_progress)
        assert c.stat()[0] == "IDLE" and c.done_index == k - 1
        assert c.stats.waypoints_sent == k
    p.check(k)
    emu.wait_for(" HOLD")  # the board's own echo of its events
    emu.wait_for(" RESUME")


def test_resume_on_a_latched_board_is_refused_and_clears_nothing():
    """A hold never touches a latch. An e-stop while held ends the run on the latch as ever;
    a RESUME then (the key pressed again) is refused by the board (LATCHED), the refusal is
    said, and the board stays in ESTOP: only CLR clears it."""
    from armbridge.errors import ArmbridgeError
    from armbridge.executor.hold import HoldRequests, hold_turn

    k = 20
    durs, q = wave(k)
    port = transport.open_port("emu:esp32?speed=0")
    try:
        errors: list[str] = []
        stopped: list[bool] = []
        c: BoardClient

        def on_telemetry(t: float, m: P.Telemetry) -> None:
            if m.state == "HOLD" and not stopped:
                stopped.append(True)
                c.estop()  # Ctrl-C while held

        c = BoardClient(port, ARM3R, on_telemetry=on_telemetry, on_error=lambda t, text: errors.append(text))
        c.connect()
        c.set_rate(50)
        c.request_hold(True)  # before anything moves
        with pytest.raises(ArmbridgeError, match="e-stop latched"):
            c.execute(durs, q)
        assert c._held and port.emulator.state == "ESTOP"
        resume = HoldRequests()
        resume.request(False)
        hold_turn(c, resume)  # what the loop does with the next key
        assert any("refused RESUME" in e and "LATCHED" in e and "nothing was cleared" in e for e in errors), errors
        assert c._held  # still held as far as the host knows: nothing moves until CLR
        assert c.stat()[0] == "ESTOP" and port.emulator.state == "ESTOP"
        assert port.emulator.executed == []  # held from the start: no waypoint ran
    finally:
        port.close()


# ---------------------------------------------------------------- `armbridge run` at a terminal

def _plan(tmp_path: Path, k: int, duration: float) -> Path:
    robot = get_robot("arm3r")
    qs = [[1.5 + 0.3 * (i % 2), -1.5 + 0.1 * (i % 3), 0.0] for i in range(k)]
    path = tmp_path / "plan.json"
    save_plan(make_plan(robot, qs, duration), path)
    return path


def _on_the_terminal() -> None:
    """The pty is the child's controlling terminal: Ctrl-C typed on it is SIGINT."""
    default_signals()
    os.setsid()
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


class Terminal:
    """`armbridge ARGS` with stdin, stdout and stderr on a pty, as at a terminal: what it writes
    is collected by a thread; `type` is the user's keys."""

    def __init__(self, *args: str) -> None:
        self.master, slave = os.openpty()
        self.p = subprocess.Popen([ARMBRIDGE, *args], stdin=slave, stdout=slave, stderr=slave,
                                  preexec_fn=_on_the_terminal)
        os.close(slave)
        self.out = b""
        self._lock = threading.Lock()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        while True:
            try:
                if not select.select([self.master], [], [], 0.2)[0]:
                    if self.p.poll() is not None:
                        return
                    continue
                data = os.read(self.master, 65536)
            except OSError:
                return
            if not data:
                return
            with self._lock:
                self.out += data

    def text(self) -> str:
        with self._lock:
            return self.out.decode(errors="replace")

    def wait_for(self, what: str, timeout: float = 120.0) -> None:
        end = time.monotonic() + timeout
        while what not in self.text():
            assert time.monotonic() < end and self.p.poll() is None, (what, self.text()[-2000:])
            time.sleep(0.05)

    def type(self, keys: bytes) -> None:
        os.write(self.master, keys)

    def finish(self, timeout: float = 120.0) -> int:
        try:
            return self.p.wait(timeout=timeout)
        finally:
            time.sleep(0.3)  # the reader's last bytes
            os.close(self.master)


def test_space_at_the_terminal_holds_and_resumes_armbridge_run(tmp_path, board):
    emu, link = board
    k = 60    # 6 s of plan: room for the key to land on a loaded machine
    plan, js = _plan(tmp_path, k, 0.1), tmp_path / "run.json"
    term = Terminal("run", str(plan), "--port", link, "--json", str(js), "--rrd", str(tmp_path / "run.rrd"))
    try:
        term.wait_for("space or p: hold / resume")
        emu.wait_for(" DONE 2 ")  # the plan is running
        term.type(b" ")
        emu.wait_for(" HOLD")     # the board got HOLD ...
        term.wait_for("held (space resumes)")  # ... and the bar says so
        time.sleep(1.5)
        term.type(b"p")
        emu.wait_for(" RESUME")
        rc = term.finish()
    finally:
        if term.p.poll() is None:
            term.p.kill()
    assert rc == 0, term.text()[-3000:]
    s = json.loads(js.read_text())
    assert s["completed"] and s["waypoints_done"] == k and s["final_state"] == "IDLE"
    assert s["holds"] == 1 and s["held_s"] >= 1.0
    # the held time is reported apart, not in the measured duration (board time, not wall clock)
    assert s["measured_duration_s"] < s["planned_duration_s"] + 0.5 * s["held_s"], s
    assert "held (holds / time)" in term.text()


def test_ctrl_c_while_held_estops_as_ever(tmp_path, board):
    emu, link = board
    plan, js = _plan(tmp_path, 40, 0.25), tmp_path / "run.json"
    term = Terminal("run", str(plan), "--port", link, "--json", str(js), "--rrd", str(tmp_path / "run.rrd"),
                    "--no-progress")
    try:
        term.wait_for("space or p: hold / resume")
        emu.wait_for(" DONE 1 ")
        term.type(b" ")
        emu.wait_for(" HOLD")
        term.wait_for("held (space resumes)")  # no bar: a line
        term.type(b"\x03")  # Ctrl-C at the terminal: SIGINT
        rc = term.finish()
    finally:
        if term.p.poll() is None:
            term.p.kill()
    assert rc == 130, term.text()[-3000:]
    emu.wait_for(" ESTOP")
    s = json.loads(js.read_text())
    assert s["stopped_by"] == "SIGINT" and s["estop_sent"] and s["final_state"] == "ESTOP"
    assert s["holds"] == 1 and not s["completed"]


def test_no_keys_leaves_the_keyboard_alone(tmp_path):
    plan, js = _plan(tmp_path, 5, 0.2), tmp_path / "run.json"
    term = Terminal("run", str(plan), "--port", "emu:esp32?speed=0", "--json", str(js), "--rrd",
                    str(tmp_path / "run.rrd"), "--no-keys", "--no-progress")
    rc = term.finish()
    assert rc == 0 and "space or p" not in term.text(), term.text()[-2000:]
    assert json.loads(js.read_text())["holds"] == 0


def test_over_modbus_hold_and_resume_go_through_the_command_register():
    from require import missing

    if shutil.which("avr-gcc") is None or not os.path.isfile("/usr/include/simavr/sim_avr.h"):
        missing("the pump board's emulator needs avr-gcc and libsimavr-dev (scripts/setup.sh); it builds the .elf")
    robot = get_robot("soft3")
    k = 4
    plan = make_plan(robot, np.outer(np.arange(1, k + 1) / k, [0.4, 0.8, 0.9]), 0.5)
    p = Pauser(at=1, hold_s=2.0, from_thread=True)
    with open_session("modbus:emu:arduino_pump?speed=0&addr=5", robot, rate_hz=20, calibration="ignore",
                      **p.callbacks()) as c:
        p.client = c
        c.execute([500] * k, [[int(round(v * 1000)) for v in row] for row in plan.q], on_progress=p.on_progress,
                  timeout=3.0)  # 2 s of plan: the 2 s hold would pass it, if it counted
        assert c.done_index == k - 1
    kinds = [e[1] for e in p.events if e[1] in ("HOLD", "RESUME")]
    assert kinds == ["HOLD", "RESUME"], (kinds, p.errors)
    held = [s for s in p.samples if s[1] == "HOLD"]
    assert len(held) >= 3 and len({s[2] for s in held}) == 1


def test_draw_port_passes_the_keys_through(tmp_path, board):
    """`armbridge draw --port` runs its plan as `armbridge run` does, keys included."""
    emu, link = board
    js = tmp_path / "draw.json"
    term = Terminal("draw", "I", "--speed", "0.02", "--travel-speed", "0.1", "--out", str(tmp_path / "i.json"),
                    "--port", link, "--rrd", str(tmp_path / "draw.rrd"), "--json", str(js), "--no-progress")
    try:
        term.wait_for("space or p: hold / resume")
        emu.wait_for(" DONE 5 ")
        term.type(b" ")
        emu.wait_for(" HOLD")
        term.wait_for("held (space resumes)")
        time.sleep(1.0)
        term.type(b" ")
        emu.wait_for(" RESUME")
        term.wait_for("resumed")
        rc = term.finish()
    finally:
        if term.p.poll() is None:
            term.p.kill()
    assert rc == 0, term.text()[-3000:]
    s = json.loads(js.read_text())
    assert s["completed"] and s["holds"] == 1 and s["held_s"] >= 0.8
    assert "drawing error" in term.text()


def test_pause_keys_leave_a_terminal_alone_in_the_background():
    """A run started in the background (`armbridge run ... &`) whose stdin is still the terminal:
    setting the terminal's mode or reading it would stop the run (SIGTTOU, SIGTTIN), so the keys
    stay off."""
    code = (
        "import os, signal, sys\n"
        "from armbridge.executor.keys import PauseKeys\n"
        "signal.signal(signal.SIGTTOU, signal.SIG_IGN)\n"
        "os.setpgid(0, 0)\n"  # our own group: the terminal's foreground group is another one now
        "with PauseKeys(lambda on: None) as keys:\n"
        "    print('active' if keys.active else 'inactive', flush=True)\n"
    )
    master, slave = os.openpty()

    def fg_elsewhere() -> None:
        default_signals()
        os.setsid()
        fcntl.ioctl(0, termios.TIOCSCTTY, 0)  # the pty controls this session, its group is foreground

    try:
        r = subprocess.run([os.path.join(os.path.dirname(ARMBRIDGE), "python"), "-c",
                            "import os, subprocess, sys\n"
                            f"p = subprocess.run([sys.executable, '-c', {code!r}], stdout=subprocess.PIPE, text=True)\n"
                            "print(p.stdout.strip(), file=sys.stderr)\n"],
                           stdin=slave, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           preexec_fn=fg_elsewhere, timeout=60)
    finally:
        os.close(master)
        os.close(slave)
    assert r.stderr.strip().splitlines()[-1] == "inactive", r.stderr


def test_a_board_that_resets_while_held_is_held_again_before_anything_moves():
    """A reset forgets the hold (the board boots IDLE); the resync resends the rest of the
    plan, so the host sends HOLD again first: nothing runs until the user resumes."""
    k = 30
    durs, q = wave(k)
    port = transport.open_port("emu:esp32?speed=0")
    emu = port.emulator
    marks: dict[str, int] = {}

    class ResetWhileHeld(Pauser):
        def on_telemetry(self, t: float, m: P.Telemetry) -> None:
            if self.held_at is not None and "reset" not in marks and t - self.held_at >= 0.3:
                marks["reset"] = len(emu.executed)
                emu.reset()
            if self.held_at is not None and not self.resumed and t - self.held_at >= self.hold_s:
                marks["resume"] = len(emu.executed)
            super().on_telemetry(t, m)

    p = ResetWhileHeld(at=8, hold_s=2.0)
    try:
        c = BoardClient(port, ARM3R, **p.callbacks())
        p.client = c
        c.connect()
        c.set_rate(50)
        c.execute(durs, q, on_progress=p.on_progress)
        assert executed(emu) == [(i, tuple(q[i])) for i in range(k)]  # each once, in order, after the reset too
    finally:
        port.close()
    assert marks["resume"] == marks["reset"], marks  # nothing ran between the reset and the resume
    assert c.stats.resyncs >= 1
    assert any("forgot its hold" in e for e in p.errors), p.errors
    kinds = [e[1] for e in p.events if e[1] in ("HOLD", "RESUME", "BOOT")]
    assert kinds[kinds.index("HOLD"):] == ["HOLD", "BOOT", "HOLD", "RESUME"], kinds


def test_the_summary_counts_the_hold_and_leaves_it_out_of_the_measured_figures(tmp_path, monkeypatch):
    """run_plan on a lockstep emulator, held 2 s of board time at waypoint 6 by a stand-in for the
    keyboard: the summary's holds and held_s; the measured duration and the tracking against the
    plan come out as in the same run never held (the plan's clock stood still too)."""
    import armbridge.executor.pause as pause_mod
    from armbridge.executor.run import run_plan

    class Keys:  # PauseKeys' surface, pressing "space" from the board's own telemetry
        def __init__(self, on_hold) -> None:
            self.active = True
            self.client = on_hold.__self__  # the inline engine's BoardClient
            self.held_at: float | None = None
            self.resumed = False
            inner = self.client.on_telemetry

            def on_telemetry(t: float, m: P.Telemetry) -> None:
                inner(t, m)
                if self.held_at is None and self.client.done_index >= 5:
                    self.held_at = t
                    on_hold(True)
                elif self.held_at is not None and not self.resumed and t - self.held_at >= 2.0:
                    self.resumed = True
                    on_hold(False)

            self.client.on_telemetry = on_telemetry

        def __enter__(self):
            return self

        def __exit__(self, *exc) -> None:
            pass

    robot = get_robot("arm3r")
    qs = [[1.5 + 0.3 * (i % 2), -1.5 + 0.1 * (i % 3), 0.0] for i in range(16)]
    plan = make_plan(robot, qs, 0.25)
    plain = run_plan(plan, "emu:esp32?speed=0&seed=3", tmp_path / "plain.rrd", progress=False)
    monkeypatch.setattr(pause_mod, "PauseKeys", Keys)
    held = run_plan(plan, "emu:esp32?speed=0&seed=3", tmp_path / "held.rrd", progress=False, pause_keys=True,
                    timeout=10.0)
    assert plain.completed and held.completed and plain.holds == 0
    assert held.holds == 1 and 1.9 <= held.held_s <= 2.3, held.held_s
    assert abs(held.measured_duration_s - plain.measured_duration_s) < 0.1
    for name, tr in held.tracking_plan.items():
        assert tr.max <= 1.5 * plain.tracking_plan[name].max + 0.01, (name, tr, plain.tracking_plan[name])
    assert "held (holds / time)" in str([c for c in held.table().columns[0]._cells])
