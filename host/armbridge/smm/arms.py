"""The arms whose self-motion manifolds armbridge computes: a view of the robot registry.

Every arm has exactly one degree of redundancy (n = m + 1), so its SMMs are
1-D loops (section III-B). All are DHChain objects (armbridge.robots.dh),
which carry the SmmArm API: name, n, m, reach, fk, task, task_error,
jacobian, canonical, uncanonical, fk_error. The robots themselves (planar3r,
spatial4r, spatial7r, and why each is what it is) are defined once, in the
registry (armbridge.robots.catalog); a planar chain there (arm3r, the
bridge's arm) is seen here as its 'xy' DH chain (DHChain.from_planar), whose
joint limits SMMs ignore.
"""
from __future__ import annotations

from armbridge.errors import ArmbridgeError
from armbridge.robots import catalog
from armbridge.robots.dh import SPACES, DHChain
from armbridge.robots.planar import PlanarChain

SmmArm = DHChain

_AS_DH: dict[str, DHChain] = {}


def _smm_arm(robot: object) -> DHChain | None:
    """robot as an SMM arm, or None when it is not a revolute chain with one degree of redundancy."""
    if isinstance(robot, PlanarChain):
        arm = _AS_DH.setdefault(robot.name, DHChain.from_planar(robot))
    elif isinstance(robot, DHChain):
        arm = robot
    else:
        return None
    return arm if arm.n == SPACES[arm.space] + 1 else None


def smm_names() -> list[str]:
    """The registered robots that have SMMs."""
    return [n for n in catalog.names() if _smm_arm(catalog.get_robot(n)) is not None]


def get_smm_arm(name: str) -> DHChain:
    """The SMM arm of the registered robot called name (case-insensitive)."""
    try:
        arm = _smm_arm(catalog.get_robot(name))
    except ArmbridgeError:
        arm = None
    if arm is None:
        raise ArmbridgeError(f"unknown SMM robot {name!r}; known: {', '.join(smm_names())}")
    return arm


ARMS: dict[str, DHChain] = {n: get_smm_arm(n) for n in smm_names()}
