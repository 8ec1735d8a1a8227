"""Is this the board that was calibrated, with that calibration? (issue 23 §2)

After HELLO a run asks the board IDENT (its chip id and the id of the
calibration it holds, firmware/common/calstore.py) and looks for the host's
calibration file of that board (boards/calfile.py). The decision:

| host file for (board, uid) | board's cal | result |
|---|---|---|
| none                       | 0           | "uncalibrated": runs (the firmware's defaults) |
| none                       | id          | "calibrated elsewhere": runs (the board carries it) |
| id                         | same id     | "calibrated": runs |
| id                         | other / 0   | refused, one line: its calibration erased, or made elsewhere since |
| (board answers IDENT VERB) |             | "unknown": firmware before calibration; runs |

`policy` "check" refuses a mismatch (a run); "report" returns it as status
"mismatch" (`board info`); "ignore" asks nothing (`--no-calibration-check`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from armbridge.boards import calfile, of_identity
from armbridge.errors import ArmbridgeError
from armbridge.link import protocol as P

CAL_POLICIES = ("check", "report", "ignore")


class CalibrationMismatch(ArmbridgeError):
    """The board is not the one this host calibrated, or no longer holds that
    calibration: the run is refused before anything moves (exit 2, one line)."""


@dataclass(frozen=True)
class Calibration:
    """What a run knows of the board's calibration (the summary's `calibration`)."""

    status: str           # calibrated | uncalibrated | calibrated elsewhere | mismatch | unknown | not checked
    uid: str | None = None
    board_id: int | None = None
    file: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {"status": self.status, "uid": self.uid, "id": self.board_id, "file": self.file}


def ident(client: Any) -> tuple[str, int] | None:
    """(uid, cal id) from IDENT; None from firmware without it (ER VERB)."""
    ans = client.ask("IDENT")
    if isinstance(ans, P.Er):
        if ans.code == P.VERB:
            return None
        raise ArmbridgeError(f"the board refused IDENT: {ans.code} {ans.name}")
    try:
        return str(ans.payload[0]), int(ans.payload[1])
    except (IndexError, ValueError):
        raise ArmbridgeError(f"the board's IDENT reply is malformed: {' '.join(ans.payload)}") from None


def check(client: Any, policy: str = "check", folder: Path | None = None) -> Calibration:
    """The decision table above; ArmbridgeError (one line) on a mismatch."""
    if policy not in CAL_POLICIES:
        raise ArmbridgeError(f"calibration policy {policy!r}: expected one of {', '.join(CAL_POLICIES)}")
    if policy == "ignore":
        return Calibration("not checked")
    got = ident(client)
    if got is None:
        return Calibration("unknown")
    uid, held = got
    board = of_identity(client.info.fw) or client.info.fw
    path = calfile.path_for(board, uid, folder)
    host = calfile.find(board, uid, folder)
    if host is None:
        return Calibration("calibrated elsewhere" if held else "uncalibrated", uid, held)
    if host.id != held and policy == "report":
        return Calibration("mismatch", uid, held, str(path))
    if host.id != held:
        what = f"calibration {held}" if held else "no calibration"
        raise CalibrationMismatch(f"the {board} board {uid} holds {what}, but this host calibrated it as {host.id} "
                             f"({path}): erased, or calibrated elsewhere since? Run `armbridge calibrate {board} "
                             f"--port PORT` again, or pass --no-calibration-check")
    return Calibration("calibrated", uid, held, str(path))
