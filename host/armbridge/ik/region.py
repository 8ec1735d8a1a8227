"""The 3R drawing arm's safe region: one disk and one pen angle, defined here and only here.

The paper keeps the end effector inside "a circular safety zone" (section 3,
the CBF's h_0 of eq. 6) and holds the wrist still while the other joints move
(section 4.2.1). Here the pen keeps one orientation `phi` while drawing, and
the safe region is the largest disk of tip positions that the closed-form IK
reaches at that `phi` with every joint at least `JOINT_MARGIN` inside its
limits, shrunk by one grid step so the sampled boundary cannot overstate it.
`phi` is the one of `PHI_CANDIDATES` that gives the largest disk; near ties
(within a grid step) go to the phi nearest 0, which for arm3r puts the disk
in the first quadrant, where the paper draws (arm3r: centre (0.076, 0.190) m,
radius 0.1149 m, phi 0).

Everything that needs the region takes it from here: the drawing placement
(`armbridge.draw`), the CBF safety filter's safe set (`ik.cbf`), the IK
pipeline's drawing targets and the model card (`ik.arm3r_pipeline`,
`train.arm3r_ik`), the benchmark (`bench.arm3r`). The CBF's pen angle is the
drawing's: every point of the disk is reached at `phi` with the margin, so a
reference the pipeline gives there starts the CBF inside its safe set.
It sits below `draw/` and `ik/cbf.py` in the data flow (it needs only the
closed-form IK), so neither imports the other for it. So does the margin the
executed pen needs inside the disk at a pen speed (`margin_for`): the drawing
places and filters by it, and a run filters any drawing plan by it.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik.analytic3r import ik
from armbridge.robots.planar import PlanarChain

JOINT_MARGIN = np.deg2rad(5.0)  # rad: every joint keeps this far from its limits
PHI_CANDIDATES = np.deg2rad(np.arange(-180.0, 180.0, 30.0))
GRID_STEPS = 160  # grid cells across the arm's reach (arm3r: 4.75 mm a cell)


@dataclass(frozen=True)
class SafeRegion:
    """The circular safe region of the tip: centre (m), radius (m); h_0 of eq. (6)."""

    center: tuple[float, float]
    radius: float

    def __post_init__(self) -> None:
        if not self.radius > 0:
            raise ArmbridgeError(f"the safe region needs a radius > 0 m, got {self.radius}")
        object.__setattr__(self, "center", (float(self.center[0]), float(self.center[1])))

    def h(self, xy: Any) -> np.ndarray:
        """h_0 = R^2 - |xy - c|^2: >= 0 inside (eq. 6), shape (...)."""
        d = np.asarray(xy, dtype=float) - np.asarray(self.center)
        return self.radius**2 - np.sum(d * d, axis=-1)

    def contains(self, xy: Any) -> np.ndarray:
        return self.h(xy) >= 0


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
def _region(robot: PlanarChain) -> tuple[SafeRegion, float]:
    """The safe disk and its pen orientation (computed once per robot: a grid and a distance transform)."""
    from scipy import ndimage  # type: ignore[import-untyped]  # scikit-image's own dependency

    robot = _check(robot)
    reach = float(np.sum(robot.link_lengths))
    h = 2 * reach / GRID_STEPS
    xs = np.linspace(-reach, reach, GRID_STEPS + 1)
    grid = np.stack(np.meshgrid(xs, xs), axis=-1)
    best: tuple[np.ndarray, float, float] | None = None
    for phi in sorted(PHI_CANDIDATES, key=abs):  # nearest 0 first: it wins near ties
        depth = ndimage.distance_transform_edt(reachable(robot, grid, float(phi))) * h
        i = np.unravel_index(int(np.argmax(depth)), depth.shape)
        radius = float(depth[i]) - h
        if best is None or radius > best[1] + h:
            best = (grid[i].copy(), radius, float(phi))
    assert best is not None
    if best[1] <= 0:
        raise ArmbridgeError(f"robot {robot.name!r} has no safe drawing region (joint limits too tight)")
    return SafeRegion((best[0][0], best[0][1]), best[1]), best[2]


def safe_region(robot: PlanarChain) -> SafeRegion:
    """The disk the arm draws in and the CBF keeps the tip in (see the module docstring)."""
    return _region(robot)[0]


def pen_angle(robot: PlanarChain) -> float:
    """The pen orientation phi (rad) the safe region holds for: the drawing IK and the CBF use it."""
    return _region(robot)[1]


# The margin --fit keeps inside the safe disk's edge, and the CBF filter keeps every streamed
# waypoint inside, by pen speed (m/s -> m; linear between rows, flat beyond the ends): the
# executed pen strays from the commanded one by servo lag and corner overshoot, the bow of a
# joint-space segment and the potentiometer noise of the measured pen. Measured on emu:esp32
# (docs/drawing.md, "The safety margin"): the largest distance by which the measured pen went
# beyond the disk's edge with the drawings fitted to the edge itself (no margin), over the
# paper's twelve samples and "HELLO WORLD". Up to 0.1 m/s: 1.28 mm on the nominal plant
# (--cartesian 1.25 mm), 2.01 mm on ten drawn ones (plant=random, seeds 2-11), and with a
# 2.5 mm margin in place a drawn plant still reached 2.38 mm (seed 3 at 0.1 m/s): 3 mm.
# Faster, the nominal plant's worst (3.51 mm at 0.15, 5.81 at 0.2, 39.7 at 0.3 m/s) and at
# least 1 mm more.
MARGIN_BY_SPEED = (
    (0.10, 0.0030),
    (0.15, 0.0045),
    (0.20, 0.0075),
    (0.30, 0.050),
)


def margin_for(speed: float) -> float:
    """The safety margin (m) for a pen speed (m/s): MARGIN_BY_SPEED, linear between its rows."""
    v, m = zip(*MARGIN_BY_SPEED)
    return float(np.interp(speed, v, m))
