"""The robot interface every robot model implements, whatever its kinematics.

A robot is data (as in roboticstoolbox): a frozen dataclass built from a JSON
description (`to_dict` / `from_dict`), named in the registry
(robots/catalog.py). What the rest of armbridge needs from it is this:

* the plan file, the executor and the board see a configuration q of `dof`
  coordinates, each with a name, a unit ("rad" or "m"), limits
  [q_min, q_max] and a speed limit v_max (unit/s): for a chain of revolute
  joints that is its joints; for a MASR it is the n joint angles and the
  Mobile Actuator's position d along the arm (n + 1 coordinates; `n` stays
  each model's own joint count);
* the recording draws any robot as one polyline, `joint_points(q)`: base,
  every joint, the tip, in 2-D (`draw_dim` 2) or 3-D (3), and marks
  `ee_point(q)`, where the end effector is (the tip of a chain, the MA of a
  MASR);
* `fk(q)` is the tip pose in the model's own form ((x, y, phi) for the planar
  models, a 4x4 transform for a DH chain): callers that need a pose know
  which robot they hold.

Every method takes q of shape (..., dof) and works on the whole batch.
"""
from __future__ import annotations

from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

UNITS = ("rad", "m")


@runtime_checkable
class Robot(Protocol):
    """What a plan, the executor and the recording use of a robot."""

    kind: ClassVar[str]  # the registry's name for the model: "planar", "masr", "dh"

    @property
    def name(self) -> str:
        """The registry name (a file names the robot by it)."""
        ...

    @property
    def dof(self) -> int:
        """Coordinates of a configuration q (what a plan waypoint and a W line hold)."""
        ...

    @property
    def joint_names(self) -> tuple[str, ...]:
        """One unique name per coordinate of q."""
        ...

    @property
    def joint_units(self) -> tuple[str, ...]:
        """The unit of each coordinate: "rad" or "m"."""
        ...

    @property
    def q_min(self) -> np.ndarray:
        """(dof,) lower limits."""
        ...

    @property
    def q_max(self) -> np.ndarray:
        """(dof,) upper limits."""
        ...

    @property
    def v_max(self) -> np.ndarray:
        """(dof,) speed limits, unit/s."""
        ...

    @property
    def reach(self) -> float:
        """No point of the arm is farther than this from the base (m)."""
        ...

    @property
    def draw_dim(self) -> int:
        """2 (a planar arm, drawn in its plane) or 3."""
        ...

    def fk(self, q: Any) -> Any:
        """The tip pose, in the model's own form."""
        ...

    def joint_points(self, q: Any) -> np.ndarray:
        """The arm as a polyline, (..., points, draw_dim): base, every joint, the tip."""
        ...

    def ee_point(self, q: Any) -> np.ndarray:
        """Where the end effector is, (..., draw_dim)."""
        ...

    def within_limits(self, q: Any) -> np.ndarray:
        """True where every coordinate is inside [q_min, q_max] (bounds included), shape (...)."""
        ...

    def to_dict(self) -> dict[str, Any]:
        """The JSON description; `from_dict(to_dict())` gives an equal robot."""
        ...


def limits_check(robot: Robot, q: Any) -> np.ndarray:
    """within_limits for any robot whose limits are the box [q_min, q_max]."""
    q = np.asarray(q, dtype=float)
    return np.all((q >= robot.q_min) & (q <= robot.q_max), axis=-1)


def readonly(a: Any) -> np.ndarray:
    """A float copy of a that nobody can write to (a frozen robot's arrays stay frozen)."""
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a
