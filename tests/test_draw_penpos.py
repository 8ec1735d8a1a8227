"""Pen heights and the pen's settle as options (issue 25 §4): PENPOS end to end.

On the emulated boards (both rigs, CPython and the real MicroPython interpreter)
the pen touches the paper only where the servo's pulse reaches the rig's contact
width, so a down width short of it draws nothing and the run's summary says so;
`draw` keeps the settings in the plan and `run` sends them unless its command
line says otherwise; CALID keeps them across a power cycle; a board without a
pen servo refuses them before any waypoint; bad values are one line, before any
port opens. The firmware's own logic on a fake HAL: tests/firmware/test_fw_arm_pen.py."""
from __future__ import annotations

import json
import os
import select
import shutil
import subprocess

import pytest
from rich.console import Console
from typer.testing import CliRunner

from armbridge.cli import build_app
from armbridge.draw.build import build
from armbridge.draw.sources import text_lines
from armbridge.emulator.board import EmulatedBoard
from armbridge.emulator.simhal import PEN_CONTACT_US, SimHal
from armbridge.errors import ArmbridgeError
from armbridge.executor.run import run_plan
from armbridge.executor.session import open_session
from armbridge.plans.format import load_plan
from armbridge.resources import firmware_dir
from armbridge.robots import ARM3R, get_robot
from cli_procs import ARMBRIDGE
from require import require_micropython

SHORT = 1500  # a down width that stops short of the default rig's contact width
assert 1200 < SHORT < PEN_CONTACT_US < 1700   # the default rig: contact between the default up and down


def _plan(text: str = "I"):
    return build(text_lines(text), get_robot("arm3r"), name=text, source=f"text {text!r}", size=0.05,
                 speed=0.03).plan


RIGS = [pytest.param("", id="effort"), pytest.param("&servos=pca9685", id="pca9685"),
        pytest.param("&interpreter=micropython", id="effort-micropython", marks=pytest.mark.hil),
        pytest.param("&servos=pca9685&interpreter=micropython", id="pca9685-micropython", marks=pytest.mark.hil)]


@pytest.mark.parametrize("rig", RIGS)
def test_a_down_width_short_of_the_paper_draws_nothing(rig, ports, tmp_path):
    if "micropython" in rig:
        require_micropython()
    plan = _plan()
    url = "emu:esp32?speed=0" + rig
    s = run_plan(plan, url, tmp_path / "a.rrd", progress=False)
    d = s.drawing
    assert s.completed and s.pen_pos is None and d["pen_down_samples"] > 50
    assert d["pen_untouched"] < 0.2 * d["pen_down_samples"], d  # only while the pen travels down
    s = run_plan(plan, url, tmp_path / "b.rrd", progress=False, pen_pos={"down_us": SHORT})
    d = s.drawing
    assert s.completed and s.pen_pos == {"up_us": 1200, "down_us": SHORT, "settle_ms": 150}
    assert d["pen_down_samples"] > 50 and d["pen_untouched"] == d["pen_down_samples"], d
    con = Console(record=True, width=200)
    con.print(s.table())
    assert f"{d['pen_untouched']} of {d['pen_down_samples']} pen-down samples did not touch" in con.export_text()


def test_the_settle_option_is_the_boards_dwell(ports, tmp_path):
    """--pen-wait: each pen-down segment waits it out on the board before it moves."""
    plan = _plan()
    s = run_plan(plan, "emu:esp32?speed=0", tmp_path / "r.rrd", progress=False, pen_pos={"settle_ms": 600})
    assert s.completed and s.pen_pos["settle_ms"] == 600
    emu = ports[0].emulator
    done = {wid: ms for ms, wid, _ in emu.executed}
    first_down = int(next(i for i in range(1, plan.k) if plan.pen[i] == 1 and plan.pen[i - 1] == 0))
    assert done[first_down] - done[first_down - 1] >= 1000 * plan.durations[first_down] + 600 - 10


def test_draw_keeps_the_settings_and_the_command_line_wins(tmp_path):
    out, js = tmp_path / "i.json", tmp_path / "s.json"
    r = CliRunner().invoke(build_app(), ["draw", "I", "--size", "0.05", "--speed", "0.03", "--out", str(out),
                                         "--pen-down", str(SHORT), "--pen-wait", "100",
                                         "--port", "emu:esp32?speed=0", "--rrd", str(tmp_path / "a.rrd"),
                                         "--json", str(js), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "pen heights (PENPOS)" in r.output and "pen on the paper (emulated)" in r.output
    assert load_plan(out).provenance["drawing"]["pen_pos"] == {"down_us": SHORT, "settle_ms": 100}
    s = json.loads(js.read_text())
    assert s["pen_pos"] == {"up_us": 1200, "down_us": SHORT, "settle_ms": 100}
    assert s["drawing"]["pen_untouched"] == s["drawing"]["pen_down_samples"] > 0
    # `run` of that plan: the plan's settings, the command line's over them
    r = CliRunner().invoke(build_app(), ["run", str(out), "--port", "emu:esp32?speed=0", "--pen-down", "1650",
                                         "--rrd", str(tmp_path / "b.rrd"), "--json", str(js), "--no-progress",
                                         "--no-keys"])
    assert r.exit_code == 0, r.output
    s = json.loads(js.read_text())
    assert s["pen_pos"] == {"up_us": 1200, "down_us": 1650, "settle_ms": 100}
    assert s["drawing"]["pen_untouched"] < 0.2 * s["drawing"]["pen_down_samples"]


def test_a_board_without_a_pen_refuses_it_before_any_waypoint(ports, tmp_path, monkeypatch):
    monkeypatch.setattr(SimHal, "has_pen", False)
    with pytest.raises(ArmbridgeError, match=r"refused PENPOS \(VERB\).*no pen-lift servo") as e:
        run_plan(_plan(), "emu:esp32?speed=0", tmp_path / "r.rrd", progress=False, pen_pos={"up_us": 1000})
    assert "\n" not in str(e.value)
    assert ports[0].emulator.executed == [] and not (tmp_path / "r.rrd").exists()
    with pytest.raises(ArmbridgeError, match="not with --pen off"):
        run_plan(_plan(), "emu:esp32?speed=0", tmp_path / "r.rrd", progress=False, pen="off",
                 pen_pos={"up_us": 1000})
    # settings the plan carries (armbridge draw's) under --pen auto: no servo, nothing to set; the pen-up
    # moves are marked as ever. Under --pen on the board must take them.
    plan = _plan()
    plan.provenance["drawing"]["pen_pos"] = {"down_us": 1650}
    s = run_plan(plan, "emu:esp32?speed=0", tmp_path / "m.rrd", progress=False)
    assert s.completed and s.pen == "marked" and s.pen_pos is None
    with pytest.raises(ArmbridgeError, match=r"no pen-lift servo; the plan carries them .*--pen off"):
        run_plan(plan, "emu:esp32?speed=0", tmp_path / "o.rrd", progress=False, pen="on")


def test_a_firmware_older_than_penpos_is_told_apart(tmp_path):
    """A board whose firmware has the pen servo (PEN) but not PENPOS, on a real pty: the run stops
    before any waypoint, saying the firmware is the reason, not the servo."""
    root = tmp_path / "fw"
    shutil.copytree(firmware_dir() / "common", root / "common")
    shutil.copytree(firmware_dir() / "esp32", root / "esp32")
    arm = root / "esp32" / "arm.py"
    src = arm.read_text()
    old = src.replace('            self.verbs["PENPOS"] = self.pen.cmd_penpos\n', "")
    assert old != src
    arm.write_text(old)
    link = str(tmp_path / "arm")
    emu = EmulatedBoard("esp32", link=link, firmware_root=root).start()
    try:
        with pytest.raises(ArmbridgeError, match=r"has a pen-lift servo \(PEN works\) but its firmware predates"):
            run_plan(_plan(), link, tmp_path / "r.rrd", progress=False, pen_pos={"down_us": 1650})
        assert emu.executed == [] and not (tmp_path / "r.rrd").exists()
    finally:
        emu.stop()


def test_calid_keeps_the_pen_across_a_power_cycle(ports, tmp_path):
    """Under the real MicroPython interpreter: PENPOS, CALID, then a new emulator on the same
    board filesystem (a power cycle) comes up with the saved widths."""
    require_micropython()
    url = f"emu:esp32?interpreter=micropython&speed=0&fs={tmp_path / 'fs'}"
    with open_session(url, ARM3R, calibration="ignore") as c:
        c.command("PENPOS", 1000, 1900, 250)
        c.command("CALID", 31)
    assert "P=1000,1900,250" in (tmp_path / "fs" / "cal.txt").read_text()
    with open_session(url, ARM3R, calibration="ignore") as c:
        assert c.command("IDENT").payload[1] == "31"
        c.command("PEN", 1)   # at rest: the pen moves now, to the saved down width
        c.command("PING")
        hal = ports[-1].emulator.hal
        assert hal.pen_us_log and hal.pen_us_log[-1][1] == 1900


def test_out_of_range_is_one_line_before_the_port_opens(tmp_path):
    """The real program on a pty that nothing else holds: exit 2, one line naming the option and its
    range, and not one byte on the port."""
    plan = tmp_path / "p.json"
    r = CliRunner().invoke(build_app(), ["draw", "I", "--out", str(plan)])
    assert r.exit_code == 0, r.output
    master, slave = os.openpty()
    try:
        port = os.ttyname(slave)
        for args, what in ((["--pen-up", "3000"], "--pen-up 3000: outside 500..2500 us"),
                           (["--pen-wait", "2001"], "--pen-wait 2001: outside 0..2000 ms")):
            p = subprocess.run([ARMBRIDGE, "run", str(plan), "--port", port, "--no-progress", *args],
                               capture_output=True, text=True, timeout=60)
            assert p.returncode == 2, p.stderr
            lines = p.stderr.strip().splitlines()
            assert len(lines) == 1 and what in lines[0], p.stderr
            assert select.select([master], [], [], 0)[0] == []   # nothing was written to the port
    finally:
        os.close(master)
        os.close(slave)
    r = CliRunner().invoke(build_app(), ["draw", "I", "--out", str(tmp_path / "q.json"), "--pen-down", "400"])
    assert isinstance(r.exception, ArmbridgeError) and "--pen-down 400: outside 500..2500 us" in str(r.exception)
    assert not (tmp_path / "q.json").exists()


def test_board_pen_sets_and_saves_with_the_boards_calibration(tmp_path):
    """`armbridge board pen`: PENPOS (and PEN with --lower); --save CALIDs again under the id the
    board holds, so the host's calibration file still matches; a board with none is one line."""
    fs = tmp_path / "fs"
    url = f"emu:esp32?speed=0&fs={fs}"
    r = CliRunner().invoke(build_app(), ["board", "pen", "--down", "1650", "--save", "--port", url])
    assert isinstance(r.exception, ArmbridgeError) and "holds no calibration" in str(r.exception)
    assert not (fs / "cal.txt").exists()
    with open_session(url, ARM3R, calibration="ignore") as c:
        c.command("CALID", 9)
    r = CliRunner().invoke(build_app(), ["board", "pen", "--down", "1650", "--wait", "90", "--lower", "--save",
                                         "--port", url])
    assert r.exit_code == 0, r.output
    assert "down 1650 us" in r.output and "saved with calibration 9" in r.output
    assert (fs / "cal.txt").read_text().split()[:2] == ["ABC1", "9"]
    assert "P=1200,1650,90" in (fs / "cal.txt").read_text()
    r = CliRunner().invoke(build_app(), ["board", "pen", "--wait", "5000", "--port", url])
    assert isinstance(r.exception, ArmbridgeError) and "--wait 5000: outside 0..2000 ms" in str(r.exception)


@pytest.mark.parametrize("device", ["arduino_pump", "masr_ma"])
def test_the_boards_without_a_pen_answer_verb_and_run_on(device):
    """The pump board's C sketch (in simavr) and the MASR actuator know PENPOS's shape from the
    shared table, and refuse it as a verb they do not implement; the board keeps answering."""
    from armbridge.link import protocol as P

    with open_session(f"emu:{device}?speed=0", None, calibration="ignore") as c:
        ans = c.ask("PENPOS", 1200, 1700, 150)
        assert isinstance(ans, P.Er) and ans.code == P.VERB, ans
        ans = c.ask("PENPOS", 1200, 1700, 5000)   # the range is checked first, as for every verb
        assert isinstance(ans, P.Er) and ans.code == P.RANGE and ans.detail == ("settle_ms",), ans
        assert c.stat()[0] == "IDLE"


def _next(proc, text: str, start: int) -> int:
    """The index of the first line of `proc` from `start` on that holds `text` (waiting for it)."""
    while True:
        for i in range(start, len(proc.lines)):
            if text in proc.lines[i]:
                return i
        line = proc._q.get(timeout=60)
        assert line is not None, f"the emulator ended without {text!r}: {proc.lines[-8:]}"
        proc.lines.append(line)


def test_over_a_pty_to_armbridge_emulate(tmp_path):
    """The real programs, as a user runs them: `armbridge emulate esp32 --servos pca9685` on a pty,
    `armbridge run --pen-down --pen-wait` to it (PENPOS before the first waypoint, the summary's
    pen_pos), then `armbridge board pen --lower` (the pen at rest settles at the new width)."""
    from cli_procs import Proc, emulated_board

    plan = tmp_path / "i.json"
    r = CliRunner().invoke(build_app(), ["draw", "I", "--size", "0.03", "--speed", "0.05", "--out", str(plan)])
    assert r.exit_code == 0, r.output
    board = emulated_board(tmp_path, "--speed", "4", "--servos", "pca9685")
    emu, link = next(board)
    try:
        run = Proc("run", str(plan), "--port", link, "--pen-down", "1650", "--pen-wait", "60", "--json", "-",
                   "--rrd", str(tmp_path / "r.rrd"), "--no-progress", "--no-keys")
        rc, err = run.finish(timeout=120)
        assert rc == 0, err
        s = json.loads("\n".join(run.lines))
        assert s["completed"] and s["pen_pos"] == {"up_us": 1200, "down_us": 1650, "settle_ms": 60}
        assert "pen_untouched" not in s["drawing"]   # a board on a pty: the host cannot know where the tip is
        seen = _next(emu, " PEN 0*", 0) + 1      # the run's last event: the pen lifted at the end
        pen = Proc("board", "pen", "--up", "1100", "--down", "1800", "--wait", "40", "--lower", "--port", link)
        rc, err = pen.finish(timeout=60)
        assert rc == 0 and "pen up 1100 us, down 1800 us, settle 40 ms" in " ".join(pen.lines), (err, pen.lines)
        # the pen at rest went to its new up width and settled (PEN 0), then down (PEN 1): new events
        _next(emu, " PEN 1*", seen)
        events = [ln.split(" PEN ")[1][0] for ln in emu.lines[seen:] if " EV " in ln and " PEN " in ln]
        assert events == ["0", "1"], emu.lines[seen:]
    finally:
        board.close()


@pytest.mark.parametrize("rig, seed", [("", 4), ("&servos=pca9685", 3)], ids=["effort", "pca9685"])
def test_a_drawn_rig_has_its_own_contact_width(rig, seed, ports, tmp_path):
    """plant=random draws the rig's contact width (its hidden truth, emulator/truth.py): a down width
    20 us short of it draws nothing, one 40 us past it draws. (Seeds 4 and 3 draw about 1619 and
    1626 us, past the default rig's 1550.)"""
    from armbridge.emulator.plant import hidden_truth as effort_truth
    from armbridge.emulator.servo_plant import hidden_truth as pca_truth
    from armbridge.emulator.truth import truth_rng

    url = f"emu:esp32?speed=0&plant=random&seed={seed}{rig}"
    s = run_plan(_plan(), url, tmp_path / "a.rrd", progress=False, pen_pos={"down_us": 1600})
    hal = ports[-1].emulator.hal
    truth = (pca_truth if rig else effort_truth)(hal.rig.cfg if rig else ports[-1].emulator.cfg, truth_rng(seed))
    contact = truth.pen_contact_us
    assert 1600 < contact < 1640 and contact != PEN_CONTACT_US
    assert (hal.rig.pen.contact_us if rig else hal.pen_contact_us) == contact   # the drawn truth is the physics
    d = s.drawing
    assert s.completed and d["pen_untouched"] == d["pen_down_samples"] > 50, d
    s = run_plan(_plan(), url, tmp_path / "b.rrd", progress=False, pen_pos={"down_us": int(contact) + 40})
    d = s.drawing
    assert s.completed and d["pen_untouched"] < 0.2 * d["pen_down_samples"], d
