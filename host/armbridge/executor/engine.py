"""The link engine: a board's session served from its own thread or process.

A run's timing-critical work (reading the port, answering, retransmission
timers, keep-alives, streaming under credit) must keep its schedule whatever
the caller's thread does meanwhile: log to Rerun, plot, crunch numpy, or hold
the GIL in one long call. So the session (a BoardClient, or a ModbusClient)
runs here, in an `Engine`, and the caller holds a `RemoteClient`
(executor/remote.py) with the same surface, whose calls become messages
(executor/wire.py) and whose callbacks run in the caller's thread as the
engine's messages arrive. Between calls the engine keeps serving the link
(`drain` in short slices): keep-alives go out and a board that reset is
resynchronised while the caller is busy.

Where the engine runs, chosen by measurement (docs/benchmarks.md, "Runs under
load"; `armbridge bench load`):

* a child process (`python -m armbridge.executor.engine`) for a board outside
  this process: a serial device, another process's pty, a socket. Its time
  never stops, and a thread would not do: a 2 s call that holds the GIL in the
  caller's thread (sum over a range, a big sort, a C extension) stalls every
  thread of the interpreter, and the board's 1 s watchdog fired mid-plan in
  every such run with the session in the caller's thread or in a thread of its
  own; with the session in a child it never did.
* a thread for an emulator paced in this process (`emu:DEVICE`): the board
  shares the interpreter, so a call that holds the GIL stops the board's clock
  as it stops the host's (their clocks are one: `EmulatedBoard.host_time`), and
  a busy pure-Python caller only shares the GIL with it.
* none (the caller's thread, as a plain BoardClient) for a lockstep emulator
  (`speed=0`): its time advances only while its host reads, so nothing can
  fire while the caller is busy, and serving it from elsewhere would make a
  seeded run depend on thread timing instead of repeating bit for bit.

The child process is its own session leader (a Ctrl-C on the terminal reaches
the caller, which stops the run through the engine), and it sends the e-stop
byte and exits when its caller goes away without closing it (killed, crashed).
"""
from __future__ import annotations

import queue
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from contextlib import nullcontext
from typing import Any

from armbridge.executor.wire import Aborted, decode, encode, mirror, snapshot

#: the client methods a caller may run in the engine
CALLS = frozenset({"connect", "command", "ask", "can", "stat", "set_rate", "execute", "drain", "settle_tolerance"})
IDLE_SLICE_S = 0.01  # one idle service step (client clock): the longest a new call waits to start
IDLE_BACKOFF_S = 0.25  # after a failure between calls (a board gone), the next idle service step


class Engine:
    """Serves one client: runs the calls that arrive in `inbox`, posts callbacks and
    answers with `post`, and keeps the link alive between calls. `abort` is set from
    outside (an e-stop, an abandoned call) and ends the running call with Aborted."""

    def __init__(self, make_client: Callable[..., Any], post: Callable[[dict], None], inbox: "queue.Queue[dict]",
                 abort: threading.Event) -> None:
        self.post = post
        self.inbox = inbox
        self.abort = abort
        self._estop_due = threading.Event()
        self.client = make_client(on_telemetry=self._tel, on_event=self._ev, on_error=self._err,
                                  interrupt=self._interrupt, guard=nullcontext)

    def request_estop(self) -> None:
        """From any thread: the e-stop, then the running call ends. The line protocol's
        byte is out of band and goes out here and now, whatever the engine is doing;
        Modbus's is a register write, which the engine makes at its next wait, between
        two transactions (a master may not interleave them)."""
        if getattr(self.client, "estop_out_of_band", False):
            try:
                self.client.estop()
            except Exception:  # noqa: BLE001 - a port gone: the running call says so (PortGone)
                pass
        else:
            self._estop_due.set()
        self.abort.set()

    def request_hold(self, on: bool) -> None:
        """From any thread: hold (True) or resume (False) the running plan, like the e-stop out of
        band (the engine is mid-`execute`); the client sends HOLD / RESUME at its next turn."""
        request = getattr(self.client, "request_hold", None)
        if request is None:
            from armbridge.executor.hold import hold_unsupported

            self._err(None, hold_unsupported(type(self.client).__name__))
            return
        request(on)

    def _estop_if_due(self) -> None:
        if self._estop_due.is_set():
            self._estop_due.clear()
            try:
                self.client.estop()
            except Exception as exc:  # noqa: BLE001 - said to the caller, whose state check shows it
                self._err(None, f"e-stop failed: {exc}")

    # callbacks of the client: messages for the caller
    def _tel(self, t: float, m: Any) -> None:
        self.post({"k": "tel", "t": t, "m": m, "mirror": mirror(self.client)})

    def _ev(self, t: float | None, m: Any) -> None:
        self.post({"k": "ev", "t": t, "m": m, "mirror": mirror(self.client)})

    def _err(self, t: float | None, text: str) -> None:
        self.post({"k": "err", "t": t, "text": text, "mirror": mirror(self.client)})

    def _progress(self, n: int) -> None:
        self.post({"k": "progress", "n": n, "mirror": mirror(self.client)})

    def _interrupt(self) -> None:
        self._estop_if_due()
        if self.abort.is_set():
            raise Aborted("the call was ended by the caller")

    def serve(self) -> None:
        """Until `close`: calls as they come, the link served between them (after a
        failure between calls, not again for IDLE_BACKOFF_S)."""
        quiet_until = 0.0
        while True:
            live = self.client.connected
            wait = max(0.0, quiet_until - time.monotonic()) if live else 0.05
            try:
                msg = self.inbox.get(timeout=wait) if wait > 0 else self.inbox.get_nowait()
            except queue.Empty:
                if live and time.monotonic() >= quiet_until and not self._idle():
                    quiet_until = time.monotonic() + IDLE_BACKOFF_S
                continue
            self._estop_if_due()
            kind = msg["k"]
            if kind == "close":
                return
            if kind == "call":
                self._call(msg)
            else:  # abort outside a call: nothing to end
                self.abort.clear()

    def _idle(self) -> bool:
        """One slice of service between calls; False when it failed (said to the caller)."""
        self._estop_if_due()
        self.abort.clear()
        try:
            self.client.drain(IDLE_SLICE_S)
        except Aborted:
            self.abort.clear()
        except Exception as exc:  # noqa: BLE001 - a board gone between calls: said, and the next call fails
            self._err(None, f"between calls: {exc}")
            return False
        return True

    def _call(self, msg: dict) -> None:
        self._estop_if_due()
        self.abort.clear()
        name = msg["name"]
        try:
            if name not in CALLS:
                raise ValueError(f"{name!r} is not a call the engine runs")
            kw = dict(msg.get("kw") or {})
            if name == "execute" and kw.pop("progress", False):
                kw["on_progress"] = self._progress
            value = getattr(self.client, name)(*msg.get("args", ()), **kw)
            if name == "connect":
                value = None  # the snapshot carries the info
        except BaseException as exc:  # noqa: BLE001 - everything goes back to the caller
            self.post({"k": "exc", "id": msg["id"], "error": exc, "snap": snapshot(self.client)})
        else:
            self.post({"k": "ret", "id": msg["id"], "value": value, "snap": snapshot(self.client)})
        finally:
            self.abort.clear()


def client_factory(port: Any, robot: Any, kind: str, **client_kw: Any) -> Callable[..., Any]:
    """A function building the client of `kind` ("line" BoardClient, "modbus" ModbusClient) on `port`."""
    def make(**callbacks: Any) -> Any:
        if kind == "modbus":
            from armbridge.executor.modbus_client import ModbusClient

            return ModbusClient(port, robot, **client_kw, **callbacks)
        from armbridge.executor.client import BoardClient

        return BoardClient(port, robot, **client_kw, **callbacks)

    return make


def start_thread(make_client: Callable[..., Any], outbox: "queue.Queue[dict]",
                 inbox: "queue.Queue[dict]", abort: threading.Event, name: str) -> tuple[Engine, threading.Thread]:
    """An Engine on its own daemon thread (the client is built in the caller's thread first,
    so a bad argument raises there)."""
    engine = Engine(make_client, outbox.put, inbox, abort)
    t = threading.Thread(target=engine.serve, name=name, daemon=True)
    t.start()
    return engine, t


# ------------------------------------------------------------------ the child process

class _Outbox:
    """The child's messages to its caller, written by a thread of their own, so that a
    caller that does not read for a while (a long call holding its GIL) never blocks
    the engine: they wait here, in memory."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.q: deque[bytes] = deque()
        self.ready = threading.Condition()
        self.closed = False
        self._thread = threading.Thread(target=self._run, name="engine-outbox", daemon=True)
        self._thread.start()

    def post(self, msg: dict) -> None:
        data = encode(msg)
        with self.ready:
            self.q.append(data)
            self.ready.notify()

    def _run(self) -> None:
        while True:
            with self.ready:
                while not self.q and not self.closed:
                    self.ready.wait()
                if not self.q:
                    return
                data = b"".join(self.q)
                self.q.clear()
            try:
                self.sock.sendall(data)
            except OSError:
                return

    def flush_and_close(self, wait_s: float = 5.0) -> None:
        """Send what waits, then stop (waits for the thread: the process may exit next)."""
        with self.ready:
            self.closed = True
            self.ready.notify()
        self._thread.join(wait_s)


def _reader(sock: socket.socket, engine: Engine, buf: bytes = b"") -> None:
    """The caller's messages: an e-stop, an abort and a hold are acted on here and now (the
    engine may be in the middle of a call), every other message goes to the engine. The caller gone without
    `close` (killed, crashed): e-stop, and the engine is told to close."""
    chunk = b"-"
    while True:
        if not chunk:
            engine.request_estop()
            engine.inbox.put({"k": "close"})
            return
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            msg = decode(line)
            if msg["k"] == "estop":
                engine.request_estop()
                continue
            if msg["k"] == "abort":
                engine.abort.set()
                continue
            if msg["k"] == "hold":
                engine.request_hold(bool(msg["on"]))
                continue
            engine.inbox.put(msg)
            if msg["k"] == "close":
                return
        try:
            chunk = sock.recv(65536)
        except OSError:
            chunk = b""
        buf += chunk


def child_main(fd: int) -> int:
    """The child's life: an `open` message (url, robot, client arguments), the port
    opened and the client built (or the error sent back), then `Engine.serve`."""
    sock = socket.socket(fileno=fd)
    out = _Outbox(sock)
    buf = b""
    while b"\n" not in buf:
        chunk = sock.recv(65536)
        if not chunk:
            return 1
        buf += chunk
    line, rest = buf.split(b"\n", 1)
    msg = decode(line)
    from armbridge.link import transport
    from armbridge.robots.catalog import robot_from_dict

    transport.HOLDER = msg.get("holder")  # the port's lock names the caller's command, not this child
    try:
        robot = robot_from_dict(msg["robot"]) if msg.get("robot") is not None else None
        port = transport.open_port(msg["url"])
    except BaseException as exc:  # noqa: BLE001 - back to the caller, as its own open would raise
        out.post({"k": "exc", "id": 0, "error": exc, "snap": None})
        out.flush_and_close()
        return 1
    inbox: queue.Queue[dict] = queue.Queue()
    abort = threading.Event()
    try:
        engine = Engine(client_factory(port, robot, msg["kind"], **msg.get("kw", {})), out.post, inbox, abort)
        out.post({"k": "ret", "id": 0, "value": None, "snap": snapshot(engine.client)})
        threading.Thread(target=_reader, args=(sock, engine, rest), name="engine-reader", daemon=True).start()
        engine.serve()
    finally:
        port.close()
        out.flush_and_close()
    return 0


if __name__ == "__main__":  # python -m armbridge.executor.engine FD (started by remote.ProcessLink)
    sys.exit(child_main(int(sys.argv[1])))
