"""The syringe-pump board's C++ firmware (firmware/arduino_pump): the AVR build, the
native tests of its portable parts under AddressSanitizer/UBSan against every case
of the shared vectors, a boot of the real .elf in simavr, and the fuzz target for a
bounded time.

Everything builds into build/pytest/ inside the folder, so a test run never touches
build/arduino_pump.elf, which the emulator (SIMAVR) may be running at the same time.
A missing avr-gcc, g++ or simavr skips with the reason, and fails under
ARMBRIDGE_REQUIRE_HIL=1 (tests/require.py). About 40 s on two cores: the fuzz
driver and the native tests are built first, and the fuzz (one core, a fixed
number of inputs: FUZZ_ITERATIONS) runs beside the AVR build and the simavr boot.
No outcome here depends on the machine's speed: the fuzz runs a fixed number of
inputs from a fixed seed (its FUZZ_SECONDS only guards against a hang), and the
simavr boot is read until the lines it needs have come.
"""

import json
import os
import pathlib
import re
import shutil
import subprocess
import zlib

import pytest
from require import missing

ROOT = pathlib.Path(__file__).resolve().parents[1]
FW = ROOT / "firmware" / "arduino_pump"
BUILD = "build/pytest"
VECTORS = ROOT / "tests" / "vectors" / "lines.json"
FUZZ_ITERATIONS = 60_000   # about 6 s on an idle core; the same inputs on any machine (seed fixed)
FUZZ_SECONDS = 600         # a hang guard only
FUZZ_ARGS = (f"FUZZ_SECONDS={FUZZ_SECONDS}", f"FUZZ_ITERATIONS={FUZZ_ITERATIONS}")


def _need(*tools: str) -> None:
    for t in tools:
        if shutil.which(t) is None:
            missing(f"{t} is not installed (scripts/setup.sh installs the AVR toolchain and simavr)")


def _make(*targets: str, timeout: int = 240) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-C", str(FW), "-j2", f"BUILD={BUILD}", *targets], capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture(scope="module", autouse=True)
def fuzz_proc(request):
    """`make fuzz`, started before the module's first test when the fuzz test is to run:
    the native objects, test and fuzz binaries built first (make -j2), so that `make fuzz`
    and `make native-test` find them up to date and only run them. A failed build starts
    nothing: the tests then run make themselves and show its errors."""
    wanted = any(item.name == "test_fuzz_target_for_a_bounded_time" and item.module is request.module
                 for item in request.session.items)
    if not wanted or shutil.which("g++") is None or shutil.which("make") is None:
        yield None
        return
    native = f"{BUILD}/native"
    targets = [f"{native}/test_gcc", f"{native}/vectors.txt", f"{BUILD}/fuzz/fuzz_line"]
    if shutil.which("clang++"):
        targets.append(f"{native}/test_clang")
    if _make(*targets).returncode != 0:
        yield None
        return
    proc = subprocess.Popen(["make", "-C", str(FW), f"BUILD={BUILD}", "fuzz", *FUZZ_ARGS],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        yield proc
    finally:
        if proc.returncode is None:   # the fuzz test did not read it
            proc.kill()
            proc.communicate()


@pytest.fixture(scope="module")
def avr_build() -> subprocess.CompletedProcess:
    _need("avr-gcc", "avr-g++", "avr-size", "make")
    return _make("all")


def test_avr_build_is_clean_and_reports_flash_and_ram(avr_build):
    out = avr_build.stdout + avr_build.stderr
    assert avr_build.returncode == 0, out
    assert "warning" not in out.lower(), out          # our sources: -Wall -Wextra -Werror
    flash = re.search(r"flash: (\d+) of 253952 bytes", out)
    ram = re.search(r"ram: (\d+) of 8192 bytes", out)
    assert flash and ram, out
    assert 4000 < int(flash.group(1)) < 253952 - 8192   # room left for the bootloader
    assert int(ram.group(1)) <= 8192 - 2048, "static RAM must leave 2 KiB for the stack"
    elf = FW / BUILD / "arduino_pump.elf"
    hexfile = FW / BUILD / "arduino_pump.hex"
    assert elf.stat().st_size > 0 and hexfile.read_text().startswith(":")
    syms = subprocess.run(["avr-nm", "-C", str(elf)], capture_output=True, text=True).stdout
    assert "__vector_25" in syms        # our USART0 receive interrupt (the e-stop byte is handled there)
    assert "HardwareSerial" not in syms   # the core's Serial (and its own RX ISR) is not linked


def test_the_elf_boots_in_simavr_and_prints_boot(avr_build):
    assert avr_build.returncode == 0
    _need("simavr")
    elf = FW / BUILD / "arduino_pump.elf"
    # simavr echoes UART0 on its console (stderr); the firmware never exits, so the run
    # is read until BOOT and 5 telemetry lines have come (about 0.45 s simulated), then
    # stopped: however slowly simavr runs on a loaded machine (60 s: a hang guard only)
    cmd = ["simavr", "-m", "atmega2560", "-f", "16000000", str(elf)]
    if shutil.which("stdbuf"):
        cmd = ["stdbuf", "-o0", "-e0"] + cmd
    out = _read_until(cmd, lambda text: " BOOT " in text and len(re.findall(r" T \d", text)) >= 6, 60.0)
    text = re.sub(rb"\x1b\[[0-9;]*m", b"", out).decode("latin-1")
    lines = [x.rstrip(".") for x in text.splitlines() if "*" in x]
    boot = [x for x in lines if " BOOT " in x]
    assert boot, text[:500]
    body, crc = boot[0].rsplit("*", 1)
    assert body == "0 BOOT arduino_pump 0.1.0 2 IDLE" and crc == "%08X" % zlib.crc32(body.encode())
    tele = [x for x in lines if " T " in x]
    # seq T ms state done free, 3 x (angle, set point, duty), 3 syringes, the end-stop bits
    assert len(tele) >= 5 and all(len(x.split()) == 2 + 4 + 3 * 3 + 3 + 1 for x in tele)
    assert all(x.rsplit("*", 1)[1] == "%08X" % zlib.crc32(x.rsplit("*", 1)[0].encode()) for x in tele)


def _read_until(cmd: list[str], enough, guard_s: float) -> bytes:
    """Run cmd (stderr into stdout) and read its output until enough(text) or guard_s of wall time (a
    hang guard), then stop it; what it printed."""
    import select
    import time

    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    out = b""
    end = time.monotonic() + guard_s
    try:
        while time.monotonic() < end and not enough(re.sub(rb"\x1b\[[0-9;]*m", b"", out).decode("latin-1")):
            ready, _, _ = select.select([proc.stdout], [], [], 0.1)
            if ready:
                chunk = os.read(proc.stdout.fileno(), 65536)
                if not chunk:
                    break           # it exited
                out += chunk
    finally:
        proc.kill()
        proc.wait()
        proc.stdout.close()
    return out


@pytest.fixture(scope="module")
def native_run() -> subprocess.CompletedProcess:
    _need("g++", "make")
    return _make("native-test")


def test_native_tests_pass_under_asan_and_ubsan(native_run):
    out = native_run.stdout + native_run.stderr
    assert native_run.returncode == 0, out[-4000:]
    assert "ERROR: AddressSanitizer" not in out and "runtime error" not in out
    m = re.search(r"(\d+) checks, 0 failed", out)
    assert m and int(m.group(1)) > 2000, out[-2000:]


def test_native_tests_ran_every_vector(native_run):
    v = json.loads(VECTORS.read_text())
    m = re.search(r"vectors: meta 1, crc (\d+), good (\d+), bad (\d+), commands (\d+), streams (\d+), example (\d+)",
                  native_run.stdout)
    assert m, native_run.stdout[-2000:]
    got = [int(x) for x in m.groups()]
    assert got == [len(v[k]) for k in ("crc", "good", "bad", "commands", "streams", "example")]


def test_fuzz_target_for_a_bounded_time(fuzz_proc):
    _need("g++", "make")
    if fuzz_proc is None:
        r = _make("fuzz", *FUZZ_ARGS, timeout=FUZZ_SECONDS + 240)
    else:
        stdout, stderr = fuzz_proc.communicate(timeout=FUZZ_SECONDS + 240)
        r = subprocess.CompletedProcess(fuzz_proc.args, fuzz_proc.returncode, stdout, stderr)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-4000:]
    if shutil.which("clang++"):
        assert "Done" in out or "DONE" in out, out[-2000:]
        return
    m = re.search(r"fuzz: (\d+) mutated inputs .* 0 invariant failures", out)
    assert m and int(m.group(1)) == FUZZ_ITERATIONS, out[-2000:]   # all of them: not cut short by the clock
    stats = re.search(r"answers OK (\d+), events (\d+), modbus frames (\d+); errors: (.*)", out)
    assert stats, out[-2000:]
    errors = dict(zip(stats.group(4).split()[::2], map(int, stats.group(4).split()[1::2])))
    # the mutations reached every layer: framing, CRC, grammar, verbs, arguments, ranges, sessions
    for name in ("PARSE", "CRC", "LONG", "VERB", "ARGS", "RANGE", "SEQ", "PROTO"):
        assert errors.get(name, 0) > 0, (name, errors)
    assert int(stats.group(2)) > 0 and int(stats.group(3)) > 0


def test_the_board_is_the_soft3_robot():
    """config.h's limits are the soft3 robot's (the host checks LIM against it)."""
    from armbridge.robots.catalog import SOFT3
    text = (FW / "config.h").read_text()
    mins = [int(x) for x in re.search(r"#define LIM_MIN_MRAD \{([^}]*)\}", text).group(1).split(",")]
    maxs = [int(x) for x in re.search(r"#define LIM_MAX_MRAD \{([^}]*)\}", text).group(1).split(",")]
    vmax = [int(x) for x in re.search(r"#define VMAX_MRAD_S \{([^}]*)\}", text).group(1).split(",")]
    assert mins == [int(round(x * 1000)) for x in SOFT3.q_min]
    assert maxs == [int(round(x * 1000)) for x in SOFT3.q_max]   # the contract: 524, 960, 1047
    assert vmax == [int(round(x * 1000)) for x in SOFT3.v_max]
    assert os.path.exists(FW / "protodef.h")
