"""The caller's side of a session served by a link engine (executor/engine.py).

`RemoteClient` has BoardClient's surface (connect, command, ask, can, stat,
set_rate, execute, drain, estop, request_hold, settle_tolerance; state, info, stats,
fault_reason, done_index, done_times, start_times), so `armbridge run`, the
console and the demos do not know where the session runs. A call is a message
to the engine; while it runs, the engine's messages are dispatched here, in
the caller's thread: telemetry, events and notes to the callbacks, progress to
execute()'s on_progress, and at the end the call's answer with a snapshot of
what the caller reads afterwards. Whatever the callbacks do (log to Rerun,
plot, hold the GIL), the engine keeps the link's schedule.

A call left unanswered because the caller was interrupted (a stop signal
raises in the caller's thread) is aborted before the next one starts; the
e-stop is written at once by the engine's side (a thread: by this thread
itself, straight to the port; a child process: by the child's reader thread,
whatever its engine is doing), and ends the running call.

`ThreadLink` and `ProcessLink` carry the messages: queues of Python objects
to an engine thread of this process, JSON lines over a socket to a child
(executor/wire.py).
"""
from __future__ import annotations

import itertools
import queue
import select
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from typing import Any

from armbridge.errors import ArmbridgeError
from armbridge.executor.engine import client_factory, start_thread
from armbridge.executor.wire import Aborted, decode, encode, restore_snapshot
from armbridge.link import protocol as P
from armbridge.link.stats import LinkStats

OPEN_TIMEOUT_S = 60.0  # the child's start: Python, the imports, the port opened
SETTLE_S = 10.0  # the longest wait for an aborted call's answer (wall clock)
CLOSE_S = 5.0


class EngineGone(ArmbridgeError):
    """The engine stopped answering (its process died)."""

    exit_code = 1


# ------------------------------------------------------------------ links

class ThreadLink:
    """An engine on a thread of this process, over `port` (opened here)."""

    def __init__(self, port: Any, robot: Any, kind: str, client_kw: dict[str, Any]) -> None:
        self.port = port
        self._to: queue.Queue[dict] = queue.Queue()
        self._from: queue.Queue[dict] = queue.Queue()
        self._abort = threading.Event()
        make = client_factory(port, robot, kind, **client_kw)
        self._engine, self._thread = start_thread(make, self._from, self._to, self._abort, f"link-engine {port.url}")

    def send(self, msg: dict) -> None:
        self._to.put(msg)

    def recv(self, timeout: float) -> dict | None:
        try:
            return self._from.get(timeout=max(0.0, timeout))
        except queue.Empty:
            return None

    def estop(self) -> None:
        """From this thread, at once (Engine.request_estop: the engine may be mid-call)."""
        self._engine.request_estop()

    def hold(self, on: bool) -> None:
        """From any thread: hold or resume the running plan (Engine.request_hold)."""
        self._engine.request_hold(on)

    def abort(self) -> None:
        self._abort.set()

    def close(self) -> None:
        self._abort.set()
        self._to.put({"k": "close"})
        self._thread.join(CLOSE_S)
        self.port.close()


class ProcessLink:
    """An engine in a child process (`python -m armbridge.executor.engine`), which opens `url`."""

    def __init__(self, url: str, robot: Any, kind: str, client_kw: dict[str, Any]) -> None:
        from armbridge.link.transport import holder_text
        from armbridge.robots.catalog import robot_to_dict

        self.url = url
        self._send_lock = threading.Lock()
        parent, child = socket.socketpair()
        self._err = tempfile.TemporaryFile()
        try:
            self.proc = subprocess.Popen([sys.executable, "-m", "armbridge.executor.engine", str(child.fileno())],
                                         pass_fds=[child.fileno()], stdin=subprocess.DEVNULL,
                                         stdout=subprocess.DEVNULL, stderr=self._err, start_new_session=True)
        except OSError as exc:
            parent.close()
            raise ArmbridgeError(f"cannot start the link engine: {exc}") from None
        finally:
            child.close()
        self.sock = parent
        self._buf = b""
        self.send({"k": "open", "url": url, "robot": robot_to_dict(robot) if robot is not None else None,
                   "kind": kind, "kw": client_kw, "holder": holder_text()})
        reply = self.recv(OPEN_TIMEOUT_S)
        if reply is None or reply["k"] != "ret":
            self._reap()
            if reply is not None and reply["k"] == "exc":
                raise reply["error"]
            raise EngineGone(f"the link engine for {url} did not start{self._stderr()}")

    def send(self, msg: dict) -> None:
        try:
            with self._send_lock:  # the keyboard's thread may send a hold while this one sends a call
                self.sock.sendall(encode(msg))
        except OSError as exc:
            raise EngineGone(f"the link engine for {self.url} is gone ({exc}){self._stderr()}") from None

    def recv(self, timeout: float) -> dict | None:
        end = time.monotonic() + max(0.0, timeout)
        while b"\n" not in self._buf:
            left = end - time.monotonic()
            r, _, _ = select.select([self.sock], [], [], max(0.0, left))
            if not r:
                return None
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                raise EngineGone(f"the link engine for {self.url} exited{self._stderr()}")
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        return decode(line)

    def estop(self) -> None:
        self.send({"k": "estop"})

    def hold(self, on: bool) -> None:
        """From any thread: the child's reader hands it to its engine at once (Engine.request_hold)."""
        self.send({"k": "hold", "on": bool(on)})

    def abort(self) -> None:
        self.send({"k": "abort"})

    def _stderr(self) -> str:
        try:
            self._err.seek(0)
            tail = self._err.read()[-1500:].decode("utf-8", "replace").strip()
        except (OSError, ValueError):
            return ""
        return f": {tail}" if tail else ""

    def _reap(self) -> None:
        try:
            self.proc.wait(CLOSE_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.sock.close()
        self._err.close()

    def close(self) -> None:
        """End the running call, if any, then the engine (which closes the port)."""
        try:
            self.send({"k": "abort"})
            self.send({"k": "close"})
        except EngineGone:
            pass
        self._reap()


class PortName:
    """What a caller can know of a port another process has open: its url."""

    emulator = None
    clock = None

    def __init__(self, url: str) -> None:
        self.url = url


# ------------------------------------------------------------------ the client

class RemoteClient:
    """BoardClient's surface over a link to an engine (module docstring)."""

    speed = 1.0

    def __init__(self, link: ThreadLink | ProcessLink, robot: Any, *, now: Callable[[], float],
                 on_telemetry: Callable[[float, P.Telemetry], None] | None = None,
                 on_event: Callable[[float | None, P.Event], None] | None = None,
                 on_error: Callable[[float | None, str], None] | None = None) -> None:
        self.link = link
        self.port: Any = link.port if isinstance(link, ThreadLink) else PortName(link.url)
        self.robot = robot
        self.now = now
        self.on_telemetry, self.on_event, self.on_error = on_telemetry, on_event, on_error
        self.state: str | None = None
        self.last_event: str | None = None
        self.fault_reason: str | None = None
        self.done_index = -1
        self.info: Any = None
        self.calibration: Any = None
        self.stats = LinkStats()
        self.connected = False
        self.session: int | None = None
        self.done_times: dict[int, float] = {}
        self.start_times: dict[int, float] = {}
        self._ids = itertools.count(1)
        self._pending: int | None = None
        self._on_progress: Callable[[int], None] | None = None

    # ------------------------------------------------------------ messages
    def _mirror(self, m: dict[str, Any]) -> None:
        self.state, self.last_event = m["state"], m["last_event"]
        self.fault_reason, self.done_index = m["fault_reason"], m["done_index"]

    def _dispatch(self, msg: dict) -> None:
        kind = msg["k"]
        if "mirror" in msg:
            self._mirror(msg["mirror"])
        if kind == "tel" and self.on_telemetry is not None:
            self.on_telemetry(msg["t"], msg["m"])
        elif kind == "ev" and self.on_event is not None:
            self.on_event(msg["t"], msg["m"])
        elif kind == "err" and self.on_error is not None:
            self.on_error(msg["t"], msg["text"])
        elif kind == "progress" and self._on_progress is not None:
            self._on_progress(msg["n"])
        elif kind in ("ret", "exc") and msg.get("snap") is not None:
            snap = restore_snapshot(msg["snap"])
            self._mirror(snap)
            self.info, self.stats, self.connected = snap["info"], snap["stats"], snap["connected"]
            self.session, self.done_times, self.start_times = snap["session"], snap["done_times"], snap["start_times"]

    def _answer(self, cid: int, until: Callable[[], bool] | None = None, limit_s: float | None = None) -> dict:
        """Dispatch messages until the answer of call `cid`; `until()` true: abort the call
        (its Aborted answer is then the end); `limit_s` (wall clock): give up (EngineGone)."""
        aborted = False
        end = None if limit_s is None else time.monotonic() + limit_s
        while True:
            msg = self.link.recv(0.05)
            if msg is not None:
                self._dispatch(msg)
                if msg["k"] in ("ret", "exc") and msg.get("id") == cid:
                    return msg
            if until is not None and not aborted and until():
                self.link.abort()
                aborted = True
            if end is not None and time.monotonic() > end:
                raise EngineGone("the link engine did not answer an aborted call")

    def _settle_pending(self) -> None:
        """A call the caller stopped waiting for (interrupted): aborted, its answer awaited."""
        if self._pending is None:
            return
        cid, self._pending = self._pending, None
        self.link.abort()
        self._answer(cid, limit_s=SETTLE_S)

    def _call(self, name: str, *args: Any, until: Callable[[], bool] | None = None, **kw: Any) -> Any:
        self._settle_pending()
        cid = next(self._ids)
        self.link.send({"k": "call", "id": cid, "name": name, "args": list(args), "kw": kw})
        self._pending = cid
        msg = self._answer(cid, until)
        self._pending = None
        if msg["k"] == "exc":
            if until is not None and isinstance(msg["error"], Aborted):
                return None
            raise msg["error"]
        return msg["value"]

    # ------------------------------------------------------------ BoardClient's surface
    def connect(self, timeout: float | None = None) -> Any:
        self._call("connect", timeout)
        return self.info

    def command(self, verb: str, *args: Any, timeout: float | None = None) -> P.Ok:
        return self._call("command", verb, *args, timeout=timeout)

    def ask(self, verb: str, *args: Any, timeout: float | None = None) -> P.Ok | P.Er:
        return self._call("ask", verb, *args, timeout=timeout)

    def can(self, verb: str, *args: Any, timeout: float | None = None) -> bool:
        return bool(self._call("can", verb, *args, timeout=timeout))

    def stat(self) -> tuple[str, int | None, int | None, float]:
        return tuple(self._call("stat"))  # type: ignore[return-value]

    def set_rate(self, hz: int) -> None:
        self._call("set_rate", int(hz))

    def settle_tolerance(self, n: int) -> Any:
        return self._call("settle_tolerance", n)

    def execute(self, durations_ms, q_milli, on_progress: Callable[[int], None] | None = None,
                timeout: float | None = None, *, verb: str = "W", pen=None, commands=None) -> None:
        self._on_progress = on_progress
        try:
            self._call("execute", [int(d) for d in durations_ms], [[int(v) for v in row] for row in q_milli],
                       timeout=timeout, verb=verb, pen=None if pen is None else [int(x) for x in pen],
                       commands=None if commands is None else [(v, [int(a) for a in args]) for v, args in commands],
                       progress=on_progress is not None)
        finally:
            self._on_progress = None

    def drain(self, seconds: float, until: Callable[[], bool] | None = None, *, resync: bool = True) -> None:
        """The engine serves the link for `seconds` of the client clock, or until `until()`
        (checked here, as the messages arrive: the engine is then told to stop)."""
        if until is not None and until():
            return
        self._call("drain", seconds, resync=resync, until=until)

    def estop(self) -> None:
        self.link.estop()

    def request_hold(self, on: bool) -> None:
        """From any thread: hold (True) or resume (False) the running plan, out of band like the
        e-stop (BoardClient.request_hold, in the engine)."""
        self.link.hold(on)

    def close(self) -> None:
        self.link.close()


def thread_client(port: Any, robot: Any, kind: str, callbacks: dict[str, Any],
                  client_kw: dict[str, Any]) -> RemoteClient:
    """A RemoteClient whose engine runs in a thread of this process, over `port` (opened here)."""
    link = ThreadLink(port, robot, kind, client_kw)
    clock = getattr(port, "clock", None)
    return RemoteClient(link, robot, now=clock if callable(clock) else time.monotonic, **callbacks)


def process_client(url: str, robot: Any, kind: str, callbacks: dict[str, Any],
                   client_kw: dict[str, Any]) -> RemoteClient:
    """A RemoteClient whose engine runs in a child process, which opens `url`."""
    return RemoteClient(ProcessLink(url, robot, kind, client_kw), robot, now=time.monotonic, **callbacks)
