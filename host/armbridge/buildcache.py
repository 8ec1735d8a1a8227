"""The cache folder, and the builds into it that processes share.

What armbridge builds on first use (the simavr harness, a firmware .elf from a
read-only folder, the OMPL STRIDE shim) and what it remembers (flash manifests,
the source of every .mpy it compiled) lives in one folder, so the next run, a
test worker or another interpreter finds it there. A build holds a file lock
while it runs: processes that need the same thing at once build it one after
the other, and the later ones find it built.
"""
from __future__ import annotations

import fcntl
import hashlib
import os
import subprocess
from typing import Any
from pathlib import Path

from armbridge.errors import ArmbridgeError

ENV_CACHE = "ARMBRIDGE_CACHE"
BUILD_TIMEOUT_S = 600


def cache_dir() -> Path:
    """$ARMBRIDGE_CACHE, else $XDG_CACHE_HOME/armbridge, else ~/.cache/armbridge."""
    env = os.environ.get(ENV_CACHE)
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "armbridge"


def locked_build(args: list[str], lock: Path, what: str) -> None:
    """Run the build command `args` (make, g++) holding the file lock `lock` (made
    with its folder). A failure is one ArmbridgeError naming `what`, the command and
    the end of its output."""
    lock.parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            r = subprocess.run(args, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise ArmbridgeError(f"building {what} failed: {exc}") from None
    if r.returncode != 0:
        tail = (r.stdout + r.stderr).strip()[-1500:]
        raise ArmbridgeError(f"building {what} failed ({' '.join(args)}):\n{tail}")


def _source_path(mpy: bytes) -> Path:
    return cache_dir() / "mpy-src" / (hashlib.sha256(mpy).hexdigest() + ".py")


def remember_source(mpy: bytes, source: bytes) -> None:
    """Record that `source` compiles to `mpy` (armbridge flash calls this): an emulated
    board, which runs firmware as source, boots what it was flashed with by looking the
    source up (`mpy_source`)."""
    p = _source_path(mpy)
    if p.is_file() and p.read_bytes() == source:
        return
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_bytes(source)
    os.replace(tmp, p)


def mpy_source(mpy: bytes) -> bytes | None:
    """The source `remember_source` recorded for these .mpy bytes, or None."""
    p = _source_path(mpy)
    return p.read_bytes() if p.is_file() else None


def numba_cold(*modules: Any) -> bool:
    """Whether none of the numba kernels of these modules (`@njit(cache=True)`) has a cache
    on disk yet: a fresh install, whose first planning compiles them (tens of seconds), so
    the commands say so before they start instead of sitting silent. (A kernel only ever
    called from other kernels never gets a cache of its own, hence "none", not "any".)
    Reads numba's cache index path (a FunctionCache's `_cache_file._index_path`); a numba
    without it: False."""
    seen = False
    for module in modules:
        for obj in vars(module).values():
            index = getattr(getattr(getattr(obj, "_cache", None), "_cache_file", None), "_index_path", None)
            if isinstance(index, str):
                if os.path.exists(index):
                    return False
                seen = True
    return seen
