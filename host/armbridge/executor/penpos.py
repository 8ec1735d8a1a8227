"""The pen's heights and settle time as a run's options: `--pen-up US`, `--pen-down US`,
`--pen-wait MS` of `armbridge run` and `armbridge draw --port`, sent to the board as one
PENPOS before the first waypoint (docs/drawing.md "Pen heights").

As AxiDraw's pen_pos_up / pen_pos_down and Klipper's SET_SERVO: the widths are the pen
servo's pulses (us), the wait is the board's own dwell after every pen change (ms). An
option not given keeps the firmware's default (firmware/esp32/config.py PEN_UP_US,
PEN_DOWN_US, PEN_SETTLE_MS), so one PENPOS always carries all three. A drawing plan may
carry them in its provenance (`drawing.pen_pos`, what `armbridge draw` was given); the
command line wins, option by option.
"""
from __future__ import annotations

from armbridge.errors import ArmbridgeError
from armbridge.link import protodef

#: option -> (the PENPOS argument, its range): the protocol's own ranges
NAMES = ("--pen-up", "--pen-down", "--pen-wait")
OPTIONS = dict(zip(NAMES, ("up_us", "down_us", "settle_ms")))
_RANGES = {name: (lo, hi) for name, lo, hi in protodef.COMMANDS["PENPOS"]}
_UNITS = {"up_us": "us", "down_us": "us", "settle_ms": "ms"}


def _check(name: str, value, label: str) -> int:
    lo, hi = _RANGES[name]
    if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
        raise ArmbridgeError(f"{label} {value!r}: outside {lo}..{hi} {_UNITS[name]}")
    return value


def pen_pos_options(up: int | None, down: int | None, wait: int | None,
                    names: tuple[str, str, str] = NAMES) -> dict[str, int]:
    """The pen options given (None: not given) as PENPOS's names; ArmbridgeError (one line,
    the option, as `names` spells it, and its range) for a value outside the protocol's range."""
    return {OPTIONS[opt]: _check(OPTIONS[opt], value, label)
            for opt, label, value in zip(OPTIONS, names, (up, down, wait)) if value is not None}


def check_pen_pos(given, where: str = "pen_pos") -> dict[str, int]:
    """A partial pen_pos (a plan's provenance, an API caller's) checked as the options are."""
    if not given:
        return {}
    if not isinstance(given, dict) or set(given) - set(_RANGES):
        raise ArmbridgeError(f"{where}: expected an object of up_us, down_us, settle_ms, got {given!r}")
    return {name: _check(name, value, f"{where}.{name}") for name, value in given.items()}


def board_defaults() -> dict[str, int]:
    """The ESP32 arm firmware's own pen settings (its config), for the options not given."""
    from armbridge.boards import config

    cfg = config("esp32")
    return {"up_us": int(cfg.PEN_UP_US), "down_us": int(cfg.PEN_DOWN_US), "settle_ms": int(cfg.PEN_SETTLE_MS)}


def resolve(plan_pen_pos: dict | None, cli: dict[str, int] | None) -> dict[str, int] | None:
    """What a run sends: the plan's pen settings overridden by the command line's, the
    firmware's defaults for the rest; None when neither gives any (no PENPOS is sent)."""
    given = {**check_pen_pos(plan_pen_pos, "the plan's drawing.pen_pos"), **(cli or {})}
    if not given:
        return None
    return {**board_defaults(), **given}


def send_pen_pos(client, pos: dict[str, int], required: bool = True, hint: str = "") -> bool:
    """PENPOS up down settle -> True when the board took it. A refusal is PenRefused (one line;
    nothing streamed yet), saying which of the two VERB means: a pen servo (PEN works) on a
    firmware older than PENPOS, or no pen servo at all, which is no error when not `required`
    (the plan's own settings under --pen auto: the board draws with pen-up moves marked) -> False.
    `hint`: what the user can do instead, for the message."""
    from armbridge.link import protocol as P

    ans = client.ask("PENPOS", pos["up_us"], pos["down_us"], pos["settle_ms"])
    if not isinstance(ans, P.Er):
        return True
    if ans.code != P.VERB:
        raise PenRefused(f"the board refused PENPOS {pos['up_us']} {pos['down_us']} {pos['settle_ms']}: {ans}")
    if client.can("PEN", 0):
        raise PenRefused("the board refused PENPOS (VERB): it has a pen-lift servo (PEN works) but its firmware "
                         "predates PENPOS; flash a newer one" + (f", or {hint}" if hint else ""))
    if not required:
        return False
    raise PenRefused("the board refused PENPOS (VERB): it has no pen-lift servo" + (f"; {hint}" if hint else ""))


class PenRefused(ArmbridgeError):
    """The board refused the pen settings: the run stops before any waypoint (one line, exit 2)."""
