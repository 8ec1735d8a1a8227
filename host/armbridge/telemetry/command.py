"""`armbridge view FILE`: open a run's .rrd recording in the Rerun viewer."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import typer

from armbridge.errors import ArmbridgeError


def rerun_executable() -> str:
    """The `rerun` viewer of this environment: beside the Python running us, else on PATH."""
    here = Path(sys.executable).parent / "rerun"
    if here.is_file():
        return str(here)
    found = shutil.which("rerun")
    if found is None:
        raise ArmbridgeError("the rerun viewer is not installed: pip install rerun-sdk==0.41.0")
    return found


def view_cmd(
    file: Path = typer.Argument(..., help="A recording (.rrd) written by `armbridge run`."),
) -> None:
    """Open a recording in the Rerun viewer."""
    if not file.exists():
        raise ArmbridgeError(f"{file}: no such recording")
    if not file.is_file():
        raise ArmbridgeError(f"{file}: is not a file (a recording is an .rrd file)")
    exe = rerun_executable()
    try:
        rc = subprocess.run([exe, str(file)], check=False).returncode
    except OSError as exc:
        raise ArmbridgeError(f"cannot start the rerun viewer ({exe}): {exc.strerror}") from None
    except KeyboardInterrupt:
        rc = 0
    if rc != 0:
        raise typer.Exit(rc)
