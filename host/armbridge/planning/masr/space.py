"""The MASR in the planning vocabulary (planning.base): its space, its checker and its goal.

    problem = env.problem()            # Problem(MasrSpace, MasrChecker, start, MasrGoal, goal_states)
    problem.space.sample(rng, 10)      # uniform in C_f, eq. (5)
    problem.space.cost(qa, qb)         # c(a), eq. (8), in s
    problem.space.interpolate(qa, qb, 16.0)   # Steer: at most 16 s of joint and MA time
    problem.checker.motion_valid(qa, qb)      # CollisionFree along the motion convention
    problem.goal.is_satisfied(q)       # the goal check over the joint margin

* MasrSpace: C_f (eq. 5: |theta_j| <= theta_b_j, 0 <= d <= l), uniform
  sampling in it (SampleFree's map of uniform numbers), eq. (8)'s action
  cost as the metric and edge cost, and the Steer of the masr paper
  (`steer="linear"`: q_a + s (q_b - q_a), s = min(1, delta / |q_b - q_a|_t))
  or the convention's own motion cut after delta s (`steer="convention"`).
* MasrChecker: a configuration is valid in C_f and clear of the obstacles
  (inflated by half the link width); a motion q_a -> q_b is valid along the
  motion convention (CollisionChecker.edge_free, q_a taken as valid, as
  OMPL's motion validators do; the convention turns the joints in an order
  that depends on the direction, so a -> b and b -> a are different checks);
  clearance (m); every answer counts in `checks`.
* MasrGoal: the goal check of eq. (9) over the joint margin (MasrArm.reaches
  in tolerance units: its score max(dp / e_p, dphi / e_phi) over every d
  within the margin, <= 1 inside; kernels.goal_score for one configuration)
  and OnGoal's rectangle width.

MASR-RRT* (rrt_star.plan) runs its loop in numba: it takes these objects'
arrays (`kernel_args`) and calls the same kernels their methods call.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik.masr_dls import span_scores
from armbridge.planning.masr.collision import CollisionChecker, arm_points, batch_hit, config_hit, edge_hit, feasible
from armbridge.planning.masr.kernels import goal_score, steer_convention, steer_linear
from armbridge.planning.polygons import points_clearance
from armbridge.robots.masr import MasrArm
from armbridge.robots.masr_kernels import action_cost

#: Steer variants (module doc); their index is the kernels' mode.
STEERS = ("linear", "convention")


@dataclass(frozen=True, eq=False)
class MasrSpace:
    """C_f of one MASR with eq. (8) as metric and cost and the paper's Steer (module doc)."""

    arm: MasrArm
    steer: str = "linear"
    lower: np.ndarray = field(init=False)
    upper: np.ndarray = field(init=False)
    theta_b: np.ndarray = field(init=False)
    rj: np.ndarray = field(init=False)
    total: float = field(init=False)
    inv_ms: float = field(init=False)
    inv_js: float = field(init=False)

    def __post_init__(self) -> None:
        if self.steer not in STEERS:
            raise ArmbridgeError(f"unknown steer {self.steer!r} (known: {', '.join(STEERS)})")
        arm = self.arm
        tb = np.ascontiguousarray(arm.theta_b, dtype=float)
        total = float(arm.total_length)
        for name, v in (("theta_b", tb), ("rj", np.ascontiguousarray(arm.r, dtype=float)), ("total", total),
                        ("lower", np.append(-tb, 0.0)), ("upper", np.append(tb, total)),
                        ("inv_ms", 1.0 / arm.ma_speed), ("inv_js", 1.0 / arm.joint_speed)):
            object.__setattr__(self, name, v)

    @property
    def dim(self) -> int:
        return self.arm.n + 1

    @property
    def steer_mode(self) -> int:
        return STEERS.index(self.steer)

    @property
    def cost_args(self) -> tuple:
        """(rj, 1 / d-dot, 1 / theta-dot): masr_kernels.action_cost's arrays."""
        return self.rj, self.inv_ms, self.inv_js

    def from_unit(self, U: np.ndarray) -> np.ndarray:
        """Map uniform numbers U (..., n+1) in [0, 1) onto C_f: theta_j = (2u - 1) theta_b_j, d = u l."""
        n = self.arm.n
        Q = np.empty_like(U, dtype=float)
        Q[..., :n] = (2.0 * U[..., :n] - 1.0) * self.theta_b
        Q[..., n] = U[..., n] * self.total
        return Q

    def sample(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """count configurations uniform in C_f (not checked against obstacles)."""
        return self.from_unit(rng.random((count, self.dim)))

    def distance(self, a: Any, b: Any) -> np.ndarray:
        """c(a -> b), eq. (8), in s: the planners' Nearest / Near metric."""
        return self.arm.action_cost(a, b)

    def cost(self, a: Any, b: Any) -> float:
        """c(a -> b), eq. (8), in s, for one pair (the kernel the planner's loop uses)."""
        return float(action_cost(np.ascontiguousarray(a, dtype=float), np.ascontiguousarray(b, dtype=float),
                                 *self.cost_args))

    def path_cost(self, path: Any) -> float:
        """tau of a path (K, n+1), eq. (7), in s (0 for a single configuration)."""
        P = np.asarray(path, dtype=float)
        return float(self.arm.path_time(P)) if P.shape[0] > 1 else 0.0

    def interpolate(self, a: Any, b: Any, step: float) -> np.ndarray:
        """Steer(a, b) with a step of at most `step` s (module doc; the space's steer variant)."""
        qa = np.ascontiguousarray(a, dtype=float)
        qb = np.ascontiguousarray(b, dtype=float)
        out = np.empty(self.dim)
        if self.steer_mode == 0:
            steer_linear(qa, qb, self.inv_ms, self.inv_js, float(step), out)
        else:
            steer_convention(qa, qb, self.rj, self.inv_ms, self.inv_js, float(step), out)
        return out

    def clip(self, q: Any) -> np.ndarray:
        """q moved into C_f (each coordinate clipped to its bounds)."""
        return np.minimum(np.maximum(np.asarray(q, dtype=float), self.lower), self.upper)


@dataclass(eq=False)
class MasrChecker:
    """base.ValidityChecker over a CollisionChecker: C_f, obstacles, CollisionFree along the convention.

    The methods call the numba kernels directly (no facade per call): OMPL
    asks them once per state and per edge from C++.
    """

    collision: CollisionChecker
    checks: int = 0
    kernel_args: tuple = field(init=False, repr=False)

    def __post_init__(self) -> None:
        c = self.collision
        #: (lengths, rj, reach, theta_b, total, verts, starts, bbox, r2, sweep_res): collision.edge_hit's arrays
        self.kernel_args = (c.lengths, c.rj, c.reach, c.theta_b, float(c.arm.total_length), c.verts, c.starts,
                            c.bbox, c.r2, c.sweep_res)
        self._pts = np.empty((c.arm.n + 1, 2))

    @property
    def arm(self) -> MasrArm:
        return self.collision.arm

    @property
    def sweep_res(self) -> float:
        return self.collision.sweep_res

    @property
    def margin(self) -> float:
        return self.collision.margin

    def _q(self, q: Any) -> np.ndarray:
        return np.ascontiguousarray(q, dtype=float).reshape(self.arm.n + 1)

    def valid_rows(self, Q: np.ndarray) -> np.ndarray:
        """(B,) bool for configurations Q (B, n+1) already in C_f: clear of every obstacle (SampleFree's test)."""
        c = self.collision
        self.checks += int(Q.shape[0])
        return batch_hit(np.ascontiguousarray(Q, dtype=float), c.lengths, c.verts, c.starts, c.bbox, c.r2) < 0

    def is_valid(self, q: Any) -> bool:
        """q in C_free: within C_f (eq. 5) and no obstacle within the margin of any link."""
        self.checks += 1
        c, qq = self.collision, self._q(q)
        return bool(feasible(qq, c.theta_b, self.kernel_args[4])) and \
            config_hit(qq, c.lengths, c.verts, c.starts, c.bbox, c.r2, self._pts) < 0

    def motion_valid(self, a: Any, b: Any) -> bool:
        """CollisionFree(a, b) along the motion convention; b must be in C_f, a is taken as valid."""
        self.checks += 1
        L, rj, reach, tb, total, V, S, B, r2, res = self.kernel_args
        return edge_hit(self._q(a), self._q(b), L, rj, reach, tb, total, V, S, B, r2, res, False) == -1

    def clearance(self, q: Any) -> float:
        """The least distance (m) from any link's surface to an obstacle (negative: penetration; inf: none)."""
        self.checks += 1
        c = self.collision
        arm_points(self._q(q), c.lengths, self._pts)
        return float(points_clearance(self._pts, c.verts, c.starts, np.empty(self.arm.n))) - c.margin

    def path_problem(self, path: Any) -> Optional[str]:
        """None if every edge of path (K, n+1) is collision-free along the convention, else a message."""
        return self.collision.path_problem(path)


@dataclass(frozen=True, eq=False)
class MasrGoal:
    """The goal region of eq. (9) over the joint margin: pose (x, y, phi), tolerances e_p (m), e_phi (rad).

    rect_width: OnGoal's rectangle width along each link (default e_p).
    """

    arm: MasrArm
    pose: np.ndarray
    e_p: float
    e_phi: float
    rect_width: Optional[float] = None

    kernel_args: tuple = field(init=False, repr=False)
    _jp: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "pose", np.ascontiguousarray(self.pose, dtype=float).reshape(3))
        w = self.e_p if self.rect_width is None else float(self.rect_width)
        if not w > 0:
            raise ArmbridgeError(f"goal rectangle width must be > 0 m, got {w}")
        object.__setattr__(self, "rect_width", w)
        arm = self.arm
        #: (lengths, rj, total, pose, half width, e_p, e_phi, d_margin): kernels.on_goal's and goal_score's arrays
        object.__setattr__(self, "kernel_args", (
            np.ascontiguousarray(arm.link_lengths, dtype=float), np.ascontiguousarray(arm.r, dtype=float),
            float(arm.total_length), self.pose, 0.5 * w, float(self.e_p), float(self.e_phi), float(arm.d_margin)))
        object.__setattr__(self, "_jp", np.empty((arm.n + 1, 2)))

    def _score1(self, q: Any) -> float:
        return float(goal_score(np.ascontiguousarray(q, dtype=float).reshape(self.arm.n + 1), self.kernel_args,
                                self._jp))

    def is_satisfied(self, q: Any) -> bool:
        """The goal check of one configuration: d holds the joint margin and eq. (9) holds for every d
        within it (MasrArm.reaches, in tolerance units: score <= 1)."""
        return self._score1(q) <= 1.0

    def score(self, q: Any) -> np.ndarray:
        """max(dp / e_p, |dphi| / e_phi) over every d within the joint margin (inf within it of a joint), (...)."""
        return span_scores(self.arm, self.pose, q, self.e_p, self.e_phi)

    def distance(self, q: Any) -> float:
        """0 inside the goal, else the score of one configuration (tolerance units: > 1)."""
        s = self._score1(q)
        return 0.0 if s <= 1.0 else s
