"""What a board's latch says, in words (docs/protocol.md §3.2, §4, §9).

A board latches FAULT with a reason token (STAT's fifth field: FOLLOW:2,
STALL:LOCO, MAGNET:MISSED, ...) and says `EV FAULT c v`: the coordinate c and
a value whose meaning depends on the reason (protodef.FAULT_REASONS): a
following error in the joint's milli-unit, a motor effort in per-mille, a
magnet's number. An ESTOP over a latch keeps the first cause as its reason.
Until STAT has said the reason, only `c v` are known, and nothing is guessed
about them. Pure: tokens and numbers in, one line out.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

from armbridge.link.protodef import FAULT_REASONS

MILLI = {"rad": "mrad", "m": "mm"}


def fault_text(reason: str | None, args: Sequence[str], joint: Callable[[int], str],
               unit: Callable[[int], str]) -> str:
    """One line for a latch: `reason` the token (None: not known yet), `args` EV FAULT's
    `c v` (may be empty: a latch found by STAT after it happened), `joint(j)` names
    joint j ('joint 2 (elbow)'), `unit(j)` its SI unit ('rad' or 'm')."""
    c, v = _ints(args)
    if reason is None or reason == "-":
        if c is None:
            return "FAULT"
        return f"FAULT at {joint(c)}" + (f" (value {v})" if v is not None else "") + ": reason not known yet"
    kind, _, what = reason.partition(":")
    words, value = FAULT_REASONS.get(kind, (None, None))
    if words is None:
        return f"{reason}" + (f" ({joint(c)}, value {v})" if c is not None and v is not None else "")
    if kind == "WDOG":
        return words
    if kind == "MAGNET":
        k = v if v is not None else (int(what) if what.isdigit() else None)
        where = f"magnet {k}" if k is not None else "a magnet"
        if what == "MISSED":
            return f"{words}: {where} missed (the actuator is not where its wheel count says: slip or a lost magnet)"
        if what == "SPURIOUS":
            return f"{words}: a magnet edge where none can be (nearest {where})"
        return f"{words}: {reason}"
    target = "the locomotion motor" if what == "LOCO" else joint(int(what)) if what.isdigit() else joint(c or 0)
    j = int(what) if what.isdigit() else c
    if value == "error":
        amount = "" if v is None else f" {v} {MILLI.get(unit(j or 0), 'milli-units')}"
        return f"{target}: {words}{amount}"
    if value == "effort":
        amount = "" if v is None else f" at {abs(v) / 10:g} % effort (no encoder count)"
        return f"{target}: {words}{amount}"
    return f"{target}: {words}"


def _ints(args: Sequence[str]) -> tuple[int | None, int | None]:
    out: list[int | None] = []
    for i in range(2):
        try:
            out.append(int(args[i]))
        except (IndexError, ValueError):
            out.append(None)
    return out[0], out[1]
