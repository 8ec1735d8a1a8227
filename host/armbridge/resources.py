"""Where the package's shipped files are: firmware, models, environments, test vectors.

Every lookup goes through `importlib.resources`, so it finds the files of the
installed package, wherever it is installed and whatever the working directory:
never the checkout (`Path(__file__).parents[3]`) or a path relative to the cwd.

The project keeps its top-level layout (`firmware/`, `models/`, `tests/vectors/`),
and the package sees them as `armbridge/_data/{firmware,models,vectors}`:

* in the checkout these are symlinks (`host/armbridge/_data/*` -> the top-level
  folders), so an editable install (`pip install -e .`, what `make setup` does)
  reads the checkout's files as they are edited;
* `python -m build` follows the symlinks: the sdist and the wheel hold real
  copies (pyproject's package-data lists which files), so an installed wheel
  and a wheel built from the sdist read their own files.

The functions return `pathlib.Path`: the firmware is loaded as files by the
emulator and by mpy-cross, so a resource must be a real file on disk (a wheel is
always installed unpacked; a zip import cannot run the emulator).
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from armbridge.errors import ArmbridgeError


def _resource(*parts: str) -> Path:
    """The package resource `armbridge/<parts>` as a Path that exists."""
    node = files("armbridge").joinpath(*parts)
    if not isinstance(node, Path):
        raise ArmbridgeError(f"armbridge is installed as an archive ({node}); "
                             "install it unpacked (pip install armbridge) to use its shipped files")
    if not node.exists():
        raise ArmbridgeError(f"the installed armbridge package lacks {'/'.join(parts)} ({node}); "
                             "reinstall it (pip install --force-reinstall armbridge)")
    return node


def firmware_dir() -> Path:
    """The firmware sources: `common/`, `esp32/`, and each further board's folder."""
    return _resource("_data", "firmware")


def models_dir() -> Path:
    """The shipped ONNX models and their cards (`models/onnx` in the checkout)."""
    return _resource("_data", "models", "onnx")


def model_dir(name: str) -> Path:
    """One shipped model's folder or file under models_dir(), e.g. `smm-arm3r`
    (not checked: the caller names what is missing in its own words)."""
    return models_dir() / name


def envs_dir() -> Path:
    """The built-in MASR planning environments E1, E2, E3 (`planning/masr/envs/*.json`)."""
    return _resource("planning", "masr", "envs")


def vectors_file() -> Path:
    """The protocol test vectors shared by every codec (`tests/vectors/lines.json`)."""
    return _resource("_data", "vectors", "lines.json")
