"""armbridge commands as real child processes, for the CLI tests: `Proc`
collects a child's stdout lines; `emulated_board` starts `armbridge emulate
esp32` on a pty."""
from __future__ import annotations

import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

BIN = Path(sys.executable).parent
ARMBRIDGE = str(BIN / "armbridge")
RERUN = str(BIN / "rerun")


def default_signals() -> None:
    # As at a terminal: a suite started in the background hands its children
    # ignored SIGINT/SIGHUP, which Python (and armbridge, on purpose) then keep.
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


class Proc:
    """A child process whose stdout lines are collected by a thread."""

    def __init__(self, *args: str, preexec=default_signals) -> None:
        self.p = subprocess.Popen([ARMBRIDGE, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                  preexec_fn=preexec)
        self.lines: list[str] = []
        self._q: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.p.stdout:
            self._q.put(line.rstrip("\n"))
        self._q.put(None)

    def wait_for(self, text: str, timeout: float = 120.0) -> str:
        """The first line holding `text` (already seen or still to come); `timeout` (wall clock) is a hang
        guard: a child starting on a loaded machine may take many seconds to import."""
        for line in self.lines:
            if text in line:
                return line
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            assert left > 0, f"no line with {text!r}; so far: {self.lines[-8:]}"
            try:
                line = self._q.get(timeout=left)
            except queue.Empty:
                continue
            assert line is not None, f"the process ended without {text!r}: {self.lines[-8:]}"
            self.lines.append(line)
            if text in line:
                return line

    def finish(self, timeout: float = 60.0) -> tuple[int, str]:
        """Wait for the exit: (exit code, stderr)."""
        err = self.p.stderr.read()
        rc = self.p.wait(timeout=timeout)
        while True:
            try:
                line = self._q.get(timeout=60)  # the reader's end (None) comes at once: a hang guard
            except queue.Empty:
                break
            if line is None:
                break
            self.lines.append(line)
        return rc, err

    def stop(self) -> None:
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGINT)
            try:
                self.p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait()


def emulated_board(tmp_path: Path, *extra: str):
    """`armbridge emulate esp32` on a pty, reachable as tmp_path/arm (a fixture's
    body: yields (Proc, link)); its stdout echoes BOOT and EV lines."""
    link = str(tmp_path / "arm")
    emu = Proc("emulate", "esp32", "--link", link, "--seed", "1", "-v", *extra)
    try:
        emu.wait_for("esp32 emulator on /dev/pts/")
        yield emu, link
    finally:
        emu.stop()
