"""The firmware under the real MicroPython interpreter (`--interpreter micropython`).

The emulator normally imports the firmware modules into CPython, which runs
them about nine times faster than MicroPython does. This runner boots the same
firmware files instead in the MicroPython WebAssembly interpreter from npm
(`@micropython/micropython-webassembly-pyscript`), run by Node
(`mpbridge/bridge.mjs`), against the bridge HAL of `mpbridge/bridgehal.py`
(the arm's effort rig) or `mpbridge/bridgerigs.py` (the MASR actuator, the
PCA9685 rig: `rig_of` picks it from the emulator's HAL), so
that the executor and the tests meet MicroPython itself: its integers, its
string formatting, its builtins, its memory.

Lockstep, one round trip per emulator tick: `poll()` sends the emulator's clock,
the bytes the UART delivered and the rig's sensors, the firmware runs one pass
of its main loop there, and the answer (the firmware's HAL calls, in order: UART
writes, outputs, outputs off, persisted memory, completed waypoints, the rig's
own fields, and its state) is replayed on the emulator's HAL; a question in the
middle of a pass (an I2C register read) is answered from that HAL after the
log before it is replayed. So plant, UART lanes and the
board's records are the same objects as under CPython. Before each boot the
emulator HAL's files (`hal.files`: the IK weights) are written into the
interpreter's filesystem, where the firmware's `hal.read_file` opens them as on
the chip, and its pen servo (`hal.has_pen`) is announced; pen moves and the
pen's widths (PENPOS) come back in the log and are replayed on `hal.write_pen`
and `hal.set_pen_widths`. About 60 us of the round
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


def rig_of(hal: Any) -> str:
    """The bridge's name for the rig of the emulator's HAL `hal` (bridgehal.make_hal):
    "ma" (MaSimHal: counts and hall edges in, loco/rot/grip out), "pca" (PcaSimHal:
    the firmware's PCA9685 driver on the bridged I2C bus), "arm" (SimHal: efforts)."""
    if hasattr(hal, "wheel_count"):
        return "ma"
    if getattr(hal, "POSITIONAL", False):
        return "pca"
    return "arm"


class MicroPythonBoard:
    """The emulator's view of a board running under MicroPython (the duck type
    of the firmware's Board: poll(), state, estop(), on_done)."""

    def __init__(self, proc: NodeProcess, hal: Any, n: int) -> None:
        self.proc = proc
        self.hal = hal
        self.state = "RESET"
        self.on_done: Callable[..., None] | None = None
        self.rig = rig_of(hal)
        self._q = [0.0] * n
        self._replay = self._handlers(hal)
        self._flash(hal)
        self._answer(self._request("B", hal.load_persist() or b""))

    def _flash(self, hal: Any) -> None:
        """The HAL's optional parts and its files into the fresh interpreter (F, H requests)."""
        caps = json.dumps({"has_pen": bool(getattr(hal, "has_pen", False)), "uid": hal.uid(),
                           "rig": self.rig}).encode()
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

    def _sensors(self) -> str:
        """The rig's sensor readings at the emulator's clock (bridgehal's SENSORS)."""
        hal = self.hal
        if self.rig == "ma":
            edges = hal.hall_edges()
            return "%d %d %d %s %r" % (hal.wheel_count(), hal.gear_count(), hal.hall_level(),
                                       ",".join(map(str, edges)) or "-", hal.rot_load())
        hal.read_positions(self._q)
        return " ".join(map(repr, self._q))

    def _request(self, cmd: str, data: bytes | None) -> str:
        hal = self.hal
        line = "%s %d %d %s %s" % (cmd, hal.ticks_ms(), hal.ticks_us(), data.hex() if data else "-",
                                   self._sensors())
        answer = self.proc.call(line)
        while answer.startswith("?"):   # a question mid-pass: the log so far, then the query
            fields = answer[1:].split("\t")
            self._apply(fields[:-1])
            answer = self.proc.call(self._query(fields[-1]))
        return answer

    def _query(self, q: str) -> str:
        if q[:1] == "r" and self.rig == "pca":
            addr, reg, n = (int(x) for x in q[1:].split(","))
            return self.hal.bridged_read(addr, reg, n).hex()
        raise BridgeError(f"the MicroPython bridge asked {q[:40]!r}, which this rig does not answer")

    def _handlers(self, hal: Any) -> dict[str, Callable[[str], None]]:
        """Field kind -> how it is replayed on the emulator's HAL `hal` (see bridgehal.py's docstring)."""
        def done(body: str) -> None:
            if self.on_done is not None:
                self.on_done(*json.loads(body))

        def file(body: str) -> None:
            name, _, data = body.partition(" ")
            hal.write_file(name, bytes.fromhex(data))

        def floats(body: str) -> list[float]:
            return [float(x) for x in body.split(",")]

        h: dict[str, Callable[[str], None]] = {
            "T": lambda b: hal.uart_write(bytes.fromhex(b)),
            "X": lambda b: hal.outputs_off(),
            "P": lambda b: hal.save_persist(bytes.fromhex(b)),
            "N": lambda b: hal.write_pen(b == "1") if hasattr(hal, "write_pen") else None,
            "Y": lambda b: hal.set_pen_widths(*(int(x) for x in b.split(","))),
            "W": file,
            "D": done,
        }
        if self.rig == "arm":
            h["O"] = lambda b: hal.write_outputs(floats(b))
        elif self.rig == "ma":
            h.update(L=lambda b: hal.loco(float(b)), R=lambda b: hal.rot(float(b)), G=lambda b: hal.grip(b == "1"))
        else:  # pca: the transfers drive the simulated chip; the HAL-level fields are records
            def i2c(body: str) -> None:
                addr, reg, data = body.split(",")
                hal.bridged_write(int(addr), int(reg), bytes.fromhex(data))

            h.update(I=i2c, Z=lambda b: hal.bridged_sleep_us(int(b)), Q=lambda b: hal.bridged_positions(floats(b)),
                     X=lambda b: hal.bridged_off(), N=lambda b: hal.bridged_pen(b == "1"),
                     Y=lambda b: hal.bridged_pen_widths(*(int(x) for x in b.split(","))),
                     C=lambda b: hal.bridged_calibration(*(int(x) for x in b.split(","))))
        return h

    def _apply(self, fields: list[str]) -> None:
        """Replays the firmware's HAL calls on the emulator's HAL, in order."""
        replay = self._replay
        for f in fields:
            kind, body = f[:1], f[1:]
            if kind == "!":
                raise FirmwareCrashed("the firmware raised under MicroPython:\n" + json.loads(body))
            handler = replay.get(kind)
            if handler is None:
                raise BridgeError(f"the MicroPython bridge sent an unknown field {f[:40]!r}")
            handler(body)

    def _answer(self, answer: str) -> None:
        fields = answer.split("\t")
        self.state = fields[0]
        self._apply(fields[1:])
