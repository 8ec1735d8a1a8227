"""Pseudo-terminals for emulated boards.

`open_pty()` returns a raw, no-echo pty whose slave name exists on this
machine. In some sandboxes the name `os.openpty()` gives is missing from
/dev/pts; then the multiplexer /dev/pts/ptmx (or /dev/ptmx) is opened directly
and the slave is unlocked and named with the TIOCSPTLCK / TIOCGPTN ioctls.

The emulator keeps the slave fd open for the pty's whole life, so the pty never
hangs up when a host closes the port, and reads/writes the master fd
(non-blocking).
"""
from __future__ import annotations

import array
import fcntl
import os
import termios
import tty
from dataclasses import dataclass, field

# <asm-generic/ioctls.h>: _IOW('T', 0x31, int) and _IOR('T', 0x30, unsigned int)
TIOCSPTLCK = getattr(termios, "TIOCSPTLCK", 0x40045431)
TIOCGPTN = getattr(termios, "TIOCGPTN", 0x80045430)


@dataclass
class Pty:
    master: int
    slave: int
    name: str
    link: str | None = None
    _closed: bool = field(default=False, repr=False)

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


def open_pty(link: str | None = None) -> Pty:
    """Open a raw pty; optional `link`: a symlink to the slave (an existing symlink is replaced)."""
    master, slave = os.openpty()
    name = os.ttyname(slave)
    if not os.path.exists(name):
        os.close(master)
        os.close(slave)
        master, slave, name = _open_via_ptmx()
    _raw(slave)
    os.set_blocking(master, False)
    p = Pty(master, slave, name)
    if link is not None:
        if os.path.lexists(link):
            if not os.path.islink(link):
                p.close()
                raise FileExistsError(f"{link} exists and is not a symlink; refusing to replace it")
            os.unlink(link)
        os.symlink(name, link)
        p.link = link
    return p
