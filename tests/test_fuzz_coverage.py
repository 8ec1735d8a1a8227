"""Coverage-guided fuzzing, bounded (docs/fuzzing.md).

The pump board's C++ parsers under libFuzzer with ASan and UBSan
(firmware/arduino_pump/fuzz/Makefile: codec, session, modbus, board), each for
ARMBRIDGE_FUZZ_SECONDS (default 10; ARMBRIDGE_FUZZ_RUNS bounds the inputs too)
from the kept corpus and the seeds of the shared vectors; their llvm-cov coverage
over the kept corpus above the floors measured when the corpus was made; every
kept input (a crash-* one is a regression) replayed. The Python codecs (host,
MicroPython firmware's, and the C++ through ctypes) under atheris for the same
time, differentially (tests/fuzz_codecs.py), their kept corpus replayed and its
coverage above floors.

A missing clang, llvm-cov or atheris skips with the reason, and fails under
ARMBRIDGE_REQUIRE_HIL=1 (tests/require.py). The replay of the Python corpus needs
neither (g++ builds the C++ shim, else host and firmware are compared alone).
Everything builds into firmware/arduino_pump/build/pytest-fuzz; nothing is written
into the kept corpora. About a minute on two cores with the default time.
"""
import json
import os
import pathlib
import re
import shutil
import subprocess
import sys

import pytest
from require import missing

ROOT = pathlib.Path(__file__).resolve().parents[1]
FUZZ = ROOT / "firmware" / "arduino_pump" / "fuzz"
B = ROOT / "firmware" / "arduino_pump" / "build" / "pytest-fuzz"
SECONDS = int(os.environ.get("ARMBRIDGE_FUZZ_SECONDS", "10"))
RUNS = os.environ.get("ARMBRIDGE_FUZZ_RUNS", "")   # inputs per fuzzer besides the time, when given
TARGETS = ("codec", "session", "modbus", "board")

# llvm-cov over the kept corpus (firmware/arduino_pump/fuzz/corpus/<target>) when it was
# last minimised: lines / branches of the target's own sources (docs/fuzzing.md has the
# table). The floors sit a few points under, so that a change of the sources by a few
# lines does not trip them, while a corpus that lost its reach does.
#                 floor (lines, branches)     measured
CPP_FLOORS = {"codec": (95.0, 88.0),          # proto.cpp        97.2 / 90.6
              "session": (97.0, 93.0),        # session.cpp     100.0 / 96.9
              "modbus": (94.0, 90.0),         # modbus.cpp       96.5 / 93.2
              "board": (83.0, 69.0)}          # every portable   87.1 / 73.2
# coverage.py over tests/fuzz_corpus/*: measured host 85.9/80.6, firmware proto 96.6/95.3,
# firmware session 95.2/95.8 (lines / branches)
PY_FLOORS = {"host": (82.0, 76.0), "fw_proto": (94.0, 92.0), "fw_session": (92.0, 92.0)}


def _make(*args: str, timeout: int = 600) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-C", str(FUZZ), "-j2", f"B={B}", f"PYTHON={sys.executable}", *args],
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def built():
    for tool in ("clang++", "llvm-profdata", "llvm-cov", "make"):
        if shutil.which(tool) is None:
            missing(f"{tool} is not installed (scripts/setup.sh installs clang, libclang-rt-14-dev and llvm)")
    r = _make("build", "seeds", "shim")
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    return r


def test_libfuzzer_targets_run_without_a_crash(built):
    shutil.rmtree(B / "crash", ignore_errors=True)
    r = _make("run", f"FUZZ_SECONDS={SECONDS}", f"FUZZ_RUNS={RUNS}", timeout=SECONDS * len(TARGETS) + 300)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-6000:]
    for t in TARGETS:
        done = re.search(rf"fuzz {t}: #(\d+)\s+DONE\s+cov: (\d+)", out)
        assert done and int(done.group(1)) > 0, (t, out[-3000:])
    assert not list((B / "crash").glob("*")), "crash inputs in " + str(B / "crash")


def _cov_total(text: str) -> tuple[float, float]:
    """Lines and branches cover (%) from llvm-cov report's TOTAL row."""
    row = [x for x in text.splitlines() if x.startswith("TOTAL")][-1].split()
    # TOTAL regions missed cover functions missed executed lines missed cover branches missed cover
    return float(row[9].rstrip("%")), float(row[12].rstrip("%"))


def test_kept_corpus_coverage_above_the_floors(built):
    r = _make("cov", timeout=600)
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    got = {t: _cov_total((B / "cov" / f"{t}.txt").read_text()) for t in TARGETS}
    for t, (lines, branches) in CPP_FLOORS.items():
        assert got[t][0] >= lines and got[t][1] >= branches, (t, got[t], CPP_FLOORS[t], r.stdout[-3000:])


def test_every_kept_input_replays(built):
    """The kept corpora, crash-* regression inputs included, under ASan/UBSan."""
    r = _make("regress", timeout=600)
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    for t in TARGETS:
        assert f"regress {t}:" in r.stdout, r.stdout


# ------------------------------------------------------------------ Python
def _shim() -> None:
    """The C++ codec for the differential check: built with clang++ or g++ when either is here."""
    if shutil.which("make") and (shutil.which("clang++") or shutil.which("g++")):
        r = _make("shim")
        assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]


def _py(*args: str, timeout: int = 600) -> subprocess.CompletedProcess:
    env = dict(os.environ, ARMBRIDGE_CODEC_SHIM=str(B / "libcodec_shim.so"))
    return subprocess.run([sys.executable, str(ROOT / "tests" / "fuzz_codecs.py"), *args], capture_output=True,
                          text=True, timeout=timeout, env=env, cwd=ROOT)


@pytest.mark.parametrize("target", ["codec", "session"])
def test_python_corpus_replays_and_the_codecs_agree(target):
    """Every kept input (both fuzzers' corpora of this layout), crash-* ones included:
    host, MicroPython firmware and C++ give the same answers."""
    _shim()
    r = _py("replay", target, f"tests/fuzz_corpus/{target}", f"firmware/arduino_pump/fuzz/corpus/{target}")
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    assert re.search(rf"replay {target}: \d+ inputs agree", r.stdout), r.stdout
    if (B / "libcodec_shim.so").exists():
        assert "C++ included" in r.stdout, r.stdout


@pytest.mark.parametrize("target", ["codec", "session"])
def test_python_fuzzer_runs_without_a_disagreement(target, tmp_path):
    try:
        import atheris  # noqa: F401
    except ImportError:
        missing("atheris is not installed (pip install -e '.[test]')")
    _shim()
    r = _py("fuzz", target, f"-max_total_time={SECONDS}", *([f"-runs={RUNS}"] if RUNS else []), "-seed=1",
            "-max_len=1024",
            f"-artifact_prefix={tmp_path}/", str(tmp_path), f"tests/fuzz_corpus/{target}",
            f"firmware/arduino_pump/fuzz/corpus/{target}", timeout=SECONDS + 300)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-6000:]
    assert re.search(r"Done \d+ runs", out), out[-3000:]
    assert not list(tmp_path.glob("crash-*"))


def test_python_coverage_above_the_floors():
    try:
        import coverage  # noqa: F401
    except ImportError:
        missing("coverage is not installed (pip install -e '.[test]')")
    r = _py("cov")
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    for name, (lines, branches) in PY_FLOORS.items():
        assert got[name]["lines"] >= lines and got[name]["branches"] >= branches, (name, got[name])
