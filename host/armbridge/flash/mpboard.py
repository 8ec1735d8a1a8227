"""A MicroPython board's raw REPL through mpremote, used as a library.

mpremote 1.29's `SerialTransport` (the transport `mpremote connect` builds)
does the protocol: Ctrl-C to stop the running firmware, Ctrl-A into the raw
REPL, a soft reboot (a fresh interpreter), raw paste with flow control. On it
this module runs what a flash needs, each a short program on the board:
identity (`os.uname()`, `sys.implementation`, the FW_NAME of the config
module on the board), the manifest, the sha256 of a
set of files in one round trip, `fs_writefile` / `fs_hashfile` / `fs_rmfile`
as `mpremote fs cp/sha256sum/rm` do, and `machine.reset()` as `mpremote reset`
does. Every failure is one BoardFailure naming the port.
"""
from __future__ import annotations

import ast
import io
from contextlib import redirect_stdout
from typing import Any, Callable

from armbridge.errors import ArmbridgeError, BoardFailure

_HASHES = """import hashlib, binascii
def _h(p):
    try:
        f = open(p, 'rb')
    except OSError:
        return None
    h = hashlib.sha256()
    b = bytearray(512)
    m = memoryview(b)
    while True:
        n = f.readinto(b)
        if not n:
            break
        h.update(m[:n])
    f.close()
    return binascii.hexlify(h.digest()).decode()
print(repr(dict((p, _h(p)) for p in %r)))
"""

_INFO = """import os, sys
u = os.uname()
try:
    f = open(%r)
    m = f.read()
    f.close()
except OSError:
    m = None
try:
    import config
    fw = config.FW_NAME
except Exception:
    fw = None
print(repr((sys.implementation.name, '%%d.%%d.%%d' %% sys.implementation.version[:3], u.machine, m,
            sorted(os.listdir()), fw)))
"""


def _transport_classes() -> tuple[Any, Any, Any]:
    try:
        from mpremote.transport import TransportError, TransportExecError  # type: ignore[import-untyped]
        from mpremote.transport_serial import SerialTransport  # type: ignore[import-untyped]
    except ImportError:
        raise ArmbridgeError('armbridge flash needs mpremote 1.29: pip install "mpremote==1.29.*" '
                             '(or pip install "armbridge[flash]")') from None
    return SerialTransport, TransportError, TransportExecError


class MpBoard:
    """The raw REPL of the board on the serial device `device` (a path)."""

    def __init__(self, device: str, label: str | None = None, timeout: float = 10.0) -> None:
        SerialTransport, self._TransportError, self._ExecError = _transport_classes()
        self.label = label or device
        try:
            # a read timeout: on a pty mpremote reads byte by byte, and a silent one would block for ever
            self.t = SerialTransport(device, baudrate=115200, timeout=timeout)
        except self._TransportError as exc:
            raise BoardFailure(f"cannot open {self.label}: {exc}") from None
        except OSError as exc:
            raise BoardFailure(f"cannot open {self.label}: {exc.strerror or exc}") from None
        try:
            with redirect_stdout(io.StringIO()):  # mpremote prints what it got when it fails
                self.t.enter_raw_repl(soft_reset=True, timeout_overall=timeout)
        except (self._TransportError, OSError) as exc:
            self.close()
            raise BoardFailure(f"the board on {self.label} does not answer MicroPython's raw REPL ({exc}): "
                               "is it a MicroPython board, and is nothing else using the port?") from None

    def close(self) -> None:
        try:
            self.t.close()
        except OSError:
            pass

    def _call(self, what: str, f: Callable[[], Any]) -> Any:
        try:
            with redirect_stdout(io.StringIO()):
                return f()
        except self._ExecError as exc:
            last = (exc.error_output or "").strip().splitlines()
            raise BoardFailure(f"{what} on {self.label} failed: {last[-1] if last else exc}") from None
        except (self._TransportError, OSError) as exc:
            raise BoardFailure(f"{what} on {self.label}: the board stopped answering ({exc})") from None

    def _eval(self, what: str, src: str) -> Any:
        out = self._call(what, lambda: self.t.exec(src))
        try:
            return ast.literal_eval(out.decode().strip())
        except (ValueError, SyntaxError):
            raise BoardFailure(f"{what} on {self.label}: unexpected answer {out[:80]!r}") from None

    # ------------------------------------------------------------ queries
    def info(self, manifest_name: str) -> dict[str, Any]:
        """implementation, version, machine, the manifest's text (None), the root's
        names, and the FW_NAME of the config module there (None: it has none)."""
        impl, ver, machine, text, names, fw = self._eval("reading the board", _INFO % manifest_name)
        return {"implementation": impl, "version": ver, "machine": machine, "manifest": text, "names": names,
                "firmware": fw}

    def hashes(self, names: list[str]) -> dict[str, str | None]:
        """sha256 hex of each file (None: missing), in one program."""
        return self._eval("hashing files", _HASHES % (sorted(names),))

    # ------------------------------------------------------------ changes
    def write(self, name: str, data: bytes, progress: Callable[[int, int], None] | None = None) -> None:
        self._call(f"writing {name}", lambda: self.t.fs_writefile(name, data, progress_callback=progress))

    def sha256(self, name: str) -> str:
        """The board's sha256 of one file (mpremote's fs_hashfile, as `fs cp` checks)."""
        return self._call(f"hashing {name}", lambda: self.t.fs_hashfile(name, "sha256")).hex()

    def remove(self, name: str) -> None:
        self._call(f"removing {name}", lambda: self.t.fs_rmfile(name))

    def reset(self) -> None:
        """machine.reset(), as `mpremote reset`: the board reboots and runs main.py."""
        self._call("resetting the board",
                   lambda: self.t.exec_raw_no_follow("import time, machine; time.sleep_ms(100); machine.reset()"))
        self.t.in_raw_repl = False
        self.close()
