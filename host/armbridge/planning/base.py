"""The planning vocabulary, as OMPL names it: state space, validity checker, goal, problem, planner, result.

    space   = ChainSpace(robot)                 # sample, distance, interpolate, cost
    checker = ChainChecker.create(robot, scene)   # is_valid, motion_valid, clearance
    problem = Problem(space, checker, start, goal)
    result  = wjrrt.solve(problem, iterations=2000, seed=0)

A robot brings its own space and checker (the MASR's are in
planning.masr: its C_f of eq. 5, the action cost of eq. 8 and the motion
convention's edge check; the planar chains' are in planning.chain); the
planners use only these protocols and the shared Tree (planning.tree), so a
new planner is a new steer over the same pieces, and a new robot is a new
space, not a new tree. Where OMPL itself is asked to plan
(planning.ompl_bridge) it is given the same checker and goal.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional, Protocol

import numpy as np


class StateSpace(Protocol):
    """A configuration space: bounds, uniform sampling, a metric, interpolation and an edge cost."""

    dim: int
    lower: np.ndarray
    upper: np.ndarray

    def sample(self, rng: np.random.Generator, count: int) -> np.ndarray: ...
    def distance(self, a: np.ndarray, b: np.ndarray) -> np.ndarray: ...
    def interpolate(self, a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray: ...
    def cost(self, a: np.ndarray, b: np.ndarray) -> float: ...


class ValidityChecker(Protocol):
    """State validity (limits and collisions), edge validity at a resolution, clearance; it counts its calls."""

    checks: int

    def is_valid(self, q: np.ndarray) -> bool: ...
    def motion_valid(self, a: np.ndarray, b: np.ndarray) -> bool: ...
    def clearance(self, q: np.ndarray) -> float: ...


class Goal(Protocol):
    """A goal region: is_satisfied(q) and a distance to it (0 inside)."""

    def is_satisfied(self, q: np.ndarray) -> bool: ...
    def distance(self, q: np.ndarray) -> float: ...


@dataclass
class Problem:
    """One planning query: where to start, what counts as arrived, and the space and checker to plan in.

    goal_states: configurations known to satisfy the goal (for bidirectional
    planners and OMPL's goal sampling); may be empty.
    """

    space: Any
    checker: Any
    start: np.ndarray
    goal: Any
    goal_states: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    name: str = ""


@dataclass
class PlanResult:
    """What any planner run gives back.

    path: (K, dim) configurations from the start into the goal, or None.
    stats: the planner's own counters (Table 1 columns for the soft-arm
    planners; IK calls and goal nodes for MASR-RRT*).
    """

    planner: str
    path: Optional[np.ndarray]
    iterations: int
    time_s: float
    tree_size: int
    collision_checks: int
    seed: Optional[int]
    cost: float = float("inf")
    stats: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)

    @property
    def success(self) -> bool:
        return self.path is not None

    def summary(self) -> dict[str, Any]:
        return {
            "planner": self.planner,
            "success": self.success,
            "cost": self.cost if self.success else None,
            "waypoints": 0 if self.path is None else int(self.path.shape[0]),
            "iterations": self.iterations,
            "time_s": self.time_s,
            "tree_size": self.tree_size,
            "collision_checks": self.collision_checks,
            "seed": self.seed,
            **self.stats,
            **self.settings,
        }


#: The modules whose numba kernels a robot's planners call (`compile_note`).
KERNELS: dict[str, tuple[str, ...]] = {
    "masr": ("armbridge.robots.masr_kernels", "armbridge.planning.masr.kernels", "armbridge.planning.masr.collision",
             "armbridge.planning.masr.margin", "armbridge.planning.tree", "armbridge.ik.masr_dls"),
    "soft": ("armbridge.planning.tree", "armbridge.planning.polygons", "armbridge.planning.soft.space",
             "armbridge.planning.soft.jtstep", "armbridge.planning.soft.jacobian_rrt", "armbridge.planning.soft.connect",
             "armbridge.planning.soft.ik",
             "armbridge.planning.soft.margin", "armbridge.planning.soft.waypoints"),
}


def compile_note(robot: str) -> str | None:
    """What to say before planning when the kernels of `robot`'s planners ("masr", "soft")
    are not compiled yet (buildcache.numba_cold), else None."""
    import importlib

    from armbridge.buildcache import numba_cold

    if not numba_cold(*(importlib.import_module(m) for m in KERNELS[robot])):
        return None
    return "compiling the planner's kernels (numba: once per install, up to a minute) ..."
