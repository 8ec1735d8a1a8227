"""The arm's safe drawing region: one disk, defined here and only here.

The paper keeps the end effector inside "a circular safety zone" (section 3)
and holds the wrist still while the other joints move (section 4.2.1). Here
the pen keeps one orientation `phi` while drawing, and the safe region is the
largest disk of tip positions that the closed-form IK reaches at that `phi`
with every joint at least `JOINT_MARGIN` inside its limits, shrunk by one
grid step so the sampled boundary cannot overstate it. `phi` is the one of
`PHI_CANDIDATES` that gives the largest disk; near ties (within a grid step)
go to the phi nearest 0, which for arm3r puts the disk in the first
quadrant, where the paper draws.

`safe_region(robot) -> (center, radius)` is the contract the drawing
placement and the CBF safety filter (`armbridge.ik.cbf`) share: change the
region here and both follow.
"""
from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik.analytic3r import ik
from armbridge.robots.planar import PlanarChain

JOINT_MARGIN = np.deg2rad(5.0)  # rad: every joint keeps this far from its limits
PHI_CANDIDATES = np.deg2rad(np.arange(-180.0, 180.0, 30.0))
GRID_STEPS = 160  # grid cells across the arm's reach (arm3r: 4.75 mm a cell)


class Region(NamedTuple):
    """The safe disk (center (2,) m, radius m) and the pen orientation phi (rad) it holds for."""

    center: np.ndarray
    radius: float
    phi: float


def _check(robot: object) -> PlanarChain:
    if not isinstance(robot, PlanarChain) or robot.n != 3:
        name = getattr(robot, "name", robot)
        raise ArmbridgeError(f"drawing needs a planar 3-joint arm (like arm3r); robot {name!r} is not one")
    return robot


def reachable(robot: PlanarChain, xy: np.ndarray, phi: float, margin: float = JOINT_MARGIN) -> np.ndarray:
    """Mask (...) of tip positions xy (..., 2) the IK reaches at orientation phi, joints `margin` inside."""
    xy = np.asarray(xy, dtype=float)
    pose = np.concatenate([xy, np.full((*xy.shape[:-1], 1), phi)], axis=-1)
    q, ok = ik(robot, pose)
    with np.errstate(invalid="ignore"):
        inside = np.all((q >= robot.q_min + margin) & (q <= robot.q_max - margin), axis=-1)
    return ok & inside


@lru_cache(maxsize=16)
def region(robot: PlanarChain) -> Region:
    """The safe disk and its pen orientation (computed once per robot: a grid and a distance transform)."""
    from scipy import ndimage  # type: ignore[import-untyped]  # scikit-image's own dependency

    robot = _check(robot)
    reach = float(np.sum(robot.link_lengths))
    h = 2 * reach / GRID_STEPS
    xs = np.linspace(-reach, reach, GRID_STEPS + 1)
    grid = np.stack(np.meshgrid(xs, xs), axis=-1)
    best: Region | None = None
    for phi in sorted(PHI_CANDIDATES, key=abs):  # nearest 0 first: it wins near ties
        depth = ndimage.distance_transform_edt(reachable(robot, grid, float(phi))) * h
        i = np.unravel_index(int(np.argmax(depth)), depth.shape)
        radius = float(depth[i]) - h
        if best is None or radius > best.radius + h:
            best = Region(grid[i].copy(), radius, float(phi))
    assert best is not None
    if best.radius <= 0:
        raise ArmbridgeError(f"robot {robot.name!r} has no safe drawing region (joint limits too tight)")
    return best


def safe_region(robot: PlanarChain) -> tuple[np.ndarray, float]:
    """(center (2,) m, radius m) of the disk the arm draws in safely (see the module docstring)."""
    r = region(robot)
    return r.center.copy(), r.radius


def drawing_phi(robot: PlanarChain) -> float:
    """The pen orientation (rad) the safe region holds for; the drawing IK uses it at every point."""
    return region(robot).phi
