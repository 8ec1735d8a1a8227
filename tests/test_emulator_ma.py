"""The emulated MASR actuator (`armbridge emulate masr_ma`, `emu:masr_ma`):
its HAL over the plant end to end, its faults from the CLI and the URL, and
the board's firmware (firmware/masr_ma) on it.

The first part runs a tiny stand-in firmware (tests/ma_standin.py: the real
link, one MV verb, a P loop on the wheel encoder) so the emulator's side is
tested on its own; the second runs the MA's own firmware."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from armbridge.emulator import EmulatedBoard
from armbridge.emulator.faults import Faults
from armbridge.emulator.ma_hal import MaSimHal
from armbridge.emulator.ma_plant import MaPlant
from armbridge.emulator.registry import board_spec
from armbridge.emulator.url import parse_emu_url
from armbridge.errors import ArmbridgeError
from ma_standin import standin_firmware
from test_emulator import Lockstep

ARMBRIDGE = str(Path(sys.executable).parent / "armbridge")


@pytest.fixture
def standin(tmp_path):
    standin_firmware(tmp_path)
    return tmp_path


def board(root, **kw) -> EmulatedBoard:
    return EmulatedBoard("masr_ma", speed=0, firmware_root=root, **kw)


def move_to(emu, h, wid, d_mm, max_s=15.0):
    assert h.request("MV", wid, d_mm)[1] == "OK"
    return h.wait("EV", lambda a: a[1] in ("DONE", "FAULT") and (a[1] == "FAULT" or a[2] == str(wid)),
                  max_s=max_s)


# ---------------------------------------------------------------- the emulator's side, on the stand-in

def test_the_ma_board_boots_on_its_plant_and_hal(standin):
    emu = board(standin)
    boot = Lockstep(emu).wait("BOOT", max_s=1.0)
    assert boot[2][0] == "masr_ma" and emu.n == 6 and emu.interpreter == "cpython"
    assert isinstance(emu.plant, MaPlant) and isinstance(emu.hal, MaSimHal)
    assert emu.positions().tolist() == [0.0] * 6           # at the base, every joint 0
    assert board_spec("masr_ma").interpreters == ("cpython", "micropython")
    with pytest.raises(ArmbridgeError, match="'simavr' cannot run the masr_ma firmware.*cpython, micropython"):
        board(standin, interpreter="simavr")


def test_a_move_is_tracked_truth_against_telemetry(standin):
    emu = board(standin, seed=2)
    h = Lockstep(emu)
    h.wait("BOOT")
    assert h.hello(1)[1] == "OK"
    ev = move_to(emu, h, 1, 450)
    assert ev[2][1] == "DONE"
    assert abs(emu.positions()[5] - 0.450) < 0.003
    assert [j for _, j, _, _ in emu.hal.hall_log] == [2, 3]
    assert [a[2] for _, v, a in h.lines if v == "EV" and a[1] == "MAGNET"] == ["2", "3"]
    track = list(emu.hal.track)
    assert len(track) > 50
    err = np.array([abs(true[5] - est[5]) for _, true, est in track])
    # encoder travel within the slip bound of the truth, re-zeroed at each magnet, plus a mm of rounding
    assert err.max() < 0.01 * 0.2 + 0.0015 + 0.001
    assert emu.hal.telemetry[-1][1][-3:][0] == 3           # jd: on link 3
    assert emu.hal.loco_log and emu.hal.outputs_on_at


def test_faults_reach_the_plant(standin):
    emu = board(standin, faults=Faults(missed=(3,), slip=((0.5, 0.5, 0.3),)))
    h = Lockstep(emu)
    h.wait("BOOT")
    h.hello(1)
    move_to(emu, h, 1, 450)
    assert [j for _, j, _, _ in emu.hal.hall_log] == [2]
    kinds = [(k, v) for _, k, v in emu.hal.faults_applied]
    assert kinds == [("missed", 3), ("slip", 0.3), ("slip", 0.0)]


def test_a_stalled_wheel_keeps_the_ma_at_the_base(standin):
    emu = board(standin, faults=Faults(stall=((6, 0.0),)))
    h = Lockstep(emu)
    h.wait("BOOT")
    h.hello(1)
    assert h.request("MV", 1, 100)[1] == "OK"
    emu.run_for(1.0)
    assert emu.positions()[5] == 0.0 and emu.hal.loco_log[-1][1] > 0
    assert [(k, v) for _, k, v in emu.hal.faults_applied] == [("stall", 6)]


def test_a_reset_keeps_the_plant(standin):
    emu = board(standin, faults=Faults(reset_at=(1.5,)))
    h = Lockstep(emu)
    h.wait("BOOT")
    h.hello(1)
    assert h.request("MV", 1, 600)[1] == "OK"
    emu.run_until(lambda: emu.now() >= 1.45)
    d = emu.positions()[5]
    assert 0.05 < d < 0.5 and emu.resets == []
    emu.run_for(1.0)
    assert emu.hal.outputs_off_at and emu.resets == [pytest.approx(1.5, abs=0.002)]
    assert emu.positions()[5] == pytest.approx(d, abs=0.005)  # coasted to a stop, stays there
    assert len(emu.boots) == 2


def test_the_arms_hal_calls_are_not_the_mas(standin):
    emu = board(standin)
    with pytest.raises(ArmbridgeError, match="no write_outputs"):
        emu.hal.write_outputs([0.0] * 6)
    with pytest.raises(ArmbridgeError, match="no read_positions"):
        emu.hal.read_positions([0.0] * 6)


# ---------------------------------------------------------------- faults from text

def test_url_parameters():
    device, kw = parse_emu_url("emu:masr_ma?speed=0&missed=3,4&slip=2:0.5:0.3&stall=2@4")
    assert device == "masr_ma" and kw["speed"] == 0
    f = kw["faults"]
    assert f.missed == (3, 4) and f.slip == ((2.0, 0.5, 0.3),) and f.stall == ((2, 4.0),)
    assert f.describe() == ("joint 2 stalls at 4 s, magnet 3 missed, magnet 4 missed, "
                            "wheel slips 0.3 from 2 s for 0.5 s")


@pytest.mark.parametrize("url, words", [
    ("emu:masr_ma?slip=2:0.5", "parameter slip: slip '2:0.5': expected START:DURATION:FRACTION"),
    ("emu:masr_ma?slip=2:0.5:1.5", "FRACTION in [0, 1]"),
    ("emu:masr_ma?slip=2:0:0.5", "DURATION > 0 s"),
    ("emu:masr_ma?missed=x", "parameter missed: missed 'x': expected a JOINT number"),
    ("emu:masr_ma?missed=0", "joints are numbered from 1"),
    ("emu:masr_ma?interpreter=simavr", "'simavr' cannot run the masr_ma firmware; interpreters: cpython, micropython"),
])
def test_bad_url_parameters_are_one_clear_error(url, words):
    with pytest.raises(ArmbridgeError) as e:
        parse_emu_url(url)
    assert words in str(e.value) and "\n" not in str(e.value)


def test_the_mas_faults_on_another_board_or_joint(standin):
    with pytest.raises(ArmbridgeError, match="missed and slip: faults of the masr_ma board; the esp32 board has none"):
        EmulatedBoard("esp32", speed=0, faults=Faults(missed=(1,), slip=((0, 1, 0.5),)))
    with pytest.raises(ArmbridgeError, match="missed magnet 6: the arm has joints 1..5"):
        board(standin, faults=Faults(missed=(6,)))
    with pytest.raises(ArmbridgeError, match="stall joint 7 does not exist"):
        board(standin, faults=Faults(stall=((7, 0.0),)))


def test_cli_help_names_the_mas_faults():
    out = subprocess.run([ARMBRIDGE, "emulate", "masr_ma", "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    text = " ".join(out.stdout.split())
    for words in ("--missed-magnet", "--slip-burst", "masr_ma (MASR mobile actuator", "J = n: the wheel"):
        assert words in text, words


def test_cli_bad_fault_is_one_clear_line():
    out = subprocess.run([ARMBRIDGE, "emulate", "masr_ma", "--slip-burst", "1:2", "--for", "1"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode != 0 and "Traceback" not in out.stderr
    err = out.stderr.strip().splitlines()
    assert len(err) == 1 and "--slip-burst '1:2': expected START:DURATION:FRACTION" in err[0], out.stderr
    assert "emulator on" not in out.stdout


# ---------------------------------------------------------------- the MA's own firmware (firmware/masr_ma)

class Ma:
    """The MA's firmware on the emulator with a lockstep host: HELLO, then actions."""

    def __init__(self, seed=1, **kw) -> None:
        self.emu = EmulatedBoard("masr_ma", speed=0, seed=seed, **kw)
        self.h = Lockstep(self.emu)
        self.h.wait("BOOT")
        assert self.h.hello(1)[1] == "OK"
        c = self.emu.cfg
        # loc.py's bound: hall window + one count + slip over the longest link; MV stops within STOP_TOL_MM
        self.loc_mm = c.HALL_WINDOW_MM + c.WHEEL_MM_PER_COUNT + c.SLIP_MAX * max(c.LINK_LENGTHS_MM)
        self.mv_mm = self.loc_mm + c.STOP_TOL_MM

    def act(self, *args, max_s=20.0):
        """One action -> (the OK/ER reply, the EV DONE or FAULT that ends it, or None after an ER)."""
        reply = self.h.request(*args)
        if reply[1] != "OK":
            return reply, None
        wid = str(args[1])
        ev = self.h.wait("EV", lambda a: a[1] == "FAULT" or (a[1] == "DONE" and a[2] == wid), max_s=max_s)
        return reply, ev

    def done(self, *args, max_s=20.0):
        reply, ev = self.act(*args, max_s=max_s)
        assert reply[1] == "OK" and ev is not None and ev[2][1] == "DONE", (reply, ev, self.stat())
        return ev

    def stat(self):
        return self.h.request("STAT")[2]

    @property
    def q(self):
        return self.emu.positions()

    def track_error_mm(self) -> float:
        """Largest |true d - the board's d| over its telemetry (mm)."""
        return max(abs(true[-1] - est[-1]) for _, true, est in self.emu.hal.track) * 1000.0


def test_mv_and_rot_reach_their_targets():
    ma = Ma(seed=1)
    ma.done("HOME", 1)                                     # power on: unhomed until a HOME
    ma.done("MV", 2, 450)
    assert abs(ma.q[5] * 1000 - 450) <= ma.mv_mm
    ma.done("ROT", 3, 3, 300)                              # drives back onto joint 3, turns it
    back = ma.emu.cfg.BACKLASH_MRAD + ma.emu.cfg.ROT_TOL_MRAD
    assert abs(ma.q[2] * 1000 - 300) <= back
    assert abs(ma.q[5] * 1000 - 400) <= ma.emu.cfg.HALL_WINDOW_MM + ma.loc_mm
    ma.done("ROT", 4, 5, -200)                             # over joint 4 to joint 5
    assert abs(ma.q[4] * 1000 + 200) <= back and abs(ma.q[2] * 1000 - 300) <= back   # the worm held joint 3
    ma.done("MV", 5, 120)
    assert abs(ma.q[5] * 1000 - 120) <= ma.mv_mm
    assert [ma.q[k] for k in (0, 1, 3)] == [0.0, 0.0, 0.0]
    assert [j for _, j, _, _ in ma.emu.hal.hall_log] == [2, 3, 3, 4, 5, 4, 3, 2]
    assert ma.track_error_mm() <= ma.loc_mm + 0.5          # telemetry rounds d to 1 mm
    assert ma.emu.hal.faults_applied == [] and ma.stat()[2] == "IDLE"


def test_a_missed_magnet_faults_and_stops_the_ma():
    ma = Ma(faults=Faults(missed=(3,)))
    ma.done("HOME", 1)
    _, ev = ma.act("MV", 2, 500)
    assert ev[2][1] == "FAULT" and ma.stat()[6] == "MAGNET:MISSED"
    assert ma.emu.hal.outputs_off_at and not ma.emu.hal.outputs_enabled
    ma.emu.run_for(0.5)
    d = ma.q[5] * 1000
    assert 400 < d < 400 + 2 * ma.loc_mm + 5                # stopped just past the silent magnet
    assert ma.h.request("MV", 3, 100)[2][2] == "LATCHED"


def test_a_small_slip_burst_stays_within_the_bound():
    ma = Ma(faults=Faults(slip=((1.0, 0.3, 0.02),)))       # 2 % for 0.3 s: 0.6 mm
    ma.done("HOME", 1)
    ma.done("MV", 2, 350)
    assert abs(ma.q[5] * 1000 - 350) <= ma.mv_mm and ma.track_error_mm() <= ma.loc_mm + 0.5
    assert [k for _, k, _ in ma.emu.hal.faults_applied] == ["slip", "slip"]


def test_a_large_slip_burst_faults_before_the_ma_is_wrong_for_long():
    ma = Ma(faults=Faults(slip=((0.8, 0.5, 0.3),)))        # 30 % for 0.5 s: about 15 mm short
    ma.done("HOME", 1)
    _, ev = ma.act("MV", 2, 350)
    assert ev[2][1] == "FAULT" and ma.stat()[6].startswith("MAGNET:")
    assert int(ev[2][0]) / 1000 < 3.0                      # at magnet 2, not at the end of the move
    assert ma.q[5] * 1000 < 230


def test_a_stalled_joint_motor_faults():
    ma = Ma(faults=Faults(stall=((3, 0.0),)))
    ma.done("HOME", 1)
    _, ev = ma.act("ROT", 2, 3, 300)
    assert ev[2][1] == "FAULT" and ma.stat()[6] == "STALL:3"
    assert ma.q[2] == 0.0 and not ma.emu.hal.outputs_enabled


def test_a_stalled_wheel_faults():
    ma = Ma(faults=Faults(stall=((6, 0.5),)))
    ma.done("HOME", 1)
    _, ev = ma.act("MV", 2, 300)
    assert ev[2][1] == "FAULT" and ma.stat()[6] == "STALL:LOCO"


def test_a_reset_mid_move_leaves_unhomed_and_home_recovers():
    ma = Ma()
    ma.done("HOME", 1)
    assert ma.h.request("MV", 2, 600)[1] == "OK"
    ma.h.wait("T", lambda a: ma.q[5] > 0.25)               # the host's PINGs feed the watchdog meanwhile
    ma.emu.reset()
    assert ma.emu.run_until(lambda: len(ma.emu.boots) == 2, 1.0)
    assert ma.h.hello(1)[1] == "OK"
    er = ma.h.request("MV", 3, 100)
    assert er[1] == "ER" and er[2][1:3] == ["14", "UNHOMED"]
    er = ma.h.request("ROT", 4, 2, 100)
    assert er[1] == "ER" and er[2][2] == "UNHOMED"
    ma.done("HOME", 5, max_s=30.0)
    assert ma.q[5] * 1000 <= 1.0
    ma.done("MV", 6, 250)
    assert abs(ma.q[5] * 1000 - 250) <= ma.mv_mm


# ---------------------------------------------------------------- limits held in every verb (issue 21)

def _watch_d_reference(ma, until, max_s=30.0):
    """Run until `until()`; -> the largest |d reference speed| (mm/s) the firmware's
    ramp had at any period, and the d references it went through."""
    peak = [0.0]
    refs = []

    def check():
        b = ma.emu.board
        if b is not None:
            peak[0] = max(peak[0], abs(b.loco.ramp.v))
            refs.append(b.loco.ramp.x)
        ma.h.find("EV")       # reads the board's lines; PINGs keep the watchdog fed
        return until()

    assert ma.emu.run_until(check, max_s), ma.h.lines[-5:]
    return peak[0], refs


def test_rot_drives_onto_its_magnet_within_a_narrowed_speed():
    """docs/protocol.md §11: every set-point change obeys the speed limits. With d's vmax
    at 20 mm/s the approach onto joint 3's magnet crept at MAG_MM_S = 40 mm/s (twice the
    limit) and the MA faulted FOLLOW:6; it now creeps at the limit and the ROT completes."""
    ma = Ma(seed=1)
    ma.done("HOME", 1)
    ma.done("MV", 2, 480)
    assert ma.h.request("SETLIM", 6, 0, 800, 20)[1] == "OK"
    ma.h.lines.clear()
    assert ma.h.request("ROT", 3, 3, -100)[1] == "OK"
    ended = lambda: any(v == "EV" and a[1] in ("DONE", "FAULT") for _, v, a in ma.h.lines)   # noqa: E731
    peak, _ = _watch_d_reference(ma, ended, max_s=30.0)
    ev = next(a for _, v, a in ma.h.lines if v == "EV" and a[1] in ("DONE", "FAULT"))
    assert ev[1:3] == ["DONE", "3"], (ev, ma.stat())
    assert peak <= 20.0 + 1e-9, peak
    assert abs(ma.q[2] * 1000 + 100) <= ma.emu.cfg.BACKLASH_MRAD + ma.emu.cfg.ROT_TOL_MRAD


def test_home_obeys_a_narrowed_speed():
    """HOME ignores a narrowed d range (it must reach the base), not the speed limit."""
    ma = Ma(seed=1)
    ma.done("HOME", 1)
    ma.done("MV", 2, 150)
    assert ma.h.request("SETLIM", 6, 100, 800, 25)[1] == "OK"
    ma.h.lines.clear()
    assert ma.h.request("HOME", 3)[1] == "OK"
    done = lambda: any(v == "EV" and a[1:3] == ["DONE", "3"] for _, v, a in ma.h.lines)   # noqa: E731
    peak, _ = _watch_d_reference(ma, done)
    assert peak <= 25.0 + 1e-9 and ma.q[5] * 1000 <= 1.0


def test_setlim_moves_d_into_a_narrowed_range_at_vmax():
    """§11 and §3.2: a SETLIM that leaves d's set point outside the new range moves it
    into the range at no more than vmax, with one EV LIMIT (before: OK and nothing)."""
    ma = Ma(seed=1)
    ma.done("HOME", 1)
    ma.done("MV", 2, 400)
    ma.h.lines.clear()
    assert ma.h.request("SETLIM", 6, 500, 800, 100)[1] == "OK"
    limits = lambda: [a for _, v, a in ma.h.lines if v == "EV" and a[1] == "LIMIT"]   # noqa: E731
    assert ma.emu.run_until(lambda: (ma.h.find("EV"), limits())[1] != [], 0.1)
    assert limits()[0][2:] == ["6"]
    assert ma.stat()[2] == "RUN"                      # moving: the watchdog guards it
    at_rest = lambda: ma.emu.board.busy() is False and ma.stat()[2] == "IDLE"   # noqa: E731
    peak, refs = _watch_d_reference(ma, at_rest, max_s=10.0)
    assert peak <= 100.0 + 1e-9 and max(refs) <= 500.0
    assert abs(ma.q[5] * 1000 - 500) <= ma.mv_mm
    assert len(limits()) == 1
    assert not any(v == "EV" and a[1] in ("START", "DONE", "FAULT") for _, v, a in ma.h.lines)
    ma.done("MV", 3, 600)                             # the range in force: MV inside it runs ...
    er = ma.h.request("MV", 4, 450)
    assert er[1] == "ER" and er[2][1:] == ["6", "RANGE", "d"]   # ... outside it is refused


def test_setlim_inside_the_range_moves_nothing():
    ma = Ma(seed=1)
    ma.done("HOME", 1)
    ma.done("MV", 2, 400)
    ma.h.lines.clear()
    assert ma.h.request("SETLIM", 6, 300, 800, 100)[1] == "OK"
    assert not ma.emu.run_until(lambda: ma.h.find("EV", lambda a: a[1] == "LIMIT") is not None, 0.3)
    assert not any(v == "EV" and a[1] == "LIMIT" for _, v, a in ma.h.lines) and ma.stat()[2] == "IDLE"


def test_setlim_that_strands_a_joint_is_refused():
    """The MA turns a joint only by driving to it: a SETLIM that would leave joint 3's
    angle outside its range is refused RANGE 3, unless a ROT of joint 3 (inside the new
    range: the rule for queued targets) is queued or running to turn it in."""
    ma = Ma(seed=1)
    ma.done("HOME", 1)
    ma.done("ROT", 2, 3, 300)
    er = ma.h.request("SETLIM", 3, -873, 200, 280)
    assert er[1] == "ER" and er[2][1:] == ["6", "RANGE", "3"]
    assert ma.h.request("LIM", 3)[2][2:] == ["3", "-873", "873", "280"]   # unchanged
    assert ma.h.request("ROT", 3, 3, 100)[1] == "OK"
    assert ma.h.request("SETLIM", 3, -873, 200, 280)[1] == "OK"
    ma.h.wait("EV", lambda a: a[1:3] == ["DONE", "3"], max_s=10.0)
    assert not any(v == "EV" and a[1] == "LIMIT" for _, v, a in ma.h.lines)
