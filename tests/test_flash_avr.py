"""armbridge flash arduino_pump: real avrdude through the Mega's real stk500v2 bootloader in simavr (issue 14 §2)."""
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from require import missing

ROOT = Path(__file__).resolve().parents[1]
BOOTLOADER = Path("/usr/share/arduino/hardware/arduino/avr/bootloaders/stk500v2/stk500boot_v2_mega2560.hex")

for tool in ("avrdude", "avr-gcc", "make"):
    if shutil.which(tool) is None:
        missing(f"{tool} is missing (scripts/setup.sh)")
if not Path("/usr/include/simavr/sim_avr.h").is_file():
    missing("libsimavr-dev is missing (scripts/setup.sh)")
if not BOOTLOADER.is_file():
    missing(f"{BOOTLOADER} is missing (arduino-core-avr, scripts/setup.sh)")


def _flash_cmd(*args: str) -> list[str]:
    return [str(Path(sys.executable).with_name("armbridge")), "flash", "arduino_pump", *args]


def _flash(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(_flash_cmd(*args), capture_output=True, text=True, timeout=600)  # builds: a hang guard


@pytest.fixture(scope="module", autouse=True)
def silent_port():
    """`armbridge flash` on a pty whose other end never answers, started before this module's
    first test: avrdude spends about 30 s in its own timeouts there (idle), beside the flash
    through the bootloader. (The test below reads what it said.)"""
    master, slave = os.openpty()
    proc = subprocess.Popen(_flash_cmd("--port", os.ttyname(slave)), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        yield proc
    finally:
        if proc.returncode is None:   # the test did not read it: the flash and its avrdude go together
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
        os.close(master)
        os.close(slave)


def test_flash_another_version_through_the_bootloader(tmp_path):
    """A copy of the firmware with FW_VERSION 9.8.7 goes through avrdude and the bootloader;
    the flash file survives, and the sketch booted from it answers HELLO with 9.8.7."""
    tree = tmp_path / "fw"
    shutil.copytree(ROOT / "firmware" / "arduino_pump", tree / "arduino_pump",
                    ignore=shutil.ignore_patterns("build"))
    cfg = tree / "arduino_pump" / "config.h"
    text = cfg.read_text()
    assert '#define FW_VERSION "0.1.0"' in text or "#define FW_VERSION" in text
    cfg.write_text(re.sub(r'#define FW_VERSION "[^"]*"', '#define FW_VERSION "9.8.7"', text))
    flash = tmp_path / "flash.bin"
    r = _flash("--port", f"emu:arduino_pump?flash={flash}", "--firmware", str(tree))
    assert r.returncode == 0, r.stderr
    m = re.search(r"(\d+) bytes written and verified .*HELLO arduino_pump 9\.8\.7 protocol 2", r.stdout)
    assert m, r.stdout
    # what avrdude wrote is in the flash file, byte for byte the .hex's image
    image = flash.read_bytes()
    assert len(image) == 256 * 1024
    hexfile = tree / "arduino_pump" / "build" / "arduino_pump.hex"
    data = {}
    base = 0
    for line in hexfile.read_text().split():
        raw = bytes.fromhex(line[1:])
        n, addr, kind = raw[0], int.from_bytes(raw[1:3], "big"), raw[3]
        if kind == 0:
            for i in range(n):
                data[base + addr + i] = raw[4 + i]
        elif kind == 2:
            base = int.from_bytes(raw[4:6], "big") << 4
    assert len(data) == int(m.group(1))
    assert all(image[a] == v for a, v in data.items())
    assert b"9.8.7" in image


def test_a_port_without_the_bootloader_is_one_line(silent_port):
    """A pty whose other end never answers (no bootloader behind it): one line, exit 1."""
    stdout, stderr = silent_port.communicate(timeout=600)  # avrdude's own ~30 s of timeouts: a hang guard
    r = subprocess.CompletedProcess(silent_port.args, silent_port.returncode, stdout, stderr)
    assert r.returncode == 1, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "does not answer the stk500v2 bootloader" in lines[0], r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("flags", [["--micropython", "IMAGE"], ["--dry-run"], ["--link", "/dev/null"], ["--force"]])
def test_an_option_of_the_micropython_boards_is_refused_on_the_mega(tmp_path, flags):
    """`--micropython` (an image for a MicroPython board), `--dry-run`, `--link`, `--force` do not apply to
    the Mega's C firmware: bad input, one line naming the option, exit 2, before any port is touched
    (--micropython was ignored once, and the flash went on)."""
    image = tmp_path / "ESP32_GENERIC.bin"
    image.write_bytes(b"\xe9" + bytes(4095))
    r = _flash("--port", str(tmp_path / "no-such-port"), *[str(image) if f == "IMAGE" else f for f in flags])
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and f"{flags[0]}: for the MicroPython boards" in lines[0], r.stderr
    assert "Traceback" not in r.stderr


def test_avrdude_that_never_finishes_is_stopped_and_leaves_nothing_behind(tmp_path, monkeypatch):
    """avrdude on a port that never answers gets AVRDUDE_S and is killed, not left spinning after
    the flash gives up (one was found still running half an hour after its port had closed)."""
    from armbridge.errors import BoardFailure
    from armbridge.flash import avrdude as A
    from armbridge.flash import TARGETS

    monkeypatch.setattr(A, "AVRDUDE_S", 1.0)
    master, slave = os.openpty()
    hexfile = tmp_path / "x.hex"
    hexfile.write_text(":00000001FF\n")
    try:
        with pytest.raises(BoardFailure, match="avrdude did not finish on silent within 1 s"):
            A.run_avrdude(TARGETS["arduino_pump"], os.ttyname(slave), hexfile, "silent")
    finally:
        os.close(master)
        os.close(slave)
    left = subprocess.run(["pgrep", "-f", f"avrdude.*{hexfile}"], capture_output=True, text=True)
    assert left.stdout.strip() == "", left.stdout
