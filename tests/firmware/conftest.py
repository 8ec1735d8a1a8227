"""CPython only: puts the firmware modules on sys.path, as the emulator does.
(The MicroPython runner in tests/mpy sets its own path and never imports this.)

The firmware uses flat module names (proto, session, pid, traj, arm, config;
the MASR actuator's ma, ma_act, loc, drive). firmware/masr_ma comes after
firmware/esp32 on the path, so the flat name `config` is the arm's: the MA
tests load masr_ma's config under another name (fwma.load_config).
Once collection has imported the test modules (which keep their own
references), those names and paths are taken out of sys.modules / sys.path
again, so they do not leak into other tests in the same session (the emulator
loads private copies of the same modules).
"""
import pathlib
import sys

_ROOT = pathlib.Path(__file__).resolve().parents[2]
_PATHS = [str(_ROOT / sub) for sub in ("firmware/masr_ma", "firmware/esp32", "firmware/common", "tests/firmware")]

for _p in _PATHS:
    if _p not in sys.path:
        sys.path.insert(0, _p)

try:  # the firmware's `import micropython` (const, viper): the emulator's CPython stand-in
    import micropython  # noqa: F401
except ImportError:
    from armbridge.emulator.runner import _micropython_shim

    sys.modules["micropython"] = _micropython_shim()


def pytest_collection_finish(session):
    for name, mod in list(sys.modules.items()):  # every flat firmware module, whatever its name
        f = getattr(mod, "__file__", None) or ""
        if f.startswith(str(_ROOT / "firmware")) or f.startswith(str(_ROOT / "tests" / "firmware")):
            del sys.modules[name]
    for p in _PATHS:
        while p in sys.path:
            sys.path.remove(p)
