"""Pseudo-terminals for emulated boards.

`open_pty()` returns a raw, no-echo pty whose slave name exists on this
machine. In some sandboxes the name `os.openpty()` gives is missing from
/dev/pts; then the multiplexer /dev/pts/ptmx (or /dev/ptmx) is opened directly
and the slave is unlocked and named with the TIOCSPTLCK / TIOCGPTN ioctls.

The emulator keeps the slave fd open for the pty's whole life, so the pty never
hangs up when a host closes the port, and reads/writes the master fd
(non-blocking).

A symlink to the pty (`open_pty(link)`, `armbridge emulate --link P`) is owned:
`P.lock` beside it holds the owner's pid under an flock for as long as the
owner lives (the kernel drops the flock when a process dies, however it dies).
A second emulator asking for P is refused with a line naming the owner; a lock
left by a dead owner is taken over (`Pty.note` says so); a pty removes only
the symlink that still points at it, and only its own lock file.
"""
from __future__ import annotations

import array
import fcntl
import os
import termios
import tty
from dataclasses import dataclass, field

from armbridge.errors import ArmbridgeError

# <asm-generic/ioctls.h>: _IOW('T', 0x31, int) and _IOR('T', 0x30, unsigned int)
TIOCSPTLCK = getattr(termios, "TIOCSPTLCK", 0x40045431)
TIOCGPTN = getattr(termios, "TIOCGPTN", 0x80045430)


@dataclass
class Pty:
    master: int
    slave: int
    name: str
    link: str | None = None
    lock_fd: int | None = None
    note: str | None = None  # e.g. that a dead owner's link was taken over
    pending: bytearray = field(default_factory=bytearray)  # bytes for the host the pty could not take yet
    dropped: int = 0         # bytes nobody read (over MAX_PENDING waiting), as on a real UART
    _closed: bool = field(default=False, repr=False)

    MAX_PENDING = 65536

    def read(self) -> bytes:
        """What the host has written, without waiting (b"" when nothing)."""
        out = b""
        while True:
            try:
                data = os.read(self.master, 4096)
            except OSError:  # nothing there (EAGAIN), or no host (EIO)
                return out
            out += data
            if len(data) < 4096:
                return out

    def flush(self) -> None:
        """Hand `pending` to the host as far as the pty takes it; beyond
        MAX_PENDING waiting, the oldest bytes fall on the floor."""
        try:
            n = os.write(self.master, bytes(self.pending))
        except (BlockingIOError, InterruptedError):
            n = 0
        except OSError:
            n = len(self.pending)
        del self.pending[:n]
        over = len(self.pending) - self.MAX_PENDING
        if over > 0:
            del self.pending[:over]
            self.dropped += over

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self.link is not None:
            try:
                if os.path.islink(self.link) and os.readlink(self.link) == self.name:
                    os.unlink(self.link)
            except OSError:
                pass
        if self.lock_fd is not None and self.link is not None:
            _release_link(self.link, self.lock_fd)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


def _raw(fd: int) -> None:
    tty.setraw(fd, termios.TCSANOW)
    attrs = termios.tcgetattr(fd)
    attrs[3] &= ~(termios.ECHO | termios.ECHONL | termios.ICANON | termios.ISIG | termios.IEXTEN)
    termios.tcsetattr(fd, termios.TCSANOW, attrs)


def _open_via_ptmx() -> tuple[int, int, str]:
    last: OSError | None = None
    for mux in ("/dev/pts/ptmx", "/dev/ptmx"):
        try:
            master = os.open(mux, os.O_RDWR | os.O_NOCTTY)
        except OSError as exc:
            last = exc
            continue
        try:
            fcntl.ioctl(master, TIOCSPTLCK, array.array("i", [0]))
            num = array.array("I", [0])
            fcntl.ioctl(master, TIOCGPTN, num)
            name = f"/dev/pts/{num[0]}"
            slave = os.open(name, os.O_RDWR | os.O_NOCTTY)
        except OSError as exc:
            os.close(master)
            last = exc
            continue
        return master, slave, name
    raise OSError(f"cannot open a pseudo-terminal: {last}")


def lock_path(link: str) -> str:
    return link + ".lock"


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
        return int(text) if text else None
    except (OSError, ValueError):
        return None


def _take_link(link: str) -> tuple[int, str | None]:
    """Own `link`: flock its lock file and write our pid -> (lock fd, note or None).

    Refuses (ArmbridgeError naming the pid) when a live process holds the lock."""
    lock = lock_path(link)
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            raise ArmbridgeError(f"link {link}: cannot create its lock file {lock}: {exc.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            owner = _read_pid(fd)
            os.close(fd)
            who = f"pid {owner}" if owner is not None else "another process"
            raise ArmbridgeError(f"link {link} is owned by a running emulator ({who}, lock {lock}); "
                                 "stop it or choose another path") from None
        try:  # the owner may have removed the file between our open and our flock
            current = os.path.samestat(os.fstat(fd), os.stat(lock))
        except OSError:
            current = False
        if current:
            break
        os.close(fd)
    old = _read_pid(fd)
    note = None
    if old is not None and old != os.getpid():
        note = f"link {link}: took it over from emulator pid {old}, which no longer holds it"
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd, note


def _release_link(link: str, fd: int) -> None:
    try:
        if os.path.samestat(os.fstat(fd), os.stat(lock_path(link))):
            os.unlink(lock_path(link))
    except OSError:
        pass
    os.close(fd)


def open_pty(link: str | None = None) -> Pty:
    """Open a raw pty; optional `link`: a symlink to the slave, owned while the
    pty is open (see the module docstring; a stale symlink is replaced)."""
    lock_fd, note = _take_link(link) if link is not None else (None, None)
    try:
        p = _open_raw()
    except BaseException:
        if lock_fd is not None and link is not None:
            _release_link(link, lock_fd)
        raise
    if link is not None:
        p.link, p.lock_fd, p.note = link, lock_fd, note
        try:
            if os.path.lexists(link):
                if not os.path.islink(link):
                    raise ArmbridgeError(f"link {link} exists and is not a symlink; refusing to replace it")
                os.unlink(link)  # a stale link: its owner is gone (we hold the lock)
            os.symlink(p.name, link)
        except OSError as exc:
            p.close()  # close() removes only a symlink to this pty
            raise ArmbridgeError(f"link {link}: {exc.strerror}") from None
        except ArmbridgeError:
            p.close()
            raise
    return p


def _open_raw() -> Pty:
    master, slave = os.openpty()
    name = os.ttyname(slave)
    if not os.path.exists(name):
        os.close(master)
        os.close(slave)
        master, slave, name = _open_via_ptmx()
    _raw(slave)
    os.set_blocking(master, False)
    return Pty(master, slave, name)
