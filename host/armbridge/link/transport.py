"""Byte transports to a board: `open_port(url)`.

A url is one of
  /dev/ttyUSB0, COM3        a serial device (opened exclusively, see below)
  socket://host:port, loop://, rfc2217://...   any pyserial URL (serial.serial_for_url)
  emu:DEVICE[?k=v&...]      an emulated board started in this process (the emulator
                            package's opener, docs/emulator.md lists the parameters)

Which opener serves a url is decided by the scheme table `SCHEMES` (scheme ->
"module:function" of an `opener(url, baud, timeout) -> Port`), then by "://"
(pyserial), else it is a device path. The table names openers by import path,
so this module imports no emulator code; a new kind of port is one entry.

Ports are exclusive. A serial device is locked twice: with pyserial's
`exclusive=True` (flock on the device: any program that honours it is kept
out) and with a lock file of our own that holds the holder's pid and command
line, so a second armbridge on a busy port is told in one line who holds it.

Every port error is one line with one hint (a `PortError`): missing device,
not a serial device, busy, no permission, and a port that goes away mid-run
("unplugged?", raised by `Port.read`/`write` as `PortGone`).

The returned `Port` has read(n), write(b), flush(), in_waiting, timeout,
baudrate, reset_input_buffer(), close() (which also releases the lock and stops
an in-process emulator), `.emulator` (the EmulatedBoard, or None) and `.clock`
(None, or a callable giving seconds on the board's time scale: an emulator
running K times faster than the wall clock; the session runs its timers on it).
"""
from __future__ import annotations

import errno
import fcntl
import importlib
import os
import re
import stat
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import serial  # type: ignore[import-untyped]

from armbridge.errors import ArmbridgeError

DEFAULT_BAUD = 115200
PORT_KINDS = "a serial device (/dev/ttyUSB0), a pyserial URL (socket://, rfc2217://, loop://) or emu:DEVICE"

# scheme -> "module:function" of opener(url, baud, timeout) -> Port. An opener
# raises PortError for trouble with the port itself (busy, gone: exit 1); any
# other ArmbridgeError it raises says the url is wrong (bad input: exit 2).
SCHEMES: dict[str, str] = {
    "emu": "armbridge.emulator.url:open_emu_port",
    # An emulated board is switched into Modbus through a line session: the executor's.
    "modbus": "armbridge.executor.modbus_open:open_modbus_port",
}


class PortError(ArmbridgeError):
    """A port that cannot be opened or used, in one line with one hint.

    `usage` is True when the port value itself is wrong (no such device, not a
    serial device, unknown kind): nothing was tried on a board, so the command
    line is at fault (exit code 2), not the run.
    """

    def __init__(self, message: str, *, usage: bool = False) -> None:
        super().__init__(message)
        self.usage = usage
        self.exit_code = 2 if usage else 1


class PortGone(PortError):
    """The port failed mid-run (a USB adapter unplugged, the emulator gone)."""


class Port:
    """A byte link to a board: a thin wrapper over a pyserial object that turns
    I/O errors into `PortGone` and releases the port's lock on close."""

    def __init__(self, ser: Any, url: str, emulator: Any = None, *, clock: Callable[[], float] | None = None,
                 lock: "PortLock | None" = None) -> None:
        self._ser = ser
        self.url = url
        self.emulator = emulator
        self.clock = clock
        self._lock = lock

    def _gone(self, what: str, exc: Exception) -> PortGone:
        return PortGone(f"the port {self.url} went away: unplugged? ({what}: {exc})")

    def read(self, n: int = 1) -> bytes:
        """Up to n bytes; waits at most `timeout` seconds for them."""
        if self.emulator is not None:
            self.emulator.host_reading()  # a lockstep emulator waits for its host (EmulatedBoard.couple)
        try:
            return self._ser.read(n)
        except (serial.SerialException, OSError) as exc:
            raise self._gone("read", exc) from None

    def write(self, data: bytes) -> int:
        try:
            n = self._ser.write(data)
        except (serial.SerialException, OSError) as exc:
            raise self._gone("write", exc) from None
        return len(data) if n is None else n

    def flush(self) -> None:
        try:
            self._ser.flush()
        except (serial.SerialException, OSError) as exc:
            raise self._gone("flush", exc) from None

    @property
    def in_waiting(self) -> int:
        try:
            return self._ser.in_waiting
        except (serial.SerialException, OSError) as exc:
            raise self._gone("poll", exc) from None

    @property
    def baudrate(self) -> int:
        return int(getattr(self._ser, "baudrate", DEFAULT_BAUD) or DEFAULT_BAUD)

    @property
    def timeout(self) -> float | None:
        return self._ser.timeout

    @timeout.setter
    def timeout(self, value: float | None) -> None:
        self._ser.timeout = value

    def reset_input_buffer(self) -> None:
        try:
            self._ser.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            raise self._gone("reset", exc) from None

    @property
    def is_open(self) -> bool:
        return bool(self._ser.is_open)

    def close(self) -> None:
        try:
            try:
                self._ser.close()
            except (serial.SerialException, OSError):
                pass  # an unplugged device: closing what is left is all we can do
        finally:
            if self._lock is not None:
                self._lock.release()
                self._lock = None
            if self.emulator is not None:
                self.emulator.stop()

    def __enter__(self) -> "Port":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Port({self.url!r})"


# ---------------------------------------------------------------------- locks
def lock_dir() -> Path:
    """Where the lock files live: per user ($XDG_RUNTIME_DIR/armbridge, else
    <tmp>/armbridge-<uid>). Other users are kept out by the device flock."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    base = Path(runtime) / "armbridge" if runtime else Path(tempfile.gettempdir()) / f"armbridge-{os.getuid()}"
    base.mkdir(mode=0o700, parents=True, exist_ok=True)
    return base


def _command_line() -> str:
    """This process's command line, as a user would recognise it (at most 200 characters)."""
    argv = list(sys.argv)
    if not argv or os.path.basename(argv[0]) in ("", "-c", "-m", "__main__.py"):  # python -c / -m: ask /proc
        try:
            argv = Path("/proc/self/cmdline").read_bytes().decode("utf-8", "replace").split("\0")[:-1]
        except OSError:
            argv = argv or ["python"]
    argv[0] = os.path.basename(argv[0]) or argv[0]
    text = " ".join(argv)
    return text if len(text) <= 200 else text[:197] + "..."


#: What a lock file says of its holder ("pid\ncommand line\n"); None: this process. A link
#: engine's child (executor/engine.py) opens the port for its caller and names the caller.
HOLDER: str | None = None


def holder_text() -> str:
    """'pid\ncommand line\n' of this process, as a port's lock file holds it."""
    return f"{os.getpid()}\n{_command_line()}\n"


class PortLock:
    """An flock on a lock file named after the device's real path, holding
    'pid\\ncommand line\\n' of the holder. Never unlinked (unlinking a lock
    file races with the next opener); emptied when released."""

    def __init__(self, fd: int, path: Path) -> None:
        self.fd = fd
        self.path = path

    @classmethod
    def acquire(cls, device: str, shown: str) -> "PortLock":
        path = lock_dir() / (device.strip("/").replace("/", "_") + ".lock")
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _read_holder(fd)
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise PortError(f"port {shown} is busy: {holder} holds it; stop that first or use another port") \
                    from None
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, (HOLDER or holder_text()).encode(), 0)
        return cls(fd, path)

    def release(self) -> None:
        try:
            os.ftruncate(self.fd, 0)
        except OSError:
            pass
        os.close(self.fd)  # closing drops the flock


def _read_holder(fd: int) -> str:
    try:
        text = os.pread(fd, 4096, 0).decode("utf-8", "replace")
    except OSError:
        text = ""
    lines = text.splitlines()
    if len(lines) >= 2 and lines[0].strip().isdigit():
        return f"{lines[1].strip()!r} (pid {lines[0].strip()})"
    return "another armbridge"


# ---------------------------------------------------------------------- openers
def _load_opener(target: str) -> Callable[..., Port]:
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def port_scheme(url: str) -> str | None:
    """'emu:esp32?x=1' -> 'emu'; 'socket://h:1' -> 'socket'; '/dev/ttyUSB0', 'COM3' -> None."""
    m = re.match(r"([A-Za-z][A-Za-z0-9+.-]+):", url)
    return m.group(1).lower() if m else None


def open_port(url: str, baud: int = DEFAULT_BAUD, timeout: float | None = 0.1) -> Port:
    """Open a serial device, a pyserial URL or a port from the scheme table (`emu:DEVICE?...`)."""
    if not url or not url.strip():
        raise PortError(f"empty port: give {PORT_KINDS}", usage=True)
    url = url.strip()
    scheme = port_scheme(url)
    if scheme in SCHEMES:
        opener = _load_opener(SCHEMES[scheme])
        try:
            return opener(url, baud, timeout)
        except PortError:
            raise
        except ArmbridgeError as exc:
            raise PortError(str(exc), usage=True) from None
    if "://" in url:
        return open_url(url, baud, timeout)
    if scheme is not None:
        raise PortError(f"unknown port kind {scheme + ':'!r} in {url!r}: give {PORT_KINDS}", usage=True)
    return open_device(url, baud, timeout)


def open_url(url: str, baud: int = DEFAULT_BAUD, timeout: float | None = 0.1) -> Port:
    """A pyserial URL (socket://, rfc2217://, loop://, ...)."""
    try:
        ser = serial.serial_for_url(url, baudrate=baud, timeout=timeout, exclusive=True)
    except ValueError as exc:
        raise PortError(f"unknown port kind in {url!r} ({exc}): give {PORT_KINDS}", usage=True) from None
    except (serial.SerialException, OSError) as exc:
        raise PortError(f"cannot open port {url!r}: {_strip_errno(exc)}: is the server running and reachable?") \
            from None
    return Port(ser, url)


def _strip_errno(exc: Exception) -> str:
    """'could not open port X: [Errno 111] Connection refused' -> 'Connection refused'."""
    text = str(exc)
    m = re.search(r"\[Errno -?\d+\] (.*)$", text)
    return m.group(1) if m else text


def open_device(path: str, baud: int = DEFAULT_BAUD, timeout: float | None = 0.1) -> Port:
    """A serial device by path (symlinks followed), locked for this process."""
    real = os.path.realpath(path)
    try:
        st = os.stat(real)
    except FileNotFoundError:
        raise PortError(f"no such device {path}: is the board plugged in? (ls /dev/serial/by-id lists those that are)",
                        usage=True) from None
    except OSError as exc:
        raise PortError(f"cannot open port {path}: {exc.strerror}") from None
    if not stat.S_ISCHR(st.st_mode):
        kind = "a directory" if stat.S_ISDIR(st.st_mode) else "a regular file" if stat.S_ISREG(st.st_mode) else \
            "not a character device"
        raise PortError(f"{path} is not a serial device ({kind}): give the board's device, e.g. /dev/ttyUSB0",
                        usage=True)
    lock = PortLock.acquire(real, path)
    try:
        ser = serial.Serial(real, baudrate=baud, timeout=timeout, exclusive=True)
    except (serial.SerialException, OSError) as exc:
        lock.release()
        raise _device_error(path, exc) from None
    return Port(ser, path, lock=lock)


def _device_error(path: str, exc: Exception) -> PortError:
    code = getattr(exc, "errno", None)
    text = str(exc)
    if "exclusively lock" in text or code == errno.EBUSY:
        return PortError(f"port {path} is busy: another program has it open (fuser -v {path} names it)")
    if code in (errno.EACCES, errno.EPERM):
        return PortError(f"cannot open port {path}: permission denied: add yourself to its group "
                         f"(ls -l {path}; usually dialout), then log in again")
    if code == errno.ENOENT:
        return PortError(f"no such device {path}: is the board plugged in?", usage=True)
    if "configure port" in text or code in (errno.ENOTTY, errno.EINVAL):
        return PortError(f"{path} is not a serial device (it takes no serial settings): give the board's device, "
                         "e.g. /dev/ttyUSB0", usage=True)
    return PortError(f"cannot open port {path}: {_strip_errno(exc)}")

