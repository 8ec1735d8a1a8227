"""One way to open a session with a board: `open_session(port, robot, ...)`.

    with open_session("emu:esp32", robot, latched="refuse", rate_hz=50) as client:
        client.execute(durations_ms, q_milli)

Every caller (the `run` command, the board console, the demos) goes through
here, so they share one safety policy for a board that is latched from before
(ESTOP, WDOG or FAULT survive resets, docs/protocol.md):

* "refuse" (default): an ArmbridgeError naming the latch and `--clear`;
  nothing moves.
* "clear": CLR, then STAT again; still latched is an ArmbridgeError.
* "allow": leave it as it is (the console shows it; CLR is the user's call).

The session runs in a link engine (executor/engine.py: a child process for a
board outside this process, a thread for an emulator paced in this one) or,
for a lockstep emulator, in the caller's thread; the caller holds BoardClient's
surface either way (executor/remote.py). The port is opened with
`armbridge.link.transport.open_port` (by the child, for a process engine) and
always closed on the way out (which also stops an in-process emulator). Time:
when the port has a `clock` attribute (a callable giving seconds, e.g. an
emulator running K times faster than the wall clock), the client's timers run
on it (BoardClient takes it from the port).
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from armbridge.errors import ArmbridgeError
from armbridge.executor import calcheck
from armbridge.executor.client import LATCHED_STATES, BoardClient

LATCH_POLICIES = ("refuse", "clear", "allow")


def latch_message(state: str, reason: str | None = None) -> str:
    """The one line that says a board is latched from before and how to go on."""
    why = f" ({reason})" if reason else ""
    return (f"the board is latched in {state}{why} from before; check the arm, then run again with --clear "
            "to clear it")


def apply_latch_policy(client: BoardClient, latched: str) -> str:
    """STAT, then act on a latched board as `latched` says; returns the state."""
    state = client.stat()[0]
    if state not in LATCHED_STATES or latched == "allow":
        return state
    if latched == "refuse":
        raise ArmbridgeError(latch_message(state, client.fault_reason if state == "FAULT" else None))
    client.command("CLR")
    state = client.stat()[0]
    if state in LATCHED_STATES:
        raise ArmbridgeError(f"the board is still latched in {state} after CLR")
    return state


ENGINES = ("auto", "inline", "thread", "process")


def in_process(url: str) -> bool:
    """Whether `url` names a board this process runs itself (emu:, or Modbus over one)."""
    from armbridge.link.transport import port_scheme

    url = url.strip()
    if port_scheme(url) == "modbus":
        url = url.split(":", 1)[1]
    return port_scheme(url) == "emu"


def open_client(port: str, robot, engine: str = "auto", *, callbacks: dict | None = None, **client_kw):
    """The session's client, not yet connected, and the function that closes it and its port.

    Where its engine runs (executor/engine.py says why): "auto" picks a child process for
    a board outside this process, a thread for an emulator paced in this process, and the
    caller's own thread ("inline", a plain BoardClient) for a lockstep emulator;
    "inline", "thread" and "process" force one (a bench compares them)."""
    from armbridge.executor.remote import process_client, thread_client
    from armbridge.link.transport import open_port, port_scheme

    if engine not in ENGINES:
        raise ArmbridgeError(f"engine {engine!r}: expected one of {', '.join(ENGINES)}")
    callbacks = callbacks or {}
    kind = "modbus" if port_scheme(port.strip()) == "modbus" else "line"
    if engine == "process" or (engine == "auto" and not in_process(port)):
        client = process_client(port, robot, kind, callbacks, client_kw)
        return client, client.close
    link = open_port(port)
    try:
        emu = getattr(link, "emulator", None)
        if engine == "inline" or (engine == "auto" and emu is not None and emu.speed == 0):
            from armbridge.executor.engine import client_factory

            return client_factory(link, robot, kind, **client_kw)(**callbacks), link.close
        client = thread_client(link, robot, kind, callbacks, client_kw)
        return client, client.close
    except BaseException:
        link.close()
        raise


@contextmanager
def open_session(port: str, robot, *, latched: str = "refuse", rate_hz: int | None = None,
                 session: int | None = None, on_telemetry=None, on_event=None, on_error=None,
                 connect_timeout: float = 5.0, engine: str = "auto",
                 on_stop: Callable[[Any, KeyboardInterrupt], None] | None = None,
                 calibration: str | None = None) -> Iterator[BoardClient]:
    """Open the port, connect (HELLO, identity, limits; robot None: version and
    limits only), apply the latch policy, set the telemetry rate, and yield the
    connected client (BoardClient's surface; `engine`: where it runs, open_client);
    the port is closed on exit, whatever happens. `on_stop(client, stop)`: a stop
    signal while connecting (the run's e-stop path: the byte goes out even to a board
    that has not answered HELLO yet), before the stop goes on up. `calibration`: the
    policy of executor/calcheck.py (default: "check" with a robot, a run; "report"
    without), its result left on `client.calibration`."""
    if latched not in LATCH_POLICIES:
        raise ArmbridgeError(f"latch policy {latched!r}: expected one of {', '.join(LATCH_POLICIES)}")
    if rate_hz is not None and not (isinstance(rate_hz, int) and 0 <= rate_hz <= 100):
        raise ArmbridgeError(f"telemetry rate {rate_hz} Hz is outside [0, 100]")
    client, close = open_client(port, robot, engine, session=session, connect_timeout=connect_timeout,
                                callbacks={"on_telemetry": on_telemetry, "on_event": on_event, "on_error": on_error})
    try:
        try:
            client.connect()
            apply_latch_policy(client, latched)
            client.calibration = calcheck.check(client, calibration or ("check" if robot is not None else "report"))
            if rate_hz is not None:
                client.set_rate(rate_hz)
        except KeyboardInterrupt as stop:
            if on_stop is not None:
                on_stop(client, stop)
            raise
        yield client
    finally:
        close()
