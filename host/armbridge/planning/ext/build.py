"""Compile stride.cpp against Debian's libompl-dev (OMPL 1.5) on first use, into the cache folder.

    from armbridge.planning.ext import build
    mod = build.stride_module()      # the imported _stride extension (compiled once, then cached)

The build is keyed by the source, the compiler line and the Python ABI, so
an edit or another interpreter builds anew; scripts/setup.sh builds it once
so tests and benchmarks never pay the ~12 s compile.

Beside the ompl wheel in one process: the module links Debian's
libompl.so.16, whose soname differs from the wheel's libompl.so, and Python
loads both RTLD_LOCAL, so every OMPL symbol resolves inside its own library
(checked with LD_DEBUG=bindings, either import order). What the two do share
are the process-wide STB_GNU_UNIQUE objects of header-only code: boost.random's
constant ziggurat tables, boost.math initialisers, Eigen's cache sizes (same
contents in both) and boost.serialization singletons, which only OMPL's
PlannerDataStorage (never used here) touches.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import sys
import sysconfig
from functools import lru_cache
from pathlib import Path
from types import ModuleType

from armbridge.buildcache import cache_dir, locked_build
from armbridge.errors import ArmbridgeError

APT = "apt-get install -y --no-install-recommends libompl-dev"
OMPL_INCLUDE = Path("/usr/include/ompl-1.5")
EIGEN_INCLUDE = Path("/usr/include/eigen3")
NAME = "_stride"


def source() -> Path:
    return Path(__file__).resolve().parent / "stride.cpp"


def _pybind11_include() -> str:
    try:
        import pybind11  # type: ignore[import-not-found,unused-ignore]
    except ImportError:
        raise ArmbridgeError("OMPL STRIDE needs pybind11 to build its shim: pip install 'armbridge[ompl]'") from None
    return str(pybind11.get_include())


def missing() -> str | None:
    """None if the shim can be built (or is built) here, else what is missing and how to get it."""
    if not (OMPL_INCLUDE / "ompl/geometric/planners/stride/STRIDE.h").is_file():
        return f"libompl-dev (OMPL 1.5 headers and libompl.so) is not installed; run scripts/setup.sh as root, or: {APT}"
    if shutil.which("g++") is None:
        return "g++ is not installed (apt-get install g++)"
    if importlib.util.find_spec("pybind11") is None:
        return "pybind11 is not installed: pip install 'armbridge[ompl]'"
    return None


def command(out: Path) -> list[str]:
    """The g++ line that builds the module at `out`."""
    return ["g++", "-O2", "-shared", "-fPIC", "-std=c++17", f"-I{sysconfig.get_paths()['include']}",
            f"-I{_pybind11_include()}", f"-I{OMPL_INCLUDE}", f"-I{EIGEN_INCLUDE}", str(source()), "-o", str(out),
            "-lompl"]


@lru_cache(maxsize=1)
def stride_module() -> ModuleType:
    """The compiled _stride module: built into cache_dir()/ompl-stride-KEY/ when absent (module doc)."""
    why = missing()
    if why:
        raise ArmbridgeError(f"OMPL STRIDE: {why}")
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    probe = command(Path("OUT"))
    key = hashlib.sha256(source().read_bytes() + " ".join(probe).encode() + sys.version.encode()).hexdigest()[:16]
    folder = cache_dir() / f"ompl-stride-{key}"
    so = folder / f"{NAME}{suffix}"
    if not so.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f"{NAME}.{os.getpid()}{suffix}"  # own name, then an atomic rename: races only build twice
        locked_build(command(tmp), cache_dir() / "ompl-stride.lock", "the OMPL STRIDE shim")
        tmp.replace(so)
    spec = importlib.util.spec_from_file_location(NAME, so)
    if spec is None or spec.loader is None:
        raise ArmbridgeError(f"OMPL STRIDE: cannot load {so}")
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)
    except ImportError as exc:
        raise ArmbridgeError(f"OMPL STRIDE: loading {so} failed ({exc}); reinstall libompl-dev: {APT}") from None
    return mod
