"""The firmware unit tests (tests/firmware) under a real MicroPython interpreter.

Runs tests/mpy/run_tests.mjs with Node and the npm package
@micropython/micropython-webassembly-pyscript (`make setup` installs it). Every
test must pass, and the number of tests run must equal the number of test_*
functions CPython sees, so a module that MicroPython silently skips fails here.
Without node or the package the test is skipped, unless ARMBRIDGE_REQUIRE_HIL=1.
"""

import ast
import os
import pathlib
import shutil
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
RUNNER = ROOT / "tests" / "mpy" / "run_tests.mjs"
PKG = ROOT / "node_modules" / "@micropython" / "micropython-webassembly-pyscript" / "micropython.mjs"
TESTS = ROOT / "tests" / "firmware"


def _missing(reason: str) -> None:
    if os.environ.get("ARMBRIDGE_REQUIRE_HIL") == "1":
        pytest.fail(reason + " (ARMBRIDGE_REQUIRE_HIL=1)")
    pytest.skip(reason)


def _expected_tests() -> set:
    names = set()
    for path in sorted(TESTS.glob("test_*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in tree.body:
            if isinstance(node, ast.FunctionDef) and node.name.startswith("test_"):
                names.add("%s::%s" % (path.stem, node.name))
    return names


def test_firmware_tests_pass_under_micropython():
    node = shutil.which("node")
    if node is None:
        _missing("node is not installed")
    if not PKG.exists():
        _missing("npm package @micropython/micropython-webassembly-pyscript missing (run `make setup`)")
    proc = subprocess.run([node, str(RUNNER), str(ROOT)], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)
    out = proc.stdout + proc.stderr
    passed = set()
    failed = []
    for line in proc.stdout.splitlines():
        if line.startswith("PASS "):
            passed.add(line[5:].strip())
        elif line.startswith("FAIL "):
            failed.append(line)
    assert proc.returncode == 0 and not failed, "MicroPython failures:\n" + out[-6000:]
    expected = _expected_tests()
    assert expected, "no firmware tests found"
    assert passed == expected, (
        "tests run under MicroPython differ from CPython's: missing %s, extra %s"
        % (sorted(expected - passed), sorted(passed - expected)))
