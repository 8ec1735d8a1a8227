"""Bench runs more than one test module reads: each made once per session.

`bench_arm3r_quick`: `armbridge bench arm3r --quick --json B --lyapunov-png P` (the
command in process, as typer runs it). test_bench_arm3r checks its tables and the
drawing runs, test_lyapunov its lyapunov key and Fig. 13; --lyapunov-png changes
nothing but the PNG it adds, so one run serves both (about 10 s each)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest


@pytest.fixture(scope="session")
def bench_arm3r_quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, Path, Path]:
    """(the CliRunner result, the JSON it wrote, the Fig. 13 PNG)."""
    from typer.testing import CliRunner

    from armbridge.bench.command import bench_app

    folder = tmp_path_factory.mktemp("bench-arm3r")
    out, png = folder / "b.json", folder / "f13.png"
    result = CliRunner().invoke(bench_app, ["arm3r", "--quick", "--json", str(out), "--lyapunov-png", str(png)])
    return result, out, png
