"""Hold and resume in the middle of a plan: the protocol's `HOLD` / `RESUME` (docs/protocol.md).

`HoldRequests` is what a client's `request_hold(on)` sets, from any thread (the
keyboard's reader, a link engine's reader, a test's callback); the client's
streaming loop takes the newest request at its next turn and sends `HOLD` or
`RESUME` as a normal checked command, answered (`hold_turn`). `PausableDeadline`
is the plan's deadline, which stops counting while the board is held: a hold as
long as the user likes never fails the run.

What a hold never does: clear a latch. The board refuses `HOLD` and `RESUME`
(`ER LATCHED`) while it is latched in ESTOP, WDOG or FAULT; the refusal is said
to the caller (on_error) and nothing else is sent (the latch then ends the run
as it would have). A Ctrl-C while held is the same e-stop as ever.

`HoldLog` is the caller's side: it follows the board's `HOLD` / `RESUME` events
(or, over Modbus, its state changes) and counts the holds and the board time held.
"""
from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from armbridge.link import protocol as P
from armbridge.link.protodef import LATCHED_STATES


class HoldRequests:
    """The newest hold / resume request, set from any thread, taken once by the streaming loop."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._want: bool | None = None

    def request(self, on: bool) -> None:
        with self._lock:
            self._want = bool(on)

    def take(self) -> bool | None:
        """The request since the last take (None: none)."""
        with self._lock:
            want, self._want = self._want, None
        return want


class PausableDeadline:
    """`seconds` from now on `now`'s clock, not counting the time `tick(held=True)` saw held."""

    def __init__(self, now: Callable[[], float], seconds: float) -> None:
        self.now = now
        self._last = now()
        self.end = self._last + seconds
        self.held_s = 0.0

    def tick(self, held: bool) -> None:
        t = self.now()
        if held:
            self.held_s += t - self._last
            self.end += t - self._last
        self._last = t

    def passed(self) -> bool:
        return self.now() > self.end


def hold_turn(client: Any, requests: HoldRequests) -> None:
    """One turn of a streaming loop: act on the newest request (HOLD or RESUME, answered),
    and keep a held board held (a board that reset and was resynchronised forgot its hold:
    it is sent again before the resent waypoints can move the arm: `_hold_lost`, set by its
    resync). `client`: a BoardClient or ModbusClient (`ask`, `state`, `_held`, `_error`)."""
    want = requests.take()
    if want is not None and want != client._held:
        _send(client, want)
    elif client._held and getattr(client, "_hold_lost", False):
        client._hold_lost = False
        client._error(None, "the board forgot its hold (it reset?): HOLD sent again")
        _send(client, True)


def release_hold(client: Any) -> None:
    """RESUME a board still held when its plan has finished (nothing is left to move)."""
    if client._held:
        _send(client, False)


def _send(client: Any, on: bool) -> None:
    verb = "HOLD" if on else "RESUME"
    ans = client.ask(verb)  # not answered in time: an ArmbridgeError, the run fails (e-stop) as for any command
    if isinstance(ans, P.Er):
        latched = f" (latched in {client.state}; nothing was cleared)" if client.state in LATCHED_STATES else ""
        client._error(None, f"the board refused {verb}: {ans.code} {ans.name}{latched}")
        return
    client._held = on


def hold_unsupported(what: str) -> str:
    """The one line a client without hold says."""
    return f"{what} cannot hold a run: pause is not available (Ctrl-C still e-stops)"


class HoldLog:
    """The caller's count of holds and board time held, from the board's events: `on_event(t, ev)`
    for every event; `intervals` (board time) once `close(t_end)` ended a hold still open.
    `on_change(held)`: called as the board reports HOLD (True) or RESUME (False)."""

    def __init__(self, on_change: Callable[[bool], None] | None = None) -> None:
        self.on_change = on_change
        self.intervals: list[tuple[float, float]] = []
        self._since: float | None = None
        self._last_t: float | None = None

    @property
    def holds(self) -> int:
        return len(self.intervals) + (self._since is not None)

    @property
    def held_s(self) -> float:
        return float(sum(b - a for a, b in self.intervals))

    def on_event(self, t: float | None, ev: Any) -> None:
        if t is not None:
            self._last_t = t
        if ev.kind == "HOLD" and self._since is None:
            self._since = t if t is not None else (self._last_t or 0.0)
            if self.on_change is not None:
                self.on_change(True)
        elif ev.kind in ("RESUME", *LATCHED_STATES, "BOOT") and self._since is not None:
            self.close(t)
            if self.on_change is not None:
                self.on_change(False)

    def close(self, t: float | None = None) -> None:
        """End an open hold at `t` (default: the last event's time)."""
        if self._since is None:
            return
        end = t if t is not None else self._last_t
        if end is not None:
            self.intervals.append((self._since, max(self._since, end)))
        self._since = None

    def note_time(self, t: float) -> None:
        """A telemetry time: where an open hold ends if the run ends while held."""
        self._last_t = t
