"""What files a MicroPython board holds: its firmware's modules and the files its config names.

The firmware folders of a board (`MicroPythonFirmware.dirs`: e.g. esp32 then
common) land side by side at the board's root, the first folder winning a name
(as the import order does): `firmware_files`. A config may name a data file
the board loads at boot (`IK_WEIGHTS`: the board IK's int8 net, the shipped
model `models/onnx/arm3r-ik/int8.bin`): `board_files`. `armbridge flash`
writes both, and an emulated board's filesystem starts with both.
"""
from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from armbridge.errors import ArmbridgeError

#: config key -> (shipped model folder, file): a data file a board's config names, and where it comes from
CONFIG_FILES = {"IK_WEIGHTS": ("arm3r-ik", "int8.bin")}


def firmware_files(dirs: Iterable[Path]) -> dict[str, bytes]:
    """The modules of the firmware folders `dirs` as they land at the board's root:
    {name.py: bytes}, the first folder winning a name."""
    out: dict[str, bytes] = {}
    for d in dirs:
        for p in sorted(Path(d).glob("*.py")):
            out.setdefault(p.name, p.read_bytes())
    return out


def config_file(key: str) -> Path:
    """The shipped file behind the config key `key` (CONFIG_FILES)."""
    from armbridge import resources

    folder, name = CONFIG_FILES[key]
    path = resources.model_dir(folder) / name
    if not path.is_file():
        raise ArmbridgeError(f"the shipped file {path} for the boards' {key} is missing "
                             f"(armbridge train writes it: models/onnx/{folder})")
    return path


def board_files(cfg: Any) -> dict[str, bytes]:
    """The data files `cfg` names, {name on the board: bytes} (CONFIG_FILES)."""
    out: dict[str, bytes] = {}
    for key in CONFIG_FILES:
        name = getattr(cfg, key, None)
        if name:
            out[str(name)] = config_file(key).read_bytes()
    return out
