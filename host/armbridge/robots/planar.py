"""Planar serial chains of revolute joints: kinematics and joint limits.

Every method takes q of shape (n,) or (..., n) and works on the whole batch
at once; angles are relative (joint i turns link i against link i-1) and the
base sits at the origin with joint 1's zero along +x. A PlanarChain is a
`robots.base.Robot` (kind "planar"): its configuration is its n joints.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.geometry import wrap_angle

_ARRAY_FIELDS = ("link_lengths", "q_min", "q_max", "v_max")
_FIELDS = ("name", *_ARRAY_FIELDS, "joint_names")


@dataclass(frozen=True, eq=False)
class PlanarChain:
    """A planar chain: link lengths in m, joint limits in rad, speed limits in rad/s."""

    kind: ClassVar[str] = "planar"
    name: str
    link_lengths: np.ndarray
    q_min: np.ndarray
    q_max: np.ndarray
    v_max: np.ndarray
    joint_names: tuple[str, ...]

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ArmbridgeError("robot name must be a non-empty string")
        arrays = {f: _float_vector(self.name, f, getattr(self, f)) for f in _ARRAY_FIELDS}
        n = arrays["link_lengths"].size
        where = f"robot {self.name!r}"
        if n == 0:
            raise ArmbridgeError(f"{where}: link_lengths is empty")
        for field, a in arrays.items():
            if a.size != n:
                raise ArmbridgeError(f"{where}: {field} has {a.size} values, link_lengths has {n}")
        if np.any(arrays["link_lengths"] <= 0):
            raise ArmbridgeError(f"{where}: link_lengths must all be > 0 m, got {arrays['link_lengths'].tolist()}")
        bad = np.flatnonzero(arrays["q_min"] >= arrays["q_max"])
        if bad.size:
            i = int(bad[0])
            raise ArmbridgeError(
                f"{where}: joint {i} needs q_min < q_max, got [{arrays['q_min'][i]}, {arrays['q_max'][i]}] rad"
            )
        if np.any(arrays["v_max"] <= 0):
            raise ArmbridgeError(f"{where}: v_max must all be > 0 rad/s, got {arrays['v_max'].tolist()}")
        names = _names(self.joint_names)
        if names is None or len(names) != n:
            raise ArmbridgeError(f"{where}: joint_names must be {n} non-empty strings, got {self.joint_names!r}")
        if len(set(names)) != n:
            raise ArmbridgeError(f"{where}: joint_names must be unique, got {list(names)}")
        for field, a in arrays.items():
            a.setflags(write=False)  # frozen means the arrays too
            object.__setattr__(self, field, a)
        object.__setattr__(self, "joint_names", names)

    @property
    def n(self) -> int:
        """Number of joints."""
        return int(self.link_lengths.size)

    @property
    def dof(self) -> int:
        """Coordinates of q: the n joints."""
        return self.n

    @property
    def joint_units(self) -> tuple[str, ...]:
        """Every joint is in rad."""
        return ("rad",) * self.n

    @property
    def reach(self) -> float:
        """The sum of the link lengths (m)."""
        return float(np.sum(self.link_lengths))

    @property
    def draw_dim(self) -> int:
        """2: drawn in its plane."""
        return 2

    def _q(self, q: Any) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.ndim == 0 or q.shape[-1] != self.n:
            raise ArmbridgeError(f"robot {self.name!r}: q must have shape (..., {self.n}), got {q.shape}")
        return q

    def joint_points(self, q: Any) -> np.ndarray:
        """Base, every joint and the tip: shape (..., n+1, 2)."""
        theta = np.cumsum(self._q(q), axis=-1)
        steps = self.link_lengths[:, None] * np.stack([np.cos(theta), np.sin(theta)], axis=-1)
        zero = np.zeros((*theta.shape[:-1], 1, 2))
        return np.concatenate([zero, np.cumsum(steps, axis=-2)], axis=-2)

    def fk(self, q: Any) -> np.ndarray:
        """End-effector pose (x, y, phi), shape (..., 3); phi = sum(q) wrapped to [-pi, pi)."""
        q = self._q(q)
        tip = self.joint_points(q)[..., -1, :]
        return np.concatenate([tip, wrap_angle(q.sum(axis=-1))[..., None]], axis=-1)

    def ee_point(self, q: Any) -> np.ndarray:
        """The tip (x, y), shape (..., 2)."""
        return self.joint_points(q)[..., -1, :]

    def jacobian(self, q: Any) -> np.ndarray:
        """d(x, y, phi)/dq, shape (..., 3, n).

        Column j: joint j turns everything beyond it, so it moves the tip by
        the perpendicular of (tip - joint j) and phi by 1.
        """
        theta = np.cumsum(self._q(q), axis=-1)
        lc, ls = self.link_lengths * np.cos(theta), self.link_lengths * np.sin(theta)
        # Reverse cumulative sums: the tip relative to joint j.
        rx = np.flip(np.cumsum(np.flip(lc, -1), axis=-1), -1)
        ry = np.flip(np.cumsum(np.flip(ls, -1), axis=-1), -1)
        return np.stack([-ry, rx, np.ones_like(rx)], axis=-2)

    def within_limits(self, q: Any) -> np.ndarray:
        """True where every joint is inside [q_min, q_max] (bounds included), shape (...)."""
        q = self._q(q)
        return np.all((q >= self.q_min) & (q <= self.q_max), axis=-1)

    def clip(self, q: Any) -> np.ndarray:
        """q with every joint clamped into its limits."""
        return np.clip(self._q(q), self.q_min, self.q_max)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description; from_dict(to_dict()) gives an equal chain."""
        d: dict[str, Any] = {"name": self.name}
        d.update({f: getattr(self, f).tolist() for f in _ARRAY_FIELDS})
        d["joint_names"] = list(self.joint_names)
        return d

    @classmethod
    def from_dict(cls, d: Any) -> PlanarChain:
        """Build from a JSON description with exactly the keys of to_dict()."""
        return cls(**description_fields(d, _FIELDS, "robot description"))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PlanarChain) and self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(json.dumps(self.to_dict()))


def description_fields(d: Any, fields: tuple[str, ...], what: str,
                       optional: tuple[str, ...] = ()) -> dict[str, Any]:
    """The values of a JSON robot description that has exactly `fields`, and any of `optional`."""
    if not isinstance(d, dict):
        raise ArmbridgeError(f"{what} must be a JSON object, got {type(d).__name__}")
    missing = [k for k in fields if k not in d]
    unknown = sorted(set(d) - set(fields) - set(optional))
    if missing or unknown:
        problems = ([f"missing keys {missing}"] if missing else []) + ([f"unknown keys {unknown}"] if unknown else [])
        extra = f", optional {list(optional)}" if optional else ""
        raise ArmbridgeError(f"{what} {d.get('name', '?')!r}: {'; '.join(problems)} "
                             f"(expected keys {list(fields)}{extra})")
    return {k: d[k] for k in (*fields, *optional) if k in d}


def _float_vector(name: str, field: str, value: Any) -> np.ndarray:
    """A finite 1-D float copy of value, or an ArmbridgeError naming the field."""
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ArmbridgeError(f"robot {name!r}: {field} must be a list of numbers, got {value!r}") from None
    if a.ndim != 1 or not np.all(np.isfinite(a)):
        raise ArmbridgeError(f"robot {name!r}: {field} must be a flat list of finite numbers, got {value!r}")
    return a


def _names(value: Any) -> tuple[str, ...] | None:
    """value as a tuple of non-empty strings, or None if it is not one."""
    if isinstance(value, str):
        return None
    try:
        names = tuple(value)
    except TypeError:
        return None
    return names if all(isinstance(s, str) and s for s in names) else None
