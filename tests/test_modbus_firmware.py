"""The pump's Modbus RTU parser (firmware/arduino_pump/modbus.cpp) built natively.

* tests/modbus/test_modbus.cpp: unit tests under AddressSanitizer and UBSan (CRC
  check values, every function code, every exception, framing by the t3.5 gap, a
  frame split across calls, broadcast, overrun, clock wrap);
* tests/modbus/fuzz_modbus.cpp: libFuzzer with clang when installed, else its own
  deterministic mutation driver, bounded, under the same sanitizers; the run must
  reach every function code's reply and every exception the map can produce;
* the parser also builds for the Mega with avr-gcc, warnings as errors.

A missing compiler skips (fails under ARMBRIDGE_REQUIRE_HIL=1: tests/require.py).
"""
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

from require import missing

ROOT = Path(__file__).resolve().parents[1]
FW = ROOT / "firmware" / "arduino_pump"
SRC = ROOT / "tests" / "modbus"
SAN = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-g", "-O1"]
WARN = ["-Wall", "-Wextra", "-Werror"]


def _cxx() -> str:
    cxx = shutil.which("g++") or shutil.which("clang++")
    if cxx is None:
        missing("no native C++ compiler (g++ or clang++) for the firmware unit tests")
    return str(cxx)


def _build(tmp: Path, name: str, main: Path, extra: list[str] | None = None, cxx: str | None = None) -> Path:
    exe = tmp / name
    cmd = [cxx or _cxx(), "-std=gnu++11", *WARN, *SAN, *(extra or []), f"-I{FW}", "-o", str(exe), str(main),
           str(FW / "modbus.cpp")]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, f"build failed: {' '.join(cmd)}\n{res.stderr}"
    return exe


def test_unit_tests_under_sanitizers(tmp_path: Path) -> None:
    exe = _build(tmp_path, "test_modbus", SRC / "test_modbus.cpp")
    res = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stdout + res.stderr
    m = re.search(r"(\d+) checks, 0 failed", res.stdout)
    assert m and int(m.group(1)) >= 90, res.stdout
    assert "runtime error" not in res.stderr, res.stderr  # UBSan


def test_unit_tests_catch_a_wrong_gap(tmp_path: Path) -> None:
    """The framing checks can fail: a parser with t3.5 = 1700 us is caught."""
    wrong = tmp_path / "fw"
    wrong.mkdir()
    shutil.copy(FW / "modbus.h", wrong / "modbus.h")
    text = (FW / "modbus.cpp").read_text()
    assert "return 1750;" in text
    (wrong / "modbus.cpp").write_text(text.replace("return 1750;", "return 1700;"))
    exe = tmp_path / "mutant"
    res = subprocess.run([_cxx(), "-std=gnu++11", f"-I{wrong}", "-o", str(exe), str(SRC / "test_modbus.cpp"),
                          str(wrong / "modbus.cpp")], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    res = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60)
    assert res.returncode != 0 and "test_framing" in res.stderr


def test_fuzz_frame_parser(tmp_path: Path) -> None:
    """The deterministic mutation driver (every function code answered, every exception of the map
    seen); the coverage-guided libFuzzer run of the same target is tests/test_fuzz_coverage.py's."""
    exe = _build(tmp_path, "fuzz", SRC / "fuzz_modbus.cpp")
    res = subprocess.run([str(exe), "1000000"], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-4000:]
    assert "runtime error" not in res.stderr, res.stderr[-4000:]
    m = re.search(r"replies fc3 (\d+) fc4 (\d+) fc6 (\d+) fc16 (\d+); exceptions(.*)", res.stdout)
    assert m, res.stdout
    assert all(int(m.group(i)) > 0 for i in range(1, 5)), res.stdout  # every function code answered
    seen = {int(c) for c, _ in re.findall(r"(\d\d):(\d+)", m.group(5))}
    assert seen == {1, 2, 3, 4, 6}, res.stdout  # every exception of the map, and no other


def test_builds_for_the_mega(tmp_path: Path) -> None:
    avr = shutil.which("avr-gcc")
    if avr is None:
        missing("avr-gcc is not installed (scripts/setup.sh installs the AVR toolchain)")
    obj = tmp_path / "modbus.o"
    res = subprocess.run([avr, "-mmcu=atmega2560", "-DF_CPU=16000000L", "-Os", "-std=gnu++11", *WARN, "-x", "c++",
                          "-c", str(FW / "modbus.cpp"), "-o", str(obj)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    size = subprocess.run(["avr-size", str(obj)], capture_output=True, text=True, timeout=30).stdout
    text, data, bss = (int(x) for x in size.splitlines()[1].split()[:3])
    assert text < 4096 and data + bss < 400, size  # flash and RAM stay small (docs/modbus.md)


def test_header_is_plain_c() -> None:
    """The header has no Arduino dependency and is valid C as well as C++."""
    gcc = shutil.which("gcc")
    if gcc is None:
        missing("no C compiler")
    res = subprocess.run([gcc, "-fsyntax-only", "-Wall", "-Wextra", "-Werror", "-x", "c", str(FW / "modbus.h")],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
