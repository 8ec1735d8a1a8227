"""An emulated MicroPython board's flash filesystem, and the firmware a boot runs from it.

`BoardFs` holds the files (`{path: bytes}`, paths relative to the board's /
without a leading slash) and the folders of one emulated board. It starts as
the board would after `mpremote fs cp firmware/common/*.py firmware/esp32/*.py :`:
the firmware folders' modules side by side at the root (the first folder wins
a name, as the import order does) and the files its config names (the IK
weights, `boards.files.board_files`). With `folder=` it is mirrored into a host
folder: an empty folder is seeded, a folder with files is the board's
filesystem as a previous emulator left it (so a flash survives the emulator).

The raw REPL (`repl.py`) changes it through `apply()`; a reset then boots the
firmware that is in it (`firmware_dir()`): every `X.py` as it is, and every
`X.mpy` without an `X.py` beside it (MicroPython imports `.py` first) as the
source it was compiled from. The emulator runs firmware as Python source (under
CPython, or the MicroPython WebAssembly port, which cannot run the xtensawin
native code of a viper kernel), so it looks the source up by the .mpy's
sha256 in the source cache (buildcache `remember_source`, `mpy_source`) that
`armbridge flash` fills when it compiles: the source that mpy-cross turned
into exactly those bytes. An .mpy nobody compiled here is one clear error.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterable

from armbridge.boards.files import firmware_files
from armbridge.buildcache import cache_dir, mpy_source  # noqa: F401 - cache_dir: the flash manifest's folder
from armbridge.errors import ArmbridgeError

MODULE_SUFFIXES = (".py", ".mpy")


def _norm(path: str) -> str:
    parts: list[str] = []
    for x in str(path).replace("\\", "/").split("/"):
        if x == "..":
            if parts:
                parts.pop()
        elif x and x != ".":
            parts.append(x)
    return "/".join(parts)


class BoardFs:
    """See the module docstring. `pristine` stays True until the first change:
    the board then still holds exactly its seed."""

    def __init__(self, files: dict[str, bytes] | None = None, dirs: Iterable[str] = (),
                 folder: str | os.PathLike | None = None) -> None:
        self.files: dict[str, bytes] = {_norm(k): bytes(v) for k, v in (files or {}).items()}
        self.dirs: set[str] = {_norm(d) for d in dirs} - {""}
        self.folder = Path(folder) if folder is not None else None
        self.pristine = True
        self._tmp: list[str] = []

    @classmethod
    def for_board(cls, firmware_dirs: Iterable[Path], extra: dict[str, bytes],
                  folder: str | os.PathLike | None = None) -> "BoardFs":
        """The board's filesystem: loaded from `folder` when it holds files, else
        the seed (firmware modules + `extra`), written into `folder` if given."""
        if folder is not None:
            root = Path(folder)
            if root.exists() and not root.is_dir():
                raise ArmbridgeError(f"board filesystem folder {root} is not a folder")
            if root.is_dir() and any(root.iterdir()):
                fs = cls(folder=root)
                for p in sorted(root.rglob("*")):
                    rel = p.relative_to(root).as_posix()
                    if p.is_dir():
                        fs.dirs.add(rel)
                    elif p.is_file():
                        fs.files[rel] = p.read_bytes()
                fs.pristine = False
                return fs
        fs = cls({**firmware_files(firmware_dirs), **extra}, folder=folder)
        if fs.folder is not None:
            for name, data in fs.files.items():
                fs._mirror_write(name, data)
        return fs

    # ------------------------------------------------------------ changes
    def apply(self, changes: list[list[str]]) -> None:
        """The REPL's change log (replfs.py): ["w", p, hex], ["rm", p],
        ["mkdir", p], ["rmdir", p], ["mv", a, b]."""
        for ch in changes:
            op, path = ch[0], _norm(ch[1])
            self.pristine = False
            if op == "w":
                self.files[path] = bytes.fromhex(ch[2])
                self._mirror_write(path, self.files[path])
            elif op == "rm":
                self.files.pop(path, None)
                self._mirror(lambda p: p.unlink(missing_ok=True), path)
            elif op == "mkdir":
                self.dirs.add(path)
                self._mirror(lambda p: p.mkdir(parents=True, exist_ok=True), path)
            elif op == "rmdir":
                self.dirs.discard(path)
                self._mirror(lambda p: p.rmdir() if p.is_dir() else None, path)
            elif op == "mv":
                dest = _norm(ch[2])
                self.files[dest] = self.files.pop(path)
                self._mirror(lambda p: p.unlink(missing_ok=True), path)
                self._mirror_write(dest, self.files[dest])

    def put(self, path: str, data: bytes) -> None:
        """A data file the running firmware wrote (its calibration): kept for the
        next boot and mirrored. It is not a change of firmware, so `pristine` stays."""
        self.files[_norm(path)] = bytes(data)
        self._mirror_write(_norm(path), self.files[_norm(path)])

    def _mirror(self, f: Any, path: str) -> None:
        if self.folder is not None:
            f(self.folder / path)

    def _mirror_write(self, path: str, data: bytes) -> None:
        if self.folder is not None:
            p = self.folder / path
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)

    # ------------------------------------------------------------ for a boot
    def board_files(self) -> dict[str, bytes]:
        """What the firmware may open with hal.read_file: every file but the modules."""
        return {k: v for k, v in self.files.items() if not k.endswith(MODULE_SUFFIXES)}

    def firmware_dir(self) -> Path:
        """A fresh host folder with the firmware as a boot imports it from the
        root (see the module docstring); removed by close()."""
        out = Path(tempfile.mkdtemp(prefix="armbridge-boardfs-"))
        self._tmp.append(str(out))
        try:
            for name, data in self.files.items():
                if "/" in name:
                    continue  # the firmware imports from the root only
                if name.endswith(".py"):
                    (out / name).write_bytes(data)
                elif name.endswith(".mpy") and name[:-4] + ".py" not in self.files:
                    src = mpy_source(data)
                    if src is None:
                        raise ArmbridgeError(
                            f"{name} on the emulated board was not compiled by armbridge flash on this machine "
                            f"(no source for its sha256 {hashlib.sha256(data).hexdigest()[:12]} in "
                            f"{cache_dir() / 'mpy-src'}); the emulator runs firmware from source")
                    (out / (name[:-4] + ".py")).write_bytes(src)
        except BaseException:
            shutil.rmtree(out, ignore_errors=True)
            raise
        while len(self._tmp) > 2:  # the one booted before this one may still be read
            shutil.rmtree(self._tmp.pop(0), ignore_errors=True)
        return out

    def close(self) -> None:
        for d in self._tmp:
            shutil.rmtree(d, ignore_errors=True)
        self._tmp.clear()
