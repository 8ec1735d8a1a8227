"""The calibration flow every board shares, and what a board's procedure returns.

Why one flow: each board measures different things (the MA's magnets, the
pump's bend curves, the arm's loops), but what happens around the measuring is
the same and is where mistakes cost most: who the board is (IDENT), the
settings sent with the ordinary verbs, CALID (the board persists them under an
id, as Klipper's SAVE_CONFIG), and the host's calibration file with the same
id (boards/calfile.py), which a later run checks the board against.

A board's procedure is `calibrate(client, cfg, only) -> Found`: `client` a
connected BoardClient, `cfg` the board's firmware config (boards/config.py),
`only` the steps asked for (a subset of its STEPS; all when empty). It measures
and returns; it sends no settings itself unless measuring needs them (a relay
test needs the loop it tunes), so a failed procedure leaves the board's saved
calibration as it was.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any, Callable

from armbridge.errors import ArmbridgeError

#: board name -> the module of its procedure (imported when used: each pulls numpy/scipy pieces)
PROCEDURES = {
    "esp32": "armbridge.calibrate.arm3r",
    "masr_ma": "armbridge.calibrate.masr",
    "arduino_pump": "armbridge.calibrate.pump",
}


@dataclass
class Found:
    """What a procedure measured: `settings`, the verbs that set it, in order
    ((verb, args) in the protocol's integer units, e.g. ("GAIN", (1, 2000, 0, 50)));
    `values`, what it measured (JSON-able: the host file's `found` and --json);
    `lines`, one human line per finding."""

    settings: list[tuple[str, tuple[int, ...]]] = field(default_factory=list)
    values: dict[str, Any] = field(default_factory=dict)
    lines: list[str] = field(default_factory=list)

    def merge(self, other: "Found") -> "Found":
        return Found(self.settings + other.settings, {**self.values, **other.values}, self.lines + other.lines)


def procedure(board: str) -> tuple[tuple[str, ...], Callable[[Any, Any, frozenset[str]], Found]]:
    """(STEPS, calibrate) of `board`'s procedure."""
    name = PROCEDURES.get(board)
    if name is None:
        raise ArmbridgeError(f"no calibration for board {board!r}; boards: {', '.join(sorted(PROCEDURES))}")
    mod = importlib.import_module(name)
    return tuple(mod.STEPS), mod.calibrate


def check_steps(board: str, only: list[str] | tuple[str, ...] | None) -> frozenset[str]:
    steps, _ = procedure(board)
    bad = [s for s in (only or ()) if s not in steps]
    if bad:
        raise ArmbridgeError(f"calibration step {bad[0]!r} is not one of {board}'s: {', '.join(steps)}")
    return frozenset(only or ())
