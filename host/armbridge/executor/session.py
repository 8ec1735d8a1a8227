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

The port is opened with `armbridge.link.transport.open_port` and always closed
on the way out (which also stops an in-process emulator). Time: when the port
has a `clock` attribute (a callable giving seconds, e.g. an emulator running K
times faster than the wall clock), the client's timers run on it (BoardClient
takes it from the port).
"""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from armbridge.errors import ArmbridgeError
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


def _client_class(port: str):
    """BoardClient for the line protocol; ModbusClient (docs/modbus.md) for a modbus: port."""
    from armbridge.link.transport import port_scheme

    if port_scheme(port.strip()) == "modbus":
        from armbridge.executor.modbus_client import ModbusClient

        return ModbusClient
    return BoardClient


@contextmanager
def open_session(port: str, robot, *, latched: str = "refuse", rate_hz: int | None = None,
                 session: int | None = None, on_telemetry=None, on_event=None, on_error=None,
                 connect_timeout: float = 5.0) -> Iterator[BoardClient]:
    """Open the port, connect (HELLO, identity, limits; robot None: version and
    limits only), apply the latch policy, set the telemetry rate, and yield the
    connected BoardClient; the port is closed on exit, whatever happens."""
    if latched not in LATCH_POLICIES:
        raise ArmbridgeError(f"latch policy {latched!r}: expected one of {', '.join(LATCH_POLICIES)}")
    if rate_hz is not None and not (isinstance(rate_hz, int) and 0 <= rate_hz <= 100):
        raise ArmbridgeError(f"telemetry rate {rate_hz} Hz is outside [0, 100]")
    from armbridge.link.transport import open_port

    link = open_port(port)
    try:
        client = _client_class(port)(link, robot, session, on_telemetry=on_telemetry, on_event=on_event,
                                         on_error=on_error, connect_timeout=connect_timeout)
        client.connect()
        apply_latch_policy(client, latched)
        if rate_hz is not None:
            client.set_rate(rate_hz)
        yield client
    finally:
        link.close()
