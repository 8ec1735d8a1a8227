"""SIGINT, SIGTERM and SIGHUP stop a run the same way: as an exception.

    with stop_on_signals():
        try:
            stream()                  # a signal raises Stopped here, once
        except Stopped as stop:       # (a KeyboardInterrupt, like Ctrl-C)
            estop(); finish()         # further signals are ignored: cleanup runs to the end
        with holding():               # a signal here waits until the block ends
            write_files()

Why an exception: the code that sends the e-stop byte, closes the recording
and writes the summary is the code that handles Ctrl-C; a terminal closing
(SIGHUP) or a process manager (SIGTERM) must take the same path, or the board
runs on until its watchdog and the .rrd has no footer. `Stopped` is a
KeyboardInterrupt so that every Ctrl-C path handles all three.

Only the first signal raises; later ones are ignored until the outermost
`stop_on_signals` exits, so a second Ctrl-C cannot cut the cleanup short (it is
bounded by timeouts). A signal that was ignored when we started (`nohup`, a
background job's SIGINT) stays ignored. Handlers can only be installed in the
main thread; elsewhere the context does nothing.
"""
from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Stopped(KeyboardInterrupt):
    """A stop signal arrived. `exit_code` is what a shell reports for it: 128 + signal number."""

    def __init__(self, signum: int) -> None:
        self.signum = int(signum)
        self.name = signal.Signals(signum).name
        super().__init__(self.name)

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


class _State:
    depth = 0
    fired: int | None = None  # the signal that raised Stopped
    hold = 0
    pending: int | None = None  # a signal that arrived while holding
    old: dict[signal.Signals, Any] = {}  # handlers as signal.getsignal gave them


def _handler(signum: int, frame: object) -> None:
    if _State.fired is not None:
        return  # already stopping
    if _State.hold:
        _State.pending = _State.pending or signum
        return
    _State.fired = signum
    raise Stopped(signum)


@contextmanager
def stop_on_signals() -> Iterator[None]:
    """Turn the stop signals into `Stopped` in this (main) thread; re-entrant."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if _State.depth == 0:
        _State.fired = None
        _State.pending = None
        _State.old = {}
        for sig in STOP_SIGNALS:
            old = signal.getsignal(sig)
            if old is signal.SIG_IGN:
                continue  # nohup / a background job: the user asked us to ignore it
            _State.old[sig] = old
            signal.signal(sig, _handler)
    _State.depth += 1
    try:
        yield
    finally:
        _State.depth -= 1
        if _State.depth == 0:
            for sig, handler in _State.old.items():
                signal.signal(sig, handler)
            _State.old = {}


@contextmanager
def holding() -> Iterator[None]:
    """Hold stop signals for the block (writing a file that must be whole); one
    that arrived meanwhile raises `Stopped` when the block ends."""
    _State.hold += 1
    try:
        yield
    finally:
        _State.hold -= 1
    if _State.hold == 0 and _State.pending is not None and _State.fired is None and _State.depth:
        signum, _State.pending = _State.pending, None
        _State.fired = signum
        raise Stopped(signum)


def stopped_by() -> int | None:
    """The signal that stopped us inside the current `stop_on_signals`, if any."""
    return _State.fired
