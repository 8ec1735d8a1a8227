"""Flashing a MicroPython board (esp32, masr_ma): build, compare, copy, verify, reset, HELLO.

1. build.build: the modules compiled for the chip, main.py, the config's files.
2. The raw REPL (mpboard.MpBoard over mpremote): the board's identity (an
   ESP32 running MicroPython; the FW_NAME of the config module it holds and
   its manifest must be this board's, or it is the wrong board: --force), the
   sha256 of every file the build has, on the board.
3. The plan: the files whose hash differs, the stale ones (a `X.py` that
   would shadow a new `X.mpy`, since MicroPython imports .py first; a file an
   earlier armbridge flash put there that this firmware no longer has). A
   second run with nothing changed copies nothing. --dry-run stops here.
4. The manifest marked "flashing", each file written and its sha256 checked on
   the board, stale files removed, the manifest marked "complete" (last).
5. machine.reset(); the firmware boots and must answer HELLO with the built
   firmware's name, version and protocol (executor.session.open_session).

Entering the raw REPL stops the firmware, so every run, --dry-run too, ends
with the reset. Failures are one BoardFailure each; before step 4 the board is
reset to the firmware it had. A failure or a stop signal once step 4 began
leaves the board in its REPL (firmware stopped, outputs off) with its manifest
and the host's journal saying it is half-flashed (manifest.Journal).
"""
from __future__ import annotations

import contextlib
import hashlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from armbridge.errors import ArmbridgeError, BoardFailure
from armbridge.flash import manifest as M
from armbridge.flash.build import Build, build


@dataclass(frozen=True)
class MicroPythonTarget:
    """A MicroPython board armbridge flashes: its name in armbridge.boards (which
    holds its firmware folders), mpy-cross's -march, esptool's chip and image
    offset, and what os.uname().machine says on it."""

    board: str
    arch: str = "xtensawin"
    chip: str = "esp32"
    image_offset: int = 0x1000
    machine: str = "ESP32"
    kind: str = "micropython"


@dataclass
class Plan:
    write: list[str] = field(default_factory=list)
    remove: list[str] = field(default_factory=list)
    unchanged: list[str] = field(default_factory=list)
    manifest: bool = False          # the manifest must be (re)written

    @property
    def changes(self) -> bool:
        return bool(self.write or self.remove or self.manifest)


@dataclass
class Result:
    build: Build
    plan: Plan
    dry_run: bool
    hello: Any = None               # the BoardInfo the flashed board answered
    bytes_written: int = 0
    half_flashed_before: str | None = None   # the board's manifest said an earlier flash was cut short


def make_plan(b: Build, hashes: dict[str, str | None], names: list[str], old: dict[str, Any] | None) -> Plan:
    local = b.sha256()
    plan = Plan()
    for name in sorted(b.files):
        (plan.unchanged if hashes.get(name) == local[name] else plan.write).append(name)
    on_board = set(names)
    shadows = {n[:-4] + ".py" for n in b.compiled} & on_board
    stale = set((old or {}).get("files", {})) - set(b.files) & on_board
    plan.remove = sorted((shadows | stale) - set(b.files) - {M.NAME})
    want = M.manifest(b, "complete")
    same = old is not None and all(old.get(k) == want[k] for k in ("board", "firmware", "version", "protocol",
                                                                   "state", "files"))
    plan.manifest = bool(plan.write or plan.remove) or not same
    return plan


@contextlib.contextmanager
def board_device(port: str) -> Iterator[tuple[str, Any]]:
    """The serial device behind `port` -> (device path or URL, in-process emulator or None).
    An emu: port starts the emulator here, on its pty (emu:DEVICE?fs=DIR keeps its filesystem)."""
    from armbridge.link.transport import port_scheme

    if port_scheme(port.strip()) != "emu":
        yield port, None
        return
    from armbridge.emulator.board import EmulatedBoard
    from armbridge.emulator.url import parse_emu_url

    device, kw = parse_emu_url(port)
    emu = EmulatedBoard(device, **kw)
    try:
        emu.start()
        yield str(emu.port), emu
    finally:
        emu.stop()


def _check_identity(t: MicroPythonTarget, b: Build, info: dict[str, Any], label: str, force: bool) -> None:
    if info["implementation"] != "micropython" or t.machine not in str(info["machine"]):
        raise BoardFailure(f"the board on {label} is {info['implementation']} on {info['machine']!r}, not MicroPython "
                           f"on an {t.machine}: wrong board?")
    old = M.parse(info["manifest"])
    if force:
        return
    if old is not None and old.get("board") != t.board:
        raise BoardFailure(f"the board on {label} holds {M.describe(old)} flashed for the {old.get('board')} board, "
                           f"not {t.board}: wrong board? (--force flashes it anyway)")
    fw = info.get("firmware")
    if fw is not None and fw != b.firmware:
        raise BoardFailure(f"the board on {label} runs {fw} firmware, not {b.firmware} ({t.board}): wrong board? "
                           "(--force flashes it anyway)")


def flash_micropython(t: MicroPythonTarget, port: str, *, firmware_root: Path | None = None, dry_run: bool = False,
                      link: str | None = None, timeout: float = 10.0, force: bool = False,
                      on_plan: Callable[[Result], None] | None = None,
                      progress: Callable[[str, int, int], None] | None = None) -> Result:
    """Flash the `t` firmware (from `firmware_root`, default the shipped tree) to
    the board on `port`; HELLO over `link` (default: the same port). on_plan(result)
    is called once the plan is known; progress(name, done, total) while writing."""
    from armbridge import boards
    from armbridge.flash.mpboard import MpBoard
    from armbridge.resources import firmware_dir

    fw = boards.board(t.board).firmware
    assert isinstance(fw, boards.MicroPythonFirmware)
    root = Path(firmware_root) if firmware_root is not None else firmware_dir()
    b = build(t.board, [root / d for d in fw.dirs], fw.config_module, t.arch)
    with board_device(port) as (device, emu):
        label = port
        board = MpBoard(device, label, timeout=timeout)
        try:
            info = board.info(M.NAME)
            _check_identity(t, b, info, label, force)
            old = M.parse(info["manifest"])
            hashes = board.hashes(sorted(b.files))
            res = Result(b, make_plan(b, hashes, info["names"], old), dry_run)
            if old is not None and old.get("state") != "complete":
                res.half_flashed_before = M.describe(old)
            if on_plan is not None:
                on_plan(res)
        except BaseException:
            with contextlib.suppress(BoardFailure):
                board.reset()  # nothing was written; the raw REPL stopped the firmware: let it run again
            raise
        if not dry_run and res.plan.changes:
            # A failure from here on leaves the board in its REPL, firmware stopped
            # (outputs off), its manifest and the journal saying it is half-flashed.
            _apply(board, res, M.Journal(port) if emu is None or "fs=" in port else None, progress)
        board.reset()
        if not dry_run:
            res.hello = _hello(link or device, b, label, timeout)
    return res


def _apply(board: Any, res: Result, journal: M.Journal | None,
           progress: Callable[[str, int, int], None] | None) -> None:
    b, plan = res.build, res.plan
    local = b.sha256()
    total = len(plan.write) + len(plan.remove)
    if journal is not None:
        journal.start(b.board, f"{b.firmware} {b.version}", total)
    board.write(M.NAME, M.encode(M.manifest(b, "flashing")))
    done = 0
    for name in plan.write:
        data = b.files[name]
        board.write(name, data, None if progress is None else (lambda n, tot, _name=name: progress(_name, n, tot)))
        got = board.sha256(name)
        if got != local[name]:
            raise BoardFailure(f"{name} failed its hash on the board (sha256 {got[:12]}, expected {local[name][:12]}): "
                               f"the board is half-flashed; run armbridge flash {b.board} again")
        res.bytes_written += len(data)
        done += 1
        if journal is not None:
            journal.progress(done)
    for name in plan.remove:
        board.remove(name)
        done += 1
    text = M.encode(M.manifest(b, "complete"))
    board.write(M.NAME, text)
    if board.sha256(M.NAME) != hashlib.sha256(text).hexdigest():
        raise BoardFailure(f"{M.NAME} failed its hash on the board: the board is half-flashed; "
                           f"run armbridge flash {b.board} again")
    if journal is not None:
        journal.done()


def _hello(link: str, b: Build, label: str, timeout: float) -> Any:
    """After the reset: the firmware must answer HELLO as what was built."""
    from armbridge.executor.session import open_session

    try:
        with open_session(link, None, latched="allow", connect_timeout=max(timeout, 5.0)) as client:
            info = client.info
            assert info is not None  # connect() filled it
    except ArmbridgeError as exc:
        raise BoardFailure(f"the flashed board on {label} does not answer HELLO after its reset: {exc}") from None
    got, want = (info.fw, info.version, info.proto), (b.firmware, b.version, b.protocol)
    if got != want:
        raise BoardFailure(f"after the flash the board on {label} answers HELLO as {got[0]} {got[1]} (protocol "
                           f"{got[2]}), expected {want[0]} {want[1]} (protocol {want[2]}): wrong board on the link?")
    return info
