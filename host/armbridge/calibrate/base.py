"""The calibration flow every board shares, and what a board's procedure returns.

Why one flow: each board measures different things (the MA's magnets, the
pump's bend curves, the arm's loops), but what happens around the measuring is
the same and is where mistakes cost most: who the board is (IDENT), the
settings sent with the ordinary verbs, CALID (the board persists them under an
id, as Klipper's SAVE_CONFIG), and the host's calibration file with the same
id (boards/calfile.py), which a later run checks the board against.

A board's procedure is `calibrate(client, cfg, only, **options) -> Found`:
`client` a connected BoardClient, `cfg` the board's firmware config
(boards/config.py), `only` the steps asked for (a subset of its STEPS; all
when empty), `options` its own keywords (the esp32's `jig`, a bench's tuning
`rule`). It measures and returns the settings; what it sends itself is what
measuring needs (a relay test; the default lines put back before the jig; the
pump's bend reference shifted while it strokes), in RAM, so a procedure that
fails leaves the calibration saved by CALID as it was. (The pump board keeps
BEND in EEPROM at once: one reset in the middle of its strokes, on a board
with no saved calibration, boots with the shifted reference; calibrating
again puts it right.)
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from armbridge.errors import ArmbridgeError
from armbridge.link.protodef import COMMANDS

#: s of board time the flow waits after CALID before it closes the port (an EEPROM written behind)
PERSIST_S = 1.0

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


def mean_telemetry(client: Any, seconds: float, field: str = "q") -> Any:
    """The mean of the telemetry's `field` ("q": the measured joints, "target": the set
    point) over `seconds` of the client's clock, what a procedure reads a resting
    board with; whoever listened to the telemetry before still hears it."""
    import numpy as np

    got: list[Any] = []
    prev = client.on_telemetry

    def tap(t: float, m: Any) -> None:
        got.append(np.asarray(getattr(m, field), float))
        if prev is not None:
            prev(t, m)

    client.on_telemetry = tap
    try:
        client.drain(seconds)
    finally:
        client.on_telemetry = prev
    if not got:
        raise ArmbridgeError("no telemetry from the board (its RATE is 0?)")
    return np.mean(got, axis=0)


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


@dataclass
class CalReport:
    """What `calibrate_board` did: the board, its chip id, the calibration's id, the
    host file, and everything found (this run's and, kept, earlier steps' settings)."""

    board: str
    uid: str
    id: int
    path: str
    found: Found
    settings: list[tuple[str, tuple[int, ...]]]

    def to_json(self) -> dict[str, Any]:
        return {"board": self.board, "uid": self.uid, "id": self.id, "file": self.path,
                "settings": [[v, *a] for v, a in self.settings], "found": self.found.values,
                "lines": self.found.lines}


def _key(verb: str, args: tuple[int, ...]) -> tuple:
    """Settings replace each other per verb, and per joint for a verb whose first argument is one."""
    specs = COMMANDS.get(verb, ())
    return (verb, args[0]) if specs and specs[0][0] == "joint" and args else (verb,)


def merged(old: list[tuple[str, tuple[int, ...]]], new: list[tuple[str, tuple[int, ...]]]):
    """Earlier settings (a previous calibration's) overridden by this run's, in order."""
    out = {_key(v, a): (v, a) for v, a in old}
    for v, a in new:
        out.pop(_key(v, a), None)
        out[_key(v, a)] = (v, a)
    return list(out.values())


def calibrate_board(port: str, board: str, *, only: list[str] | tuple[str, ...] | None = None,
                    cal_dir: Path | None = None, connect_timeout: float = 5.0, jig: str | None = None,
                    options: dict[str, Any] | None = None, firmware: Path | None = None) -> CalReport:
    """The whole flow (module docstring): who the board is, its procedure, the
    settings sent, CALID, IDENT read back, the host file written. Nothing is
    persisted unless every step and every setting succeeded (the settings sent
    before a failure stay in the board's RAM until its next reset). With `only`,
    the settings of the steps not run are kept from this host's earlier file,
    when the board still holds that calibration. `jig`: who places the pen on the
    printed marks of the esp32's jig step (calibrate/jig.py: "terminal", the user
    at the keys; "emu", the emulated user of an in-process emu: board); without
    one that step is skipped. `options`: keywords of the board's procedure (a bench's
    tuning rule). `firmware`: the firmware tree the board was flashed from, whose config
    the procedure reads (rig, PWM frequency, limits); default the shipped one."""
    from armbridge import boards
    from armbridge.boards import calfile
    from armbridge.executor import calcheck
    from armbridge.executor.session import open_session

    steps = check_steps(board, only)
    _, run = procedure(board)
    if jig is not None and board != "esp32":
        raise ArmbridgeError(f"--jig is for the esp32 board's jig step; the {board} board calibrates without one")
    cfg = boards.config(board, firmware)
    with open_session(port, None, latched="refuse", calibration="report", connect_timeout=connect_timeout) as client:
        info = client.info
        assert info is not None  # open_session yields a connected client
        fw = info.fw
        if boards.of_identity(fw) != board:
            raise ArmbridgeError(f"the board on {port} runs firmware {fw!r}, not the {board} board's")
        got = calcheck.ident(client)
        if got is None:
            raise ArmbridgeError(f"the {board} board on {port} runs firmware {fw} {info.version} without "
                                 f"IDENT/CALID: flash it (armbridge flash {board} --port {port}) to calibrate it")
        uid, held = got
        previous = calfile.find(board, uid, cal_dir)
        if previous is not None and previous.id != held:
            previous = None   # the board no longer holds it: start afresh
        extra: dict[str, Any] = dict(options or {})
        if jig is not None:
            from armbridge.calibrate.jig import make_jig

            try:
                extra["jig"] = make_jig(jig, client)
            except ValueError as exc:
                raise ArmbridgeError(f"--jig: {exc}") from None
        found = run(client, cfg, steps, **extra)
        for verb, args in found.settings:
            client.command(verb, *args)
        settings = merged(list(previous.settings) if previous is not None else [], found.settings)
        cid = calfile.cal_id(board, uid, settings)
        client.command("CALID", cid)
        back = calcheck.ident(client)
        if back != (uid, cid):
            raise ArmbridgeError(f"the board did not keep the calibration: IDENT says {back}, expected ({uid}, {cid})")
        # The pump board programs its EEPROM behind its main loop (3.4 ms a byte, about 0.5 s for the
        # record), and a Mega resets when its port is opened again: give it the time before closing.
        client.drain(PERSIST_S)
        version = info.version
    values = {**(previous.found if previous is not None else {}), **found.values}
    cal = calfile.CalFile(board=board, uid=uid, id=cid, fw=fw, fwver=version, settings=tuple(settings),
                          found=values)
    path = calfile.write(cal, cal_dir)
    return CalReport(board, uid, cid, str(path), found, settings)
