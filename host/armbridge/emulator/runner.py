"""Firmware runners: the seam between the emulator's machinery and a firmware.

The emulator (`board.EmulatedBoard`) owns sim time, the paced UART and its
faults, the plant, resets, the pty and the threads. A runner only turns a HAL
into a running board, so one machinery serves MicroPython under CPython, the
same firmware under the real MicroPython interpreter, and a C image (an AVR
.elf) under simavr (`simavr_runner.SimavrRunner`). The firmware's config (its
constants: N_JOINTS, LIMITS_MRAD, PERIOD_MS, ...) is read once by
`firmware_config` (boards/config.py reads it as data, for every runner; a C
firmware's are the #defines of its config header) and handed to the plant factory and to every boot.
A runner is any object with:

    runner.boot(hal, cfg) -> board
                                  fresh firmware state, every call (a reset calls it
                                  again: only what the firmware saved through
                                  hal.save_persist survives); the new board prints BOOT
                                  through hal.uart_write
    runner.close()                free what it holds (a child process); called by
                                  EmulatedBoard.stop()
    runner.interpreter            optional: "cpython", "micropython", ... (for messages)
    runner.modules                optional: {name: module} of in-process firmware
                                  (tests look inside); absent when it runs elsewhere

and the board it returns with:

    board.poll()                  one pass of the firmware's main loop (it calls the HAL)
    board.state                   "IDLE", "RUN", "HOLD", "ESTOP", "WDOG", "FAULT"
    board.on_done = f             set by the emulator after boot; the firmware calls
                                  f(id, targets_milli) for every completed waypoint

`boot_from(runner, dirs, config_module)` points a runner at other folders
(a board's emulated filesystem) for its next boots.

`make_runner(spec, interpreter, root)` picks the runner; "micropython" is
`armbridge.emulator.micropython.MicroPythonRunner(dirs, board_module,
config_module)`, constructed like `CPythonRunner`.
"""
from __future__ import annotations

import importlib
import sys
import threading
import types
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from armbridge.boards import ElfFirmware, MicroPythonFirmware
from armbridge.errors import ArmbridgeError

if TYPE_CHECKING:
    from armbridge.emulator.registry import BoardSpec


class FirmwareRunner(Protocol):
    def boot(self, hal: Any, cfg: Any) -> Any: ...

    def close(self) -> None: ...


# ---------------------------------------------------------------- MicroPython under CPython

_IMPORT_LOCK = threading.Lock()


def _micropython_shim() -> types.ModuleType:
    m = types.ModuleType("micropython")
    m.const = lambda x: x  # type: ignore[attr-defined]
    m.native = lambda f: f  # type: ignore[attr-defined]
    m.viper = lambda f: f  # type: ignore[attr-defined]
    m.alloc_emergency_exception_buf = lambda n: None  # type: ignore[attr-defined]
    m.schedule = lambda f, a: f(a)  # type: ignore[attr-defined]
    return m


def load_firmware(dirs: list[Path], names: tuple[str, ...]) -> dict[str, types.ModuleType]:
    """Import the modules `names` (and whatever they import) from the folders `dirs`
    into a private namespace: fresh module objects every call, and sys.modules /
    sys.path are restored afterwards, so boards never share module state.

    Returns {module name: module} for every module of those folders that was loaded.
    """
    for d in dirs:
        if not d.is_dir():
            raise ArmbridgeError(f"firmware folder {d} is missing")
    local = {p.stem for d in dirs for p in d.glob("*.py")}
    touched = local | {"micropython"}
    with _IMPORT_LOCK:
        saved = {n: sys.modules.pop(n) for n in list(touched) if n in sys.modules}
        saved_path = list(sys.path)
        saved_dwb = sys.dont_write_bytecode
        try:
            sys.path[:0] = [str(d) for d in dirs]
            sys.dont_write_bytecode = True  # keep the firmware folders clean
            importlib.invalidate_caches()
            try:
                importlib.import_module("micropython")
            except ImportError:
                sys.modules["micropython"] = _micropython_shim()
            for n in names:
                if n not in local:
                    raise ArmbridgeError(f"firmware module {n}.py not found in {', '.join(map(str, dirs))}")
                importlib.import_module(n)
            loaded = {n: sys.modules[n] for n in local if n in sys.modules}
        finally:
            for n in touched:
                sys.modules.pop(n, None)
            sys.modules.update(saved)
            sys.path[:] = saved_path
            sys.dont_write_bytecode = saved_dwb
    return loaded


class CPythonRunner:
    """MicroPython firmware modules run under CPython (about 9x faster than
    MicroPython itself: good for logic, not for timing; see docs/emulator.md)."""

    interpreter = "cpython"

    def __init__(self, dirs: list[Path], board_module: str, config_module: str) -> None:
        self.dirs = list(dirs)
        self.board_module = board_module
        self.config_module = config_module
        self.modules: dict[str, types.ModuleType] = {}

    def boot(self, hal: Any, cfg: Any) -> Any:
        self.modules = load_firmware(self.dirs, (self.config_module, self.board_module))
        return self.modules[self.board_module].Board(hal, cfg)

    def close(self) -> None:
        pass


def boot_from(runner: Any, dirs: list[Path], config_module: str) -> Any:
    """Point `runner` at the firmware folders `dirs` for its next boots (an
    emulated board's filesystem, boardfs.BoardFs.firmware_dir) -> the config
    module found there (the firmware's own constants: FW_VERSION, ...)."""
    set_dirs = getattr(runner, "set_dirs", None)
    if set_dirs is not None:
        set_dirs(dirs)
    else:
        runner.dirs = list(dirs)
    return load_firmware(list(dirs), (config_module,))[config_module]


# ---------------------------------------------------------------- choosing one

def firmware_config(spec: BoardSpec, root: Path) -> Any:
    """The board's constants, read as data from its firmware under `root` (boards.config:
    the MicroPython config module's constants, a C firmware's config-header #defines)."""
    from armbridge import boards

    fact = boards.BOARDS.get(spec.name)
    if fact is None or fact.firmware != spec.firmware:  # a variant spec: its own firmware
        fact = boards.Board(spec.name, spec.description, spec.identity, "", spec.firmware)
    return boards.config(fact, root)


def make_runner(spec: BoardSpec, interpreter: str | None, root: Path) -> FirmwareRunner:
    """The runner for `spec`'s firmware under `interpreter` (None: the spec's first)."""
    choice = interpreter or spec.interpreters[0]
    if choice not in spec.interpreters:
        raise ArmbridgeError(f"interpreter {choice!r} cannot run the {spec.name} firmware; "
                             f"it runs under: {', '.join(spec.interpreters)}")
    fw = spec.firmware
    if isinstance(fw, ElfFirmware) and choice == "simavr":
        from armbridge.emulator.simavr_chip import firmware_elf
        from armbridge.emulator.simavr_runner import SimavrRunner
        return SimavrRunner(firmware_elf(root / fw.folder, fw.elf))
    if not isinstance(fw, MicroPythonFirmware):
        raise ArmbridgeError(f"the {spec.name} board needs the {choice} runner, which armbridge does not have yet")
    dirs = [root / d for d in fw.dirs]
    if choice == "cpython":
        return CPythonRunner(dirs, fw.board_module, fw.config_module)
    try:
        mod = importlib.import_module("armbridge.emulator.micropython")
    except ModuleNotFoundError as exc:
        if exc.name != "armbridge.emulator.micropython":
            raise
        raise ArmbridgeError("interpreter 'micropython' needs armbridge.emulator.micropython, "
                             "which this armbridge does not have yet; use --interpreter cpython") from None
    runner: FirmwareRunner = mod.MicroPythonRunner(dirs, fw.board_module, fw.config_module)
    return runner
