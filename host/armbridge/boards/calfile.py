"""The host's calibration files: one per physical board, named by what the board says it is.

Why on the host as well as on the board: the board keeps its calibration
(CALID, firmware/common/calstore.py) so it runs calibrated without a host
file; the host keeps the same calibration, under the same id, so a run can
tell that the board in front of it is the one that was calibrated, with the
calibration it was calibrated with: a board swapped on the same port, one
whose saved calibration was erased, or one calibrated from another host
does not match, and the run refuses it with one line (executor/session.py).

A file is JSON: {"format": FORMAT, "board", "uid", "id", "fw", "fwver",
"created", "settings": [[verb, arg...], ...], "found": {...}}; it lives in
`cal_dir()/<board>-<uid>.json`. The id is a CRC of (board, uid, settings),
so the same settings on the same board give the same id, and within
protocol's CALID range (1..2**30-1).
"""
from __future__ import annotations

import json
import os
import re
import time
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from armbridge.errors import ArmbridgeError
from armbridge.jsonfile import read_json, write_json

FORMAT = "armbridge-calibration/1"
ENV_DIR = "ARMBRIDGE_CALIBRATION_DIR"
_UID = re.compile(r"^[0-9A-Za-z_.-]{1,64}$")


def cal_dir() -> Path:
    """$ARMBRIDGE_CALIBRATION_DIR, else $XDG_CONFIG_HOME/armbridge/calibration,
    else ~/.config/armbridge/calibration."""
    env = os.environ.get(ENV_DIR)
    if env:
        return Path(env)
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return Path(base) / "armbridge" / "calibration"


def cal_id(board: str, uid: str, settings: list[tuple[str, tuple[int, ...]]]) -> int:
    """The calibration's id: CRC-32 of (board, uid, settings), folded into 1..2**30-1."""
    text = json.dumps([board, uid, [[v, *map(int, a)] for v, a in settings]], separators=(",", ":"))
    return zlib.crc32(text.encode()) % (2 ** 30 - 1) + 1


@dataclass(frozen=True)
class CalFile:
    board: str
    uid: str
    id: int
    fw: str
    fwver: str
    settings: tuple[tuple[str, tuple[int, ...]], ...]
    found: dict[str, Any]
    created: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"format": FORMAT, "board": self.board, "uid": self.uid, "id": self.id, "fw": self.fw,
                "fwver": self.fwver, "created": self.created,
                "settings": [[v, *a] for v, a in self.settings], "found": self.found}


def path_for(board: str, uid: str, folder: Path | None = None) -> Path:
    if not _UID.match(uid):
        raise ArmbridgeError(f"board id {uid!r} is not a plain token (letters, digits, _ . -)")
    return (folder or cal_dir()) / f"{board}-{uid}.json"


def write(cal: CalFile, folder: Path | None = None, path: Path | None = None) -> Path:
    path = path or path_for(cal.board, cal.uid, folder)
    doc = cal.to_json()
    doc["created"] = doc["created"] or time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    write_json(path, doc, "the calibration file")
    return path


def read(path: Path) -> CalFile:
    """A calibration file, every problem one line naming the file and the field."""
    doc = read_json(path, "calibration file")
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ArmbridgeError(f"{path}: not an armbridge calibration file (format {FORMAT!r} expected)")
    try:
        settings = tuple((str(s[0]), tuple(int(x) for x in s[1:])) for s in doc["settings"])
        cal = CalFile(board=str(doc["board"]), uid=str(doc["uid"]), id=int(doc["id"]), fw=str(doc.get("fw", "")),
                      fwver=str(doc.get("fwver", "")), settings=settings, found=dict(doc.get("found", {})),
                      created=str(doc.get("created", "")))
    except KeyError as exc:
        raise ArmbridgeError(f"{path}: field {exc.args[0]!r} is missing") from None
    except (TypeError, ValueError, IndexError):
        raise ArmbridgeError(f"{path}: field 'settings' must be a list of [verb, integer...]") from None
    if cal.id != cal_id(cal.board, cal.uid, list(cal.settings)):
        raise ArmbridgeError(f"{path}: its id {cal.id} does not match its settings (edited by hand?): "
                             f"calibrate the board again")
    return cal


def find(board: str, uid: str, folder: Path | None = None) -> CalFile | None:
    """The host's calibration of board `board` with chip id `uid`, None if it has none."""
    path = path_for(board, uid, folder)
    return read(path) if path.is_file() else None
