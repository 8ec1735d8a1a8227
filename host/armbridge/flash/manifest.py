"""The flash manifest on the board, and the host's note of a flash under way.

`armbridge.json` at the board's root says what armbridge flashed there
(docs/flash.md):

    {"format": 1, "board": "esp32", "firmware": "arm3r", "version": "0.1.0",
     "protocol": 2, "host": "armbridge 0.9.0", "state": "complete",
     "files": {"arm.mpy": "<sha256 hex>", ..., "main.py": "..."}}

A flash writes it twice: first with "state": "flashing" (before any module is
touched), last with "complete" (after every file has passed its hash), so a
board whose flash was cut short says so to the next flash. The host keeps a
note too (`Journal`: one small JSON file per port under the cache folder,
written when a flash starts, removed when it completes), which `armbridge
board` reads: a board left half-flashed is not something to talk the line
protocol to (its firmware may be part old, part new, or not run at all).
"""
from __future__ import annotations

import json
import os
import re
import time
from typing import Any

from armbridge.buildcache import cache_dir

NAME = "armbridge.json"
FORMAT = 1


def manifest(build: Any, state: str) -> dict[str, Any]:
    from armbridge import __version__

    return {"format": FORMAT, "board": build.board, "firmware": build.firmware, "version": build.version,
            "protocol": build.protocol, "host": f"armbridge {__version__}", "state": state,
            "files": build.sha256()}


def encode(m: dict[str, Any]) -> bytes:
    return (json.dumps(m, indent=1, sort_keys=True) + "\n").encode()


def parse(text: str | None) -> dict[str, Any] | None:
    """The board's manifest, or None when it has none or an unreadable one."""
    if not text:
        return None
    try:
        m = json.loads(text)
    except ValueError:
        return None
    return m if isinstance(m, dict) and isinstance(m.get("files"), dict) else None


def describe(m: dict[str, Any]) -> str:
    return f"{m.get('firmware', '?')} {m.get('version', '?')}"


class Journal:
    """The host's note of a flash under way on `port` (see the module docstring)."""

    def __init__(self, port: str) -> None:
        self.port = port
        real = os.path.realpath(port) if os.path.exists(port) else port
        key = re.sub(r"[^A-Za-z0-9._-]+", "_", real)
        self.path = cache_dir() / "flash" / (key.strip("_") + ".json")
        self.stamp = _pty_stamp(real)

    def start(self, board: str, label: str, total: int) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.write({"port": self.port, "board": board, "firmware": label, "files": total, "written": 0,
                    "started": time.strftime("%Y-%m-%d %H:%M:%S"), "pty": self.stamp})

    def progress(self, written: int) -> None:
        note = self.read()
        if note is not None:
            note["written"] = written
            self.write(note)

    def write(self, note: dict[str, Any]) -> None:
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(note))
        os.replace(tmp, self.path)

    def read(self) -> dict[str, Any] | None:
        try:
            note = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(note, dict):
            return None
        if note.get("pty") != self.stamp:   # a pty since closed: its number now names another board
            return None
        return note

    def done(self) -> None:
        self.path.unlink(missing_ok=True)

    def warning(self) -> str | None:
        """The one line `armbridge board` says about a half-flashed board, or None."""
        note = self.read()
        if note is None:
            return None
        return (f"the board on {self.port} was left half-flashed: `armbridge flash {note.get('board', '?')}` of "
                f"{note.get('firmware', '?')} stopped after {note.get('written', '?')} of {note.get('files', '?')} "
                f"files ({note.get('started', '?')}); run `armbridge flash {note.get('board', '?')} --port "
                f"{self.port}` again")


def _pty_stamp(real: str) -> int | None:
    """A pseudo-terminal's birth (its inode's ctime, ns), None for any other port. A pty
    lives as long as its emulator and its number is reused for the next one, so a note
    about /dev/pts/N holds only while the same pty is open; a real port's note holds
    across unplugging (a board left half-flashed stays so)."""
    if not real.startswith("/dev/pts/"):
        return None
    try:
        return os.stat(real).st_ctime_ns
    except OSError:
        return None


def half_flashed(port: str) -> str | None:
    """armbridge board's check: the half-flashed line for `port`, or None."""
    return Journal(port).warning()
