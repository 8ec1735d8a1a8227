"""`armbridge calibrate`'s shared flow (calibrate/base.py), the host's calibration
files (boards/calfile.py) and a run's check of the board against them
(executor/calcheck.py), on the emulated esp32 with its filesystem kept in a
folder (so the board's cal.txt outlives one emulator, as flash does on a chip).

The board's own procedure here is a stand-in that "finds" fixed gains: what is
tested is what happens around any procedure (IDENT, settings, CALID, the file,
the refusal); each board's real procedure has its own tests
(test_calibrate_masr.py, test_calibrate_pump.py, test_calibrate_arm3r.py)."""
from __future__ import annotations

import json
import subprocess
import sys
import types
from pathlib import Path

import pytest

from armbridge.boards import calfile
from armbridge.calibrate import base
from armbridge.calibrate.base import Found, calibrate_board, merged
from armbridge.errors import ArmbridgeError
from armbridge.executor.run import run_plan
from armbridge.executor.session import open_session
from armbridge.plans.format import save_plan
from plan_runs import wave_plan
from require import require_micropython

ARMBRIDGE = str(Path(sys.executable).with_name("armbridge"))
GAINS = [("GAIN", (1, 2100, 10, 40)), ("GAIN", (2, 2200, 20, 50))]


@pytest.fixture
def standin(monkeypatch):
    """The esp32's procedure replaced by one that finds GAINS (and records its calls)."""
    calls = []
    mod = types.ModuleType("standin_procedure")
    mod.STEPS = ("gains", "other")

    def calibrate(client, cfg, only):
        calls.append((client.info.fw, int(cfg.N_JOINTS), only))
        return Found(settings=list(GAINS), values={"gains": [2.1, 2.2]}, lines=["joint 1 gains: 2.1"])

    mod.calibrate = calibrate
    monkeypatch.setitem(sys.modules, "standin_procedure", mod)
    monkeypatch.setitem(base.PROCEDURES, "esp32", "standin_procedure")
    return calls


def url(fs: Path, extra: str = "") -> str:
    return f"emu:esp32?speed=0&fs={fs}{extra}"


def test_calibrate_persists_on_the_board_and_on_the_host(tmp_path, standin, monkeypatch):
    fs, cal = tmp_path / "fs", tmp_path / "cal"
    monkeypatch.setenv(calfile.ENV_DIR, str(cal))
    report = calibrate_board(url(fs), "esp32")
    assert standin == [("arm3r", 3, frozenset())]
    assert report.settings == GAINS
    assert 1 <= report.id < 2 ** 30
    saved = calfile.read(Path(report.path))
    assert (saved.board, saved.uid, saved.id) == ("esp32", report.uid, report.id)
    assert saved.found == {"gains": [2.1, 2.2]}
    # on the board: cal.txt holds the id; a new emulator on the same filesystem (a power cycle) reports it
    assert (fs / "cal.txt").read_text().split()[:2] == ["ABC1", str(report.id)]
    with open_session(url(fs), None) as c:
        assert c.command("IDENT").payload == (report.uid, str(report.id))
        assert c.calibration.status == "calibrated"


def test_a_run_checks_the_board_against_the_host_file(tmp_path, standin, monkeypatch):
    fs, cal = tmp_path / "fs", tmp_path / "cal"
    monkeypatch.setenv(calfile.ENV_DIR, str(cal))
    report = calibrate_board(url(fs), "esp32")
    plan = save_plan(wave_plan(20), tmp_path / "wave.json")
    s = run_plan(plan, url(fs), tmp_path / "a.rrd", progress=False)
    assert s.completed and s.calibration == {"status": "calibrated", "uid": report.uid, "id": report.id,
                                             "file": report.path}
    # erased: the board's filesystem lost cal.txt; the run refuses it before sending anything
    (fs / "cal.txt").unlink()
    with pytest.raises(ArmbridgeError, match=r"holds no calibration, but this host calibrated it as"):
        run_plan(plan, url(fs), tmp_path / "b.rrd", progress=False)
    # unless asked not to check
    s = run_plan(plan, url(fs), tmp_path / "c.rrd", progress=False, calibration="ignore")
    assert s.completed and s.calibration == {"status": "not checked", "uid": None, "id": None, "file": None}
    # another physical board (a drawn plant) on the same port has no host file: runs uncalibrated
    s = run_plan(plan, url(tmp_path / "fs2", "&plant=random&seed=4"), tmp_path / "d.rrd", progress=False)
    assert s.completed and s.calibration["status"] == "uncalibrated" and s.calibration["uid"] != report.uid


def test_the_cli_refuses_with_one_line_and_board_info_reports(tmp_path, standin, monkeypatch):
    fs, cal = tmp_path / "fs", tmp_path / "cal"
    env = {"ARMBRIDGE_CALIBRATION_DIR": str(cal), "PATH": "/usr/bin:/bin"}
    report = calibrate_board(url(fs), "esp32", cal_dir=cal)
    info = subprocess.run([ARMBRIDGE, "board", "info", "--port", url(fs), "--json", "-"], capture_output=True, text=True,
                          env=env, timeout=300)
    assert info.returncode == 0, info.stderr
    got = json.loads(info.stdout)["calibration"]
    assert (got["status"], got["uid"], got["id"]) == ("calibrated", report.uid, report.id)
    assert got["settings"] == [["GAIN", 1, 2100, 10, 40], ["GAIN", 2, 2200, 20, 50]]
    toks = (fs / "cal.txt").read_text().split()
    (fs / "cal.txt").write_text(" ".join(["ABC1", "77"] + toks[2:]) + "\n")   # calibrated elsewhere since
    plan = save_plan(wave_plan(20), tmp_path / "wave.json")
    r = subprocess.run([ARMBRIDGE, "run", str(plan), "--port", url(fs), "--no-progress"], capture_output=True,
                       text=True, env=env, timeout=300)
    assert r.returncode == 2
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "holds calibration 77, but this host calibrated it as" in err[0], r.stderr
    assert "Traceback" not in r.stderr


def test_bad_steps_and_edited_files_are_one_line_errors(tmp_path, standin):
    with pytest.raises(ArmbridgeError, match=r"calibration step 'nope' is not one of esp32's: gains, other"):
        calibrate_board(url(tmp_path / "fs"), "esp32", only=["nope"], cal_dir=tmp_path)
    with pytest.raises(ArmbridgeError, match=r"no calibration for board 'plotter'"):
        calibrate_board(url(tmp_path / "fs"), "plotter", cal_dir=tmp_path)
    with pytest.raises(ArmbridgeError, match=r"runs firmware 'masr_ma', not the esp32 board's"):
        calibrate_board(f"emu:masr_ma?speed=0&fs={tmp_path / 'ma'}", "esp32", cal_dir=tmp_path)
    report = calibrate_board(url(tmp_path / "fs"), "esp32", cal_dir=tmp_path)
    path = Path(report.path)
    doc = json.loads(path.read_text())
    doc["settings"][0][2] = 9999                                    # edited by hand
    path.write_text(json.dumps(doc))
    with pytest.raises(ArmbridgeError, match=r"does not match its settings \(edited by hand\?\)"):
        calfile.read(path)
    path.write_text("{")
    with pytest.raises(ArmbridgeError, match=r"line 1, column 2: not valid JSON"):
        calfile.read(path)


def test_only_keeps_the_other_steps_settings():
    old = [("GAIN", (1, 1, 0, 0)), ("GAIN", (2, 2, 0, 0)), ("WHEEL", (16000,))]
    new = [("GAIN", (2, 5, 0, 0)), ("WHEEL", (16100,)), ("MAG", (1, 100, 1500))]
    assert merged(old, new) == [("GAIN", (1, 1, 0, 0)), ("GAIN", (2, 5, 0, 0)), ("WHEEL", (16100,)),
                                ("MAG", (1, 100, 1500))]


@pytest.mark.parametrize("interpreter", ["cpython", "micropython"])
def test_the_board_refuses_a_foreign_calibration_file_and_keeps_running(tmp_path, interpreter):
    """A cal.txt the firmware cannot read leaves its defaults and reports cal 0;
    under the MicroPython interpreter as under CPython, CALID writes the file."""
    if interpreter == "micropython":
        require_micropython()
    fs = tmp_path / "fs"
    with open_session(url(fs, f"&interpreter={interpreter}"), None) as c:
        c.command("CALID", 4242)
        assert c.command("IDENT").payload[1] == "4242"
    assert (fs / "cal.txt").read_text().split()[:2] == ["ABC1", "4242"]
    with open_session(url(fs), None) as c:
        uid = c.command("IDENT").payload[0]
    for text in ("ABC1 notanumber\n", "XYZ 5 1 2\n", "\xff\xfe"):
        (fs / "cal.txt").write_bytes(text.encode("latin-1"))
        with open_session(url(fs, f"&interpreter={interpreter}"), None) as c:
            assert c.command("IDENT").payload == (uid, "0")
            assert c.command("PING")


def test_the_pump_boards_eeprom_is_kept_in_fs_dir(tmp_path):
    """emu:arduino_pump?fs=DIR keeps the chip's EEPROM in DIR/<chip id>.eeprom, as the Mega keeps it
    across power cycles: a CALID survives a new emulator, and another drawn board has its own."""
    fs = tmp_path / "ee"
    pump = f"emu:arduino_pump?speed=0&plant=random&seed=5&fs={fs}"
    with open_session(pump, None) as c:
        uid, held = c.command("IDENT").payload
        assert held == "0"
        c.command("CALID", 31337)
        c.drain(base.PERSIST_S)
    assert (fs / f"{uid}.eeprom").is_file()
    with open_session(pump, None) as c:
        assert c.command("IDENT").payload == (uid, "31337")
    with open_session(pump.replace("seed=5", "seed=6"), None) as c:
        other, held = c.command("IDENT").payload
        assert other != uid and held == "0"


def test_the_help_names_every_boards_steps():
    """`calibrate --help` lists the steps without importing the procedures (start-up stays fast):
    the list must be each procedure's STEPS."""
    import importlib

    from armbridge.calibrate import command

    doc = command.calibrate_cmd.__doc__
    for board, module in base.PROCEDURES.items():
        steps = importlib.import_module(module).STEPS
        assert f"{board}: {', '.join(steps)}" in " ".join(doc.split()), (board, steps)


def test_the_esp32_jig_step_through_the_cli(tmp_path):
    """`armbridge calibrate esp32 --jig emu`: the emulated user places the pen on the printed marks
    (calibrate/jig.py), the flow saves the servos' CAL lines; --jig-sheet writes the marks to print;
    --jig on another board, or an unknown jig, is one line and exit 2."""
    fs, cal, sheet = tmp_path / "fs", tmp_path / "cal", tmp_path / "marks.svg"
    port = f"emu:esp32?speed=0&servos=pca9685&plant=random&seed=4&fs={fs}"
    r = subprocess.run([ARMBRIDGE, "calibrate", "esp32", "--port", port, "--dir", str(cal), "--jig", "emu",
                        "--jig-sheet", str(sheet), "--json", "-"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert sorted(s[1] for s in report["settings"] if s[0] == "CAL") == [1, 2, 3]
    assert calfile.read(Path(report["file"])).id == report["id"]
    assert sheet.read_text().startswith("<svg") and "</svg>" in sheet.read_text()
    for args, msg in ((["masr_ma", "--port", "emu:masr_ma?speed=0", "--jig", "emu"], "--jig is for the esp32"),
                      (["esp32", "--port", "emu:esp32?speed=0", "--jig", "paper"], "--jig: jig 'paper'")):
        r = subprocess.run([ARMBRIDGE, "calibrate", *args, "--dir", str(cal)], capture_output=True, text=True,
                           timeout=300)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and msg in r.stderr, r.stderr
