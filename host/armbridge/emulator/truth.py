"""Hidden physical truth: a plant's parameters drawn from documented spreads.

The nominal plant of every emulated board is exactly the model its firmware
assumes, so no controller or calibration is really tested against it. With
`emu:BOARD?plant=random&seed=N` (and `armbridge emulate BOARD --plant random
--seed N`) the board's plant is built instead from parameters drawn here: each
plant module declares its `SPREADS` (which field of its parameters varies, how
far, and the paper or data sheet that says so) and a `hidden_truth(cfg, rng)`
that returns its parameters with the drawn values in place. The host and the
firmware never read these values (they are the plant's, inside the emulator);
tests and benches may, to judge what calibration found.

Draws come from `truth_rng(seed)`, a stream of its own: the same seed gives the
same plant on every machine, and the plant's sensor noise (seeded with the same
N) is not correlated with its parameters.

A spread is one of
    normal    value = nominal + N(0, width)
    uniform   value = nominal + U(-width, width)
    scale     value = nominal * (1 + N(0, width))
clipped to [lo, hi]; a per-joint spread draws one value per joint (a tuple),
from a scalar nominal or from a tuple of one per joint.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Iterable, Literal, Sequence, TypeVar

import numpy as np

from armbridge.errors import ArmbridgeError

P = TypeVar("P")

#: what `plant=` may say
PLANTS = ("nominal", "random")
#: mixed into the seed so that the truth's stream is not the noise's
TRUTH_SALT = 0x7472757468


@dataclass(frozen=True)
class Spread:
    """How one field of a plant's parameters varies from board to board; see the module docstring.

    field: the parameters' field; kind: normal, uniform or scale; width: its
    sigma, half-width or relative sigma; per_joint: one draw per joint; lo, hi:
    bounds of the drawn value; unit: for the docs' table; source: why this
    spread (the paper's table, a data sheet, a measurement).
    """

    field: str
    kind: Literal["normal", "uniform", "scale"]
    width: float
    per_joint: bool = False
    lo: float = -np.inf
    hi: float = np.inf
    unit: str = ""
    source: str = ""

    def sample(self, nominal: Any, rng: np.random.Generator, n: int) -> Any:
        base = np.asarray(nominal, dtype=float)
        if self.per_joint:
            if not (base.ndim == 0 or base.shape == (n,)):
                raise ArmbridgeError(f"spread {self.field}: nominal {nominal!r} is not one value per joint ({n})")
            base = np.broadcast_to(base, (n,))
        size = base.shape
        if self.kind == "normal":
            x = base + rng.normal(0.0, self.width, size)
        elif self.kind == "uniform":
            x = base + rng.uniform(-self.width, self.width, size)
        elif self.kind == "scale":
            x = base * (1.0 + rng.normal(0.0, self.width, size))
        else:
            raise ArmbridgeError(f"spread {self.field}: unknown kind {self.kind!r}")
        x = np.clip(x, self.lo, self.hi)
        return tuple(float(v) for v in x) if self.per_joint else float(x)

    def describe(self) -> str:
        """The spread in words, for the docs' table ("+- 2 mm (normal sigma)")."""
        unit = f" {self.unit}" if self.unit and self.kind != "scale" else ""
        what = {"normal": f"N(0, {self.width:g}{unit})", "uniform": f"U(+-{self.width:g}{unit})",
                "scale": f"x (1 + N(0, {self.width:g}))"}[self.kind]
        return what + (" per joint" if self.per_joint else "")


def truth_rng(seed: int) -> np.random.Generator:
    """The seeded stream a board's hidden truth is drawn from (not its noise's)."""
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, TRUTH_SALT & 0xFFFFFFFF, TRUTH_SALT >> 32])


def draw(nominal: P, spreads: Iterable[Spread], rng: np.random.Generator, n: int) -> P:
    """`nominal` (a frozen dataclass) with every spread's field drawn, in the spreads' order. Pure
    but for the generator."""
    names = {f.name for f in dataclasses.fields(nominal)}  # type: ignore[arg-type]
    values: dict[str, Any] = {}
    for s in spreads:
        if s.field not in names:
            raise ArmbridgeError(f"spread {s.field}: {type(nominal).__name__} has no such field")
        values[s.field] = s.sample(getattr(nominal, s.field), rng, n)
    return dataclasses.replace(nominal, **values)  # type: ignore[type-var]


def check_plant(value: str) -> str:
    """`plant=` checked: one of PLANTS, or one ArmbridgeError naming them."""
    if value not in PLANTS:
        raise ArmbridgeError(f"plant {value!r}: expected one of {', '.join(PLANTS)}")
    return value


def table(spreads: Sequence[Spread]) -> list[str]:
    """The spreads as markdown table rows (field | spread | bounds | source), for docs/emulator.md."""
    rows = []
    for s in spreads:
        bounds = "" if (np.isinf(s.lo) and np.isinf(s.hi)) else f"[{s.lo:g}, {s.hi:g}]"
        rows.append(f"| `{s.field}` | {s.describe()} | {bounds} | {s.source} |")
    return rows
