"""Pause and resume from the keyboard while a plan runs: the keyboard side.

`PauseKeys(on_hold)` is a context manager: on a terminal (stdin a TTY) it puts
the terminal in cbreak mode (keys arrive one at a time, unechoed, Ctrl-C still
a signal) and reads keys on a daemon thread; space or p toggles between held
and running and calls `on_hold(True)` (hold) or `on_hold(False)` (resume).
Leaving restores the terminal. Not on a terminal (a pipe, a test, a CI job),
or in the background (`armbridge run ... &`, whose reading the terminal would
stop it), it does nothing and `active` is False.

`armbridge run` and `armbridge draw --port` (and the demos, through
executor/command.py `run_command`) pass `on_hold` = the session client's
`request_hold` (executor/hold.py): the streaming loop sends HOLD / RESUME at its
next turn, and the plan's deadline stops counting while the board is held.
`on_hold` is called from the reader's thread; an exception there (the link
engine gone) ends nothing but that key's effect: the run says what happened.
"""
from __future__ import annotations

import os
import select
import sys
import threading
from collections.abc import Callable
from typing import IO

TOGGLE_KEYS = frozenset(" pP")
POLL_S = 0.1  # how often the reader looks whether it should stop


def is_toggle(key: str) -> bool:
    """Whether a key pauses or resumes: space or p."""
    return key in TOGGLE_KEYS


class PauseKeys:
    """Space or p toggles hold / resume while inside the `with` block (on a TTY only)."""

    def __init__(self, on_hold: Callable[[bool], None], stream: IO | None = None) -> None:
        self.on_hold = on_hold
        self.stream = stream if stream is not None else sys.stdin
        self.held = False
        self.active = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._saved: list | None = None
        self._fd = -1

    def __enter__(self) -> PauseKeys:
        try:
            self._fd = self.stream.fileno()
            tty_in = os.isatty(self._fd)
        except (AttributeError, OSError, ValueError):
            tty_in = False
        if not tty_in or not self._foreground():  # a background job (`armbridge run ... &`): hands off
            return self
        import termios
        import tty

        self._saved = termios.tcgetattr(self._fd)
        tty.setcbreak(self._fd)
        self.active = True
        self._thread = threading.Thread(target=self._read, name="pause-keys", daemon=True)
        self._thread.start()
        return self

    def _foreground(self) -> bool:
        """Whether this process may read its terminal: reading it (or setting its mode) from
        a background process group stops the whole process (SIGTTIN, SIGTTOU). A terminal
        that is not our controlling one (a pty a test opened) stops nothing."""
        try:
            return os.tcgetpgrp(self._fd) == os.getpgrp()
        except OSError:
            return True

    def _read(self) -> None:
        while not self._stop.is_set():
            if not self._foreground():  # put in the background meanwhile (Ctrl-Z, bg): keys wait
                self._stop.wait(POLL_S)
                continue
            try:
                ready, _, _ = select.select([self._fd], [], [], POLL_S)
                if not ready:
                    continue
                data = os.read(self._fd, 1)
            except OSError:
                return
            if not data:
                return
            if is_toggle(data.decode("latin-1")):
                self.held = not self.held
                try:
                    self.on_hold(self.held)
                except Exception:  # noqa: BLE001 - the session is gone: its run reports it
                    pass

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)
        if self._saved is not None:
            import termios

            try:
                termios.tcsetattr(self._fd, termios.TCSADRAIN, self._saved)
            except (OSError, termios.error):
                pass
        self.active = False
