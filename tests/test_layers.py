"""The layer order of host/armbridge (pyproject.toml [tool.importlinter], docs/architecture.md):
every room imports only the rooms below it, and no files of one room import each other in a
circle. import-linter checks the tree as it is, and fails on a copy with an upward import or
a circle added on purpose (so the contract is not one that cannot fail)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINT = str(Path(sys.executable).parent / "lint-imports")


def lint(cwd: Path, pythonpath: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(pythonpath)}
    return subprocess.run([LINT, "--no-cache", "--config", str(cwd / "pyproject.toml")], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


def copy_of_the_package(tmp: Path) -> Path:
    """host/armbridge's Python files (not its firmware or models) and pyproject.toml, under tmp."""
    shutil.copytree(ROOT / "host" / "armbridge", tmp / "host" / "armbridge",
                    ignore=shutil.ignore_patterns("_data", "__pycache__", "*.pyc"))
    shutil.copy(ROOT / "pyproject.toml", tmp / "pyproject.toml")
    return tmp / "host" / "armbridge"


def test_the_rooms_import_only_downward_and_no_room_has_a_circle():
    r = lint(ROOT, ROOT / "host")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "Contracts: 2 kept, 0 broken." in r.stdout


def test_every_room_is_in_the_contract():
    import tomllib

    layers = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"][0]["layers"]
    named = {x.strip() for line in layers for x in line.replace(":", "|").split("|")}
    pkg = ROOT / "host" / "armbridge"
    rooms = {p.name for p in pkg.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    rooms |= {p.stem for p in pkg.glob("*.py") if p.stem != "__init__"}
    assert rooms == named, (sorted(rooms - named), sorted(named - rooms))


def test_an_upward_import_breaks_the_contract(tmp_path):
    pkg = copy_of_the_package(tmp_path)
    (pkg / "robots" / "_upward.py").write_text("import armbridge.executor.run  # a robot that knows the executor\n")
    r = lint(tmp_path, tmp_path / "host")
    assert r.returncode != 0
    assert "armbridge.robots is not allowed to import armbridge.executor" in r.stdout, r.stdout[-2000:]


def test_a_circle_between_files_breaks_the_contract(tmp_path):
    pkg = copy_of_the_package(tmp_path)
    (pkg / "plans" / "_a.py").write_text("from armbridge.plans import _b  # noqa: F401\n")
    (pkg / "plans" / "_b.py").write_text("from armbridge.plans import _a  # noqa: F401\n")
    r = lint(tmp_path, tmp_path / "host")
    assert r.returncode != 0 and "No cycles are allowed in armbridge.plans" in r.stdout, r.stdout[-2000:]


def test_the_architecture_map_is_the_contract():
    """docs/architecture.md opens with the rooms in the contract's order, one row a layer."""
    import re
    import tomllib

    layers = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"][0]["layers"]
    text = (ROOT / "docs" / "architecture.md").read_text()
    rows = re.findall(r"^\| (\d+) \| (.+?) \| .+ \|$", text, flags=re.M)
    doc = [cell.replace("`", "").replace("\\|", "|").strip() for _, cell in rows]
    assert [int(n) for n, _ in rows] == list(range(1, len(layers) + 1))
    assert [re.sub(r"\s+", " ", x) for x in doc] == [re.sub(r"\s+", " ", x) for x in layers]
