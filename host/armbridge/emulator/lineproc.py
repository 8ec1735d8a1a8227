"""A child process spoken to one line at a time over pipes, with a timeout.

The emulator's out-of-process runners are such children: `node bridge.mjs`
(the MicroPython interpreter, emulator/micropython.py), `node repl.mjs` (the
REPL console) and the simavr harness (emulator/simavr_runner.py). Each request
is one line on the child's stdin and each answer one line on its stdout;
stderr goes to a temporary file whose tail every error names, so a child that
hangs, dies or says something unexpected is one clear ArmbridgeError (of the
caller's class) rather than a hung emulator.
"""
from __future__ import annotations

import os
import select
import subprocess
import tempfile

from armbridge.errors import ArmbridgeError

STDERR_TAIL = 1500  # bytes of the child's stderr an error quotes


class LineProcess:
    """`argv` started with pipes; `what` names it in errors ("the simavr harness");
    `error`: the ArmbridgeError subclass raised; `encoding` of the lines."""

    def __init__(self, argv: list[str], what: str, timeout: float, *, error: type[ArmbridgeError] = ArmbridgeError,
                 encoding: str = "latin-1") -> None:
        self.what = what
        self.timeout = timeout
        self.error = error
        self.encoding = encoding
        self._err = tempfile.TemporaryFile()
        try:
            # Its own session: a signal to the caller's process group (Ctrl-C on the terminal,
            # `timeout`, a service manager's stop) is the caller's to act on; the child ends
            # when its stdin does.
            self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._err,
                                         bufsize=0, start_new_session=True)
        except OSError as exc:
            self._err.close()
            raise error(f"cannot start {what}: {exc}") from None
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self._in, self._out = self.proc.stdin.fileno(), self.proc.stdout.fileno()
        self._buf = bytearray()

    def send(self, line: str) -> None:
        try:
            os.write(self._in, line.encode(self.encoding) + b"\n")
        except OSError as exc:
            raise self.error(f"{self.what} is gone ({exc}){self.stderr()}") from None

    def call(self, line: str) -> str:
        """One request line -> its answer line."""
        self.send(line)
        return self.readline()

    def readline(self) -> str:
        while True:
            i = self._buf.find(b"\n")
            if i >= 0:
                line = bytes(self._buf[:i]).decode(self.encoding, "replace")
                del self._buf[:i + 1]
                return line
            r, _, _ = select.select([self._out], [], [], self.timeout)
            if not r:
                raise self.error(f"{self.what} did not answer within {self.timeout:g} s{self.stderr()}")
            chunk = os.read(self._out, 1 << 16)
            if not chunk:
                self.proc.wait(timeout=5)
                raise self.error(f"{self.what} exited (status {self.proc.returncode}){self.stderr()}")
            self._buf += chunk

    def stderr(self) -> str:
        """': <the tail of the child's stderr>', or '' (for the end of an error message)."""
        try:
            self._err.seek(0)
            tail = self._err.read()[-STDERR_TAIL:].decode("utf-8", "replace").strip()
        except (OSError, ValueError):
            return ""
        return f": {tail}" if tail else ""

    def close(self, last: bytes | None = None, wait_s: float = 5.0) -> None:
        """Stop the child: `last` (e.g. b"QUIT\\n") first, then its stdin closed; killed if it lingers."""
        p = self.proc
        if p.poll() is None:
            try:
                if last:
                    os.write(self._in, last)
                p.stdin.close()  # type: ignore[union-attr]
                p.wait(timeout=wait_s)
            except (OSError, subprocess.TimeoutExpired):
                p.kill()
                p.wait()
        for f in (p.stdout, self._err):
            try:
                f.close()  # type: ignore[union-attr]
            except OSError:
                pass
