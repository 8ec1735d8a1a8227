"""The firmware under the real MicroPython interpreter (`--interpreter micropython`).

The emulator normally imports the firmware modules into CPython, which runs
them about nine times faster than MicroPython does. This runner boots the same
firmware files instead in the MicroPython WebAssembly interpreter from npm
(`@micropython/micropython-webassembly-pyscript`), run by Node
(`mpbridge/bridge.mjs`), against the bridge HAL of `mpbridge/bridgehal.py`, so
that the executor and the tests meet MicroPython itself: its integers, its
string formatting, its builtins, its memory.

Lockstep, one round trip per emulator tick: `poll()` sends the emulator's clock,
the bytes the UART delivered and the joint readings, the firmware runs one pass
of its main loop there, and the answer (the firmware's HAL calls, in order: UART
writes, outputs, outputs off, persisted memory, completed waypoints, and its
state) is replayed on the emulator's `SimHal`, so plant, UART lanes and the
board's records are the same objects as under CPython. Before each boot the
emulator HAL's files (`hal.files`: the IK weights) are written into the
interpreter's filesystem, where the firmware's `hal.read_file` opens them as on
the chip, and its pen servo (`hal.has_pen`) is announced; pen moves come back
in the log and are replayed on `hal.write_pen`. About 60 us of the round
trip is the pipe; the rest is MicroPython.

A boot starts a fresh Node process (a fresh interpreter: a reset loses all
module state, as on the chip; the persisted memory comes from the SimHal). The
next process is started ahead, so a reset does not stall the emulator's clock.
"""
from __future__ import annotations

import json
import os
import shutil
import weakref
from importlib import resources
from pathlib import Path
from typing import Any, Callable, Sequence

from armbridge.emulator.lineproc import LineProcess
from armbridge.errors import ArmbridgeError

PACKAGE = "@micropython/micropython-webassembly-pyscript"
PACKAGE_VERSION = "1.29.0-6"   # the version package.json pins
ENV_PACKAGE = "ARMBRIDGE_MICROPYTHON"  # path to the npm package's folder (or its micropython.mjs)
HEAP_BYTES = 512 * 1024        # MicroPython heap; an ESP32 without PSRAM has ~110 KiB free
ANSWER_TIMEOUT_S = 10.0
INSTALL = (f"run `make setup` in the armbridge checkout, or `npm install {PACKAGE}@{PACKAGE_VERSION}` "
           f"in this folder, or set {ENV_PACKAGE} to the package's folder")


class BridgeError(ArmbridgeError):
    """The Node process of the bridge failed (did not start, exited, timed out)."""


class FirmwareCrashed(RuntimeError):
    """The firmware raised under MicroPython; the message holds its traceback."""


def bridge_script() -> Path:
    """bridge.mjs, found through the installed package's resources."""
    return Path(str(resources.files("armbridge.emulator.mpbridge") / "bridge.mjs"))


def find_node() -> str:
    node = shutil.which("node")
    if node is None:
        raise ArmbridgeError("--interpreter micropython needs Node.js 18 or newer (`node` is not on PATH); "
                             "install it (apt-get install nodejs npm), then " + INSTALL)
    return node


def find_micropython() -> Path:
    """micropython.mjs of the npm package: $ARMBRIDGE_MICROPYTHON, else the copy
    the package ships (`armbridge/_data/micropython`: the wheel holds it; in the
    checkout a link to node_modules), else node_modules in the working directory
    or a folder above it, else the armbridge checkout this module runs from
    (`make setup` installs it there)."""
    env = os.environ.get(ENV_PACKAGE)
    if env:
        p = Path(env)
        mjs = p if p.suffix == ".mjs" else p / "micropython.mjs"
        if not mjs.is_file():
            raise ArmbridgeError(f"{ENV_PACKAGE}={env}: no micropython.mjs there; " + INSTALL)
        return mjs
    shipped = resources.files("armbridge").joinpath("_data", "micropython", "micropython.mjs")
    if isinstance(shipped, Path) and shipped.is_file() and shipped.with_suffix(".wasm").is_file():
        return shipped
    rel = Path("node_modules", *PACKAGE.split("/"), "micropython.mjs")
    cwd = Path.cwd().resolve()
    for base in (cwd, *cwd.parents, Path(__file__).resolve().parents[3]):
        if (base / rel).is_file():
            return base / rel
    raise ArmbridgeError(f"--interpreter micropython needs the npm package {PACKAGE} "
                         "(the MicroPython WebAssembly interpreter); " + INSTALL)


class NodeProcess(LineProcess):
    """One `node bridge.mjs` child speaking the line protocol of bridgehal.py."""

    def __init__(self, argv: list[str], timeout: float = ANSWER_TIMEOUT_S) -> None:
        super().__init__(argv, "the MicroPython bridge", timeout, error=BridgeError)
        self.version: str | None = None

    def ready(self) -> str:
        """Waits for READY; -> the MicroPython version."""
        if self.version is None:
            line = self.readline()
            if not line.startswith("READY "):
                raise BridgeError(f"the MicroPython bridge said {line[:200]!r} instead of READY{self.stderr()}")
            self.version = line[6:]
        return self.version

    def close(self, last: bytes | None = None, wait_s: float = 2.0) -> None:
        super().close(last, wait_s)


def _stop_all(procs: list[NodeProcess]) -> None:
    for p in procs:
        p.close()
    procs.clear()


class MicroPythonRunner:
    """The firmware runner of `runner.py` for the MicroPython interpreter: boots
    the firmware in `dirs` (import order) there; `boot(hal, cfg)` -> a
    `MicroPythonBoard` (poll(), state, estop(), on_done)."""

    interpreter = "micropython"

    def __init__(self, dirs: Sequence[os.PathLike | str], board_module: str = "arm",
                 config_module: str = "config", heap_bytes: int = HEAP_BYTES,
                 timeout: float = ANSWER_TIMEOUT_S) -> None:
        node = find_node()
        mjs = find_micropython()
        self.argv = [node, str(bridge_script()), str(mjs), str(int(heap_bytes)), board_module,
                     config_module, "serve", *[str(Path(d)) for d in dirs]]
        self.dirs = [Path(d) for d in dirs]
        self.config_module = config_module
        self.timeout = timeout
        self.modules: dict = {}               # the firmware does not run in this process
        self._procs: list[NodeProcess] = []   # [current, spare] or fewer
        self._finalizer = weakref.finalize(self, _stop_all, self._procs)
        self.version: str | None = None
        self._spawn()  # the first boot's interpreter loads while the emulator is built

    def config(self) -> Any:
        """The board's constants for the emulator (plant, period): the firmware's
        config module, a file of constants, read under CPython."""
        from armbridge.emulator.runner import load_firmware

        return load_firmware(self.dirs, (self.config_module,))[self.config_module]

    def set_dirs(self, dirs: Sequence[os.PathLike | str]) -> None:
        """Boot from the firmware folders `dirs` from now on (runner.boot_from);
        the spare interpreter, loaded with the old ones, is dropped."""
        self.dirs = [Path(d) for d in dirs]
        self.argv = self.argv[:self.argv.index("serve") + 1] + [str(d) for d in self.dirs]
        for p in [p for p in self._procs if p.version is None]:
            p.close()
            self._procs.remove(p)

    def _spawn(self) -> NodeProcess:
        p = NodeProcess(self.argv, self.timeout)
        self._procs.append(p)
        return p

    def boot(self, hal: Any, cfg: Any) -> "MicroPythonBoard":
        """A fresh interpreter runs the firmware's boot (`Board(hal, cfg)` there);
        the process of the previous boot ends."""
        spare = [p for p in self._procs if p.version is None]
        proc = spare[0] if spare else self._spawn()
        for old in [p for p in self._procs if p is not proc and p.version is not None]:
            old.close()
            self._procs.remove(old)
        self.version = proc.ready()
        self._spawn()  # the next boot's interpreter loads meanwhile
        return MicroPythonBoard(proc, hal, int(cfg.N_JOINTS))

    def pids(self) -> list[int]:
        """The interpreters' processes (the running one and the spare), for real-time scheduling."""
        return [p.proc.pid for p in self._procs if p.proc.poll() is None]

    def close(self) -> None:
        self._finalizer()


class MicroPythonBoard:
    """The emulator's view of a board running under MicroPython (the duck type
    of the firmware's Board: poll(), state, estop(), on_done)."""

    def __init__(self, proc: NodeProcess, hal: Any, n: int) -> None:
        self.proc = proc
        self.hal = hal
        self.state = "RESET"
        self.on_done: Callable[..., None] | None = None
        self._q = [0.0] * n
        self._flash(hal)
        self._answer(self._request("B", hal.load_persist() or b""))

    def _flash(self, hal: Any) -> None:
        """The HAL's optional parts and its files into the fresh interpreter (F, H requests)."""
        caps = json.dumps({"has_pen": bool(getattr(hal, "has_pen", False)), "uid": hal.uid()}).encode()
        calls = ["H 0 0 " + caps.hex()]
        for name, data in (getattr(hal, "files", None) or {}).items():
            if not name or any(c.isspace() for c in name):
                raise ArmbridgeError(f"a board file name must be non-empty without spaces, got {name!r}")
            calls.append("F 0 0 %s %s" % (bytes(data).hex() or "-", name))
        for line in calls:
            answer = self.proc.call(line)
            if answer != "OK":
                raise BridgeError(f"the MicroPython bridge answered {answer[:200]!r} to {line[:40]!r}...")

    def poll(self) -> bool:
        """One pass of the firmware's main loop: UART bytes in, lines handled,
        control tick if due. -> True if bytes came."""
        data = self.hal.uart_read()
        self._answer(self._request("S", data))
        return bool(data)

    def estop(self) -> None:
        self._answer(self._request("E", None))

    def _request(self, cmd: str, data: bytes | None) -> str:
        hal = self.hal
        hal.read_positions(self._q)
        line = "%s %d %d %s %s" % (cmd, hal.ticks_ms(), hal.ticks_us(), data.hex() if data else "-",
                                   " ".join(map(repr, self._q)))
        return self.proc.call(line)

    def _answer(self, answer: str) -> None:
        """Replays the firmware's HAL calls on the emulator's HAL, in order."""
        fields = answer.split("\t")
        self.state = fields[0]
        hal = self.hal
        for f in fields[1:]:
            kind, body = f[:1], f[1:]
            if kind == "T":
                hal.uart_write(bytes.fromhex(body))
            elif kind == "O":
                hal.write_outputs([float(x) for x in body.split(",")])
            elif kind == "X":
                hal.outputs_off()
            elif kind == "P":
                hal.save_persist(bytes.fromhex(body))
            elif kind == "N":
                if hasattr(hal, "write_pen"):
                    hal.write_pen(body == "1")
            elif kind == "W":
                name, _, data = body.partition(" ")
                hal.write_file(name, bytes.fromhex(data))
            elif kind == "D":
                if self.on_done is not None:
                    self.on_done(*json.loads(body))
            elif kind == "!":
                raise FirmwareCrashed("the firmware raised under MicroPython:\n" + json.loads(body))
            else:
                raise BridgeError(f"the MicroPython bridge sent an unknown field {f[:40]!r}")
