"""Minimally Actuated Serial Robot (MASR): kinematics, motion convention, costs.

Model of Cohen, Sintov, Zarrouk, "Motion planning for a minimally actuated
serial robot" (masr paper), sections II-III. A planar chain of n passive
worm-gear joints and one Mobile Actuator (MA) that drives along the arm and
turns the joint it stands on.

Conventions (see docs/masr.md for the reasoning):

- A configuration is q = (theta_1, ..., theta_n, d), shape (..., n+1): relative
  joint angles in rad (joint j turns link j against link j-1), then the MA
  position d in m along the arm, d in [0, l].
- The base joint sits at the origin and the arm lies along +x when all angles
  are 0 (eq. (3)-(4): link j points along the cumulative angle theta_1+..+theta_j).
- Joint j (1-based, as in the paper) sits at r_j = l_1 + ... + l_{j-1} along the
  arm, so r_1 = 0. In arrays, r[k] is joint k+1.
- Link indices returned by numeric functions (locate) are 0-based; joints in
  the public action sequence are 1-based, as in the paper.

Every numeric method takes batches (..., n+1) and broadcasts q_c against q_d,
so a planner can price one node against thousands of candidates at once.

A MasrArm is a `robots.base.Robot` (kind "masr"): its configuration has
dof = n + 1 coordinates, theta_1..theta_n (rad, limits +-theta_b, speed
joint_speed) and d (m, limits [0, l], speed ma_speed); `n` stays the paper's
joint count.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar, Union

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.geometry import wrap_angle
from armbridge.robots.base import readonly
from armbridge.robots.planar import description_fields

_ARRAY_FIELDS = ("link_lengths", "theta_b")
_SCALAR_FIELDS = ("ma_speed", "joint_speed", "link_width", "d_margin")
_OPTIONAL = ("d_margin",)  # older descriptions (model cards, plans) lack it: the default applies
_FIELDS = ("name", *_ARRAY_FIELDS, *(f for f in _SCALAR_FIELDS if f not in _OPTIONAL))

#: A joint "needs actuation" in an action when |delta theta_j| > ANGLE_TOL (rad).
ANGLE_TOL = 1e-9
#: A joint within POS_TOL (m) of the MA counts as under the MA (no travel to it);
#: d within POS_TOL outside [0, l] is clamped onto the arm by locate/fk.
POS_TOL = 1e-9
#: Default d_margin (m): the MA firmware's localisation bound (docs/masr.md, "Joint margin").
D_MARGIN = 0.005
#: Rounding slack (m) of the margin test: r_j + d_margin is not exactly d_margin from r_j in floats.
MARGIN_TOL = 1e-12

MoveStep = tuple[str, float, float]  # ("move", d_from, d_to)
RotateStep = tuple[str, int, float, float]  # ("rotate", joint (1-based), theta_from, theta_to)
Step = Union[MoveStep, RotateStep]


@dataclass(frozen=True, eq=False)
class MasrArm:
    """A MASR arm.

    name: catalog name. link_lengths: (n,) in m, all > 0. theta_b: (n,) joint
    bounds in rad, joint j stays in [-theta_b_j, theta_b_j], 0 < theta_b_j <= pi.
    ma_speed: MA speed along the arm in m/s (d-dot). joint_speed: joint rate
    in rad/s while the MA turns it (theta-dot). link_width: link width w in m,
    used to inflate obstacles by 0.5 w (paper Fig. 3a); 0 means a line arm.
    d_margin: the least distance in m between a goal's MA position and any
    joint the MA would cross (r_2..r_n): the MA firmware's localisation bound
    (docs/masr.md, "Joint margin"). IK answers and planner goals hold it, and
    their goal check holds for every d within it (`span_pose_errors`).
    """

    kind: ClassVar[str] = "masr"
    name: str
    link_lengths: np.ndarray
    theta_b: np.ndarray
    ma_speed: float
    joint_speed: float
    link_width: float
    d_margin: float = D_MARGIN

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ArmbridgeError("MASR name must be a non-empty string")
        where = f"MASR {self.name!r}"
        arrays = {f: _float_vector(where, f, getattr(self, f)) for f in _ARRAY_FIELDS}
        lengths, bounds = arrays["link_lengths"], arrays["theta_b"]
        n = lengths.size
        if n == 0:
            raise ArmbridgeError(f"{where}: link_lengths is empty; a MASR needs at least one link")
        if bounds.size != n:
            raise ArmbridgeError(f"{where}: theta_b has {bounds.size} values, link_lengths has {n}")
        if np.any(lengths <= 0):
            raise ArmbridgeError(f"{where}: link_lengths must all be > 0 m, got {lengths.tolist()}")
        if np.any(bounds <= 0) or np.any(bounds > np.pi):
            raise ArmbridgeError(
                f"{where}: theta_b must all be in (0, pi] rad (joint j moves in [-theta_b_j, theta_b_j]), "
                f"got {bounds.tolist()}"
            )
        scalars = {f: _float_scalar(where, f, getattr(self, f)) for f in _SCALAR_FIELDS}
        for f in ("ma_speed", "joint_speed"):
            if scalars[f] <= 0:
                unit = "m/s" if f == "ma_speed" else "rad/s"
                raise ArmbridgeError(f"{where}: {f} must be > 0 {unit}, got {scalars[f]}")
        if scalars["link_width"] < 0:
            raise ArmbridgeError(f"{where}: link_width must be >= 0 m, got {scalars['link_width']}")
        half = 0.5 * float(lengths.min())
        if not 0.0 <= scalars["d_margin"] < half:
            raise ArmbridgeError(
                f"{where}: d_margin must be in [0, {half:g}) m (under half the shortest link, so every link "
                f"keeps MA positions clear of its joints), got {scalars['d_margin']}"
            )
        for f, a in arrays.items():
            a.setflags(write=False)  # frozen means the arrays too
            object.__setattr__(self, f, a)
        for f, v in scalars.items():
            object.__setattr__(self, f, v)

    # ----------------------------------------------------------------- geometry
    @property
    def n(self) -> int:
        """Number of joints (= number of links)."""
        return int(self.link_lengths.size)

    @cached_property
    def total_length(self) -> float:
        """l = l_1 + ... + l_n in m: the MA moves in d in [0, l]."""
        return float(np.sum(self.link_lengths))

    @property
    def l(self) -> float:  # noqa: E743 - the paper's name
        """Alias of total_length (the paper's l)."""
        return self.total_length

    # ------------------------------------------- the robot interface (base.Robot)
    @property
    def dof(self) -> int:
        """Coordinates of q: the n joint angles and d."""
        return self.n + 1

    @property
    def joint_names(self) -> tuple[str, ...]:
        """theta_1 .. theta_n, d (the paper's names)."""
        return (*(f"theta_{j + 1}" for j in range(self.n)), "d")

    @property
    def joint_units(self) -> tuple[str, ...]:
        """rad for the joints, m for d."""
        return ("rad",) * self.n + ("m",)

    @cached_property
    def q_min(self) -> np.ndarray:
        """(n+1,) -theta_b, then 0 for d."""
        return readonly(np.r_[-self.theta_b, 0.0])

    @cached_property
    def q_max(self) -> np.ndarray:
        """(n+1,) theta_b, then l for d."""
        return readonly(np.r_[self.theta_b, self.total_length])

    @cached_property
    def v_max(self) -> np.ndarray:
        """(n+1,) joint_speed (rad/s) per joint, then ma_speed (m/s) for d."""
        return readonly(np.r_[np.full(self.n, self.joint_speed), self.ma_speed])

    @property
    def reach(self) -> float:
        """l: the arm's length (m)."""
        return self.total_length

    @property
    def draw_dim(self) -> int:
        """2: a planar arm."""
        return 2

    def ee_point(self, q: Any) -> np.ndarray:
        """The MA (the gripper), (..., 2): ma_point."""
        return self.ma_point(q)

    @cached_property
    def r(self) -> np.ndarray:
        """(n,) joint positions along the arm: r[k] = l_1 + ... + l_k is joint k+1; r[0] = 0."""
        r = np.concatenate([[0.0], np.cumsum(self.link_lengths)[:-1]])
        r.setflags(write=False)
        return r

    def _q(self, q: Any, what: str = "q") -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.ndim == 0 or q.shape[-1] != self.n + 1:
            raise ArmbridgeError(
                f"MASR {self.name!r}: {what} must have shape (..., {self.n + 1}) "
                f"= (theta_1..theta_{self.n}, d), got {q.shape}"
            )
        return q

    def _pair(self, q_c: Any, q_d: Any) -> tuple[np.ndarray, np.ndarray]:
        q_c, q_d = self._q(q_c, "q_c"), self._q(q_d, "q_d")
        try:
            return tuple(np.broadcast_arrays(q_c, q_d))  # type: ignore[return-value]
        except ValueError:
            raise ArmbridgeError(
                f"MASR {self.name!r}: q_c {q_c.shape} and q_d {q_d.shape} do not broadcast"
            ) from None

    def locate(self, d: Any) -> tuple[np.ndarray, np.ndarray]:
        """The link the MA is on and its position along it: (j_d, d_link), each shaped like d.

        j_d is the 0-based link index (the paper's j_d minus 1) and d_link the
        distance from that link's proximal joint, so d = r[j_d] + d_link.
        At a joint (d == r[k], k >= 1) the MA is on link k with d_link = 0: the
        link that joint turns. At the tip (d == l) it is on the last link with
        d_link = l_n. d within POS_TOL outside [0, l] is clamped; further out
        is an ArmbridgeError.
        """
        d = np.asarray(d, dtype=float)
        if not np.all(np.isfinite(d)):
            raise ArmbridgeError(f"MASR {self.name!r}: MA position d must be finite")
        bad = (d < -POS_TOL) | (d > self.total_length + POS_TOL)
        if np.any(bad):
            worst = d[bad].flat[0]
            raise ArmbridgeError(
                f"MASR {self.name!r}: MA position d = {worst} m is off the arm [0, {self.total_length}] m"
            )
        d = np.clip(d, 0.0, self.total_length)
        j = np.clip(np.searchsorted(self.r, d, side="right") - 1, 0, self.n - 1)
        return j, d - self.r[j]

    def joint_points(self, q: Any) -> np.ndarray:
        """The arm as a polyline, shape (..., n+1, 2): base at the origin, every joint, the tip.

        Only the angles matter; the MA position d does not change the arm's shape.
        """
        q = self._q(q)
        theta = np.cumsum(q[..., :-1], axis=-1)
        steps = self.link_lengths[:, None] * np.stack([np.cos(theta), np.sin(theta)], axis=-1)
        zero = np.zeros((*theta.shape[:-1], 1, 2))
        return np.concatenate([zero, np.cumsum(steps, axis=-2)], axis=-2)

    def _ma(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """MA point (..., 2) and unwrapped heading (...)."""
        j, d_link = self.locate(q[..., -1])
        theta = np.cumsum(q[..., :-1], axis=-1)
        phi = np.take_along_axis(theta, j[..., None], axis=-1)[..., 0]
        base = np.take_along_axis(self.joint_points(q), j[..., None, None], axis=-2)[..., 0, :]
        return base + d_link[..., None] * np.stack([np.cos(phi), np.sin(phi)], axis=-1), phi

    def ma_point(self, q: Any) -> np.ndarray:
        """MA (gripper) position (x, y), shape (..., 2): eq. (3)-(4)."""
        return self._ma(self._q(q))[0]

    def fk(self, q: Any) -> np.ndarray:
        """MA pose (x, y, phi), shape (..., 3): eq. (2)-(4).

        phi = theta_1 + ... + theta_{j_d}, the heading of the link the MA is on
        (see locate for joints and the tip), wrapped to [-pi, pi).
        """
        p, phi = self._ma(self._q(q))
        return np.concatenate([p, wrap_angle(phi)[..., None]], axis=-1)

    def within_limits(self, q: Any) -> np.ndarray:
        """True where q is in C_f, eq. (5): |theta_j| <= theta_b_j and 0 <= d <= l (bounds included)."""
        q = self._q(q)
        joints_ok = np.all(np.abs(q[..., :-1]) <= self.theta_b, axis=-1)
        d = q[..., -1]
        return joints_ok & (d >= 0.0) & (d <= self.total_length)

    # ------------------------------------------------------------ joint margin
    def joint_clearance(self, d: Any) -> np.ndarray:
        """Distance (m) from d to the nearest joint the MA crosses (r_2..r_n); inf for one link.

        The base (d = 0) and the tip (d = l) are the arm's ends, not boundaries
        between links: the heading does not jump there.
        """
        d = np.asarray(d, dtype=float)
        inner = self.r[1:]
        if inner.size == 0:
            return np.full(d.shape, np.inf)
        return np.min(np.abs(d[..., None] - inner), axis=-1)

    def holds_margin(self, d: Any, margin: Any = None) -> np.ndarray:
        """True where d is at least margin (default d_margin) from every joint r_2..r_n (to MARGIN_TOL)."""
        m = self.d_margin if margin is None else float(margin)
        return self.joint_clearance(d) >= m - MARGIN_TOL

    def margin_range(self, link: Any, margin: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi): the MA positions on `link` (0-based) that hold the margin.

        lo = r_link + m except on the first link (0), hi = r_link + l_link - m
        except on the last (l): the ends of the arm are not joints the MA crosses.
        Both move POS_TOL further in, so that [d - m, d + m] stays on the link
        in floating point too (a joint itself counts as on the next link, locate).
        """
        m = self.d_margin if margin is None else float(margin)
        k = np.asarray(link)
        lo = np.where(k > 0, self.r[k] + m + POS_TOL, 0.0)
        hi = np.where(k < self.n - 1, self.r[k] + self.link_lengths[k] - m - POS_TOL, self.total_length)
        return lo, hi

    def span_pose_errors(self, q: Any, x_goal: Any, margin: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """(dp, |dphi|) of the goal check over every d' in [d - m, d + m] (clipped to [0, l]): the worst dp, and dphi.

        The MA at d' on the link of d has the link's heading (constant along
        the link) and a point that moves linearly with d' (eq. 3-4); |p(d') -
        x_goal| is convex in d', so its maximum over the interval is at one of
        the two ends, and checking the ends is exact. This holds only while
        the interval stays on that link, i.e. where holds_margin(d, m): a
        goal check is holds_margin and these errors within (e_p, e_phi).
        m = 0 gives fk's errors at d.
        """
        q = self._q(q)
        m = self.d_margin if margin is None else float(margin)
        x_goal = np.asarray(x_goal, dtype=float)
        p, phi = self._ma(q)
        u = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
        d = np.clip(q[..., -1], 0.0, self.total_length)
        dp = np.zeros(d.shape)
        for t in (-m, m):
            shift = np.clip(d + t, 0.0, self.total_length) - d
            dp = np.maximum(dp, np.linalg.norm(p + shift[..., None] * u - x_goal[..., :2], axis=-1))
        return dp, np.abs(wrap_angle(phi - x_goal[..., 2]))

    def reaches(self, q: Any, x_goal: Any, e_p: float, e_phi: float, margin: Any = None) -> np.ndarray:
        """The goal check: q holds the margin and the MA is within (e_p, e_phi) of x_goal (eq. 9)
        for every d' within the margin of d (span_pose_errors)."""
        q = self._q(q)
        dp, dphi = self.span_pose_errors(q, x_goal, margin)
        return self.holds_margin(q[..., -1], margin) & (dp <= e_p) & (dphi <= e_phi)

    # -------------------------------------------------------- motion convention
    def actuated(self, q_c: Any, q_d: Any) -> np.ndarray:
        """(..., n) bool: the joints an action q_c -> q_d must turn, |delta theta_j| > ANGLE_TOL."""
        q_c, q_d = self._pair(q_c, q_d)
        return np.abs(q_d[..., :-1] - q_c[..., :-1]) > ANGLE_TOL

    def _stops(self, d_c: np.ndarray) -> np.ndarray:
        """(..., n) where the MA stops to turn each joint; joints within POS_TOL of d_c snap to d_c."""
        r = np.broadcast_to(self.r, (*d_c.shape, self.n))
        return np.where(np.abs(r - d_c[..., None]) <= POS_TOL, d_c[..., None], r)

    def ma_travel(self, q_c: Any, q_d: Any) -> np.ndarray:
        """D_a: the distance the MA drives (m) for the action q_c -> q_d under the motion convention.

        With lo/hi the lowest/highest stop among d_c and the actuated joints and
        d_f = d_c + delta d: for delta d > 0 the MA sweeps down to lo, up to hi,
        then to d_f; for delta d <= 0 up to hi, down to lo, then to d_f.
        """
        q_c, q_d = self._pair(q_c, q_d)
        d_c, d_f = q_c[..., -1], q_d[..., -1]
        stops = self._stops(d_c)
        act = self.actuated(q_c, q_d)
        lo = np.minimum(np.min(np.where(act, stops, np.inf), axis=-1), d_c)
        hi = np.maximum(np.max(np.where(act, stops, -np.inf), axis=-1), d_c)
        up_first = (hi - d_c) + (hi - lo) + np.abs(d_f - lo)
        down_first = (d_c - lo) + (hi - lo) + np.abs(d_f - hi)
        return np.where(d_f - d_c > 0, down_first, up_first)

    def action_sequence(self, q_c: Any, q_d: Any) -> list[Step]:
        """The steps of one action q_c -> q_d (single configurations, shape (n+1,)).

        Each step is ("move", d_from, d_to) or ("rotate", j, theta_from, theta_to)
        with j the 1-based joint number. Order (section II-C): first the joints
        under the MA (|r_j - d_c| <= POS_TOL, no travel); then, if delta d > 0,
        the actuated joints with r_j < d_c nearest first, then those with
        r_j > d_c nearest first; if delta d <= 0 the two groups swap. Last, a
        move to d_d. Zero-length moves are left out, so an empty list means
        nothing to do. The move lengths sum to ma_travel(q_c, q_d).
        """
        q_c, q_d = self._q(q_c, "q_c"), self._q(q_d, "q_d")
        if q_c.shape != (self.n + 1,) or q_d.shape != (self.n + 1,):
            raise ArmbridgeError(
                f"MASR {self.name!r}: action_sequence takes single configurations of shape "
                f"({self.n + 1},), got {q_c.shape} and {q_d.shape}"
            )
        d_c, d_f = float(q_c[-1]), float(q_d[-1])
        stops = self._stops(np.asarray(d_c))
        act = np.flatnonzero(self.actuated(q_c, q_d))
        here = [int(k) for k in act if stops[k] == d_c]
        below = sorted((int(k) for k in act if stops[k] < d_c), key=lambda k: d_c - stops[k])
        above = sorted((int(k) for k in act if stops[k] > d_c), key=lambda k: stops[k] - d_c)
        order = here + (below + above if d_f - d_c > 0 else above + below)
        steps: list[Step] = []
        d = d_c
        for k in order:
            if stops[k] != d:
                steps.append(("move", d, float(stops[k])))
                d = float(stops[k])
            steps.append(("rotate", k + 1, float(q_c[k]), float(q_d[k])))
        if d_f != d:
            steps.append(("move", d, d_f))
        return steps

    def intermediate_configs(self, q_c: Any, q_d: Any) -> np.ndarray:
        """The configuration after each step of action_sequence, shape (m, n+1) for m steps.

        The arm is static while the MA drives, so only "rotate" rows change the
        arm's shape (joint_points); "move" rows change d and so the MA pose.
        The last row is q_d exactly: joints with a sub-tolerance difference
        (not actuated) take their q_d value there. No steps -> shape (0, n+1).
        """
        q_c, q_d = self._q(q_c, "q_c"), self._q(q_d, "q_d")
        steps = self.action_sequence(q_c, q_d)
        q = q_c.astype(float)
        rows = []
        for step in steps:
            q = q.copy()
            if len(step) == 3:  # ("move", d_from, d_to)
                q[-1] = step[2]
            else:  # ("rotate", j, theta_from, theta_to)
                q[step[1] - 1] = step[3]
            rows.append(q)
        if not rows:
            return np.empty((0, self.n + 1))
        rows[-1] = np.array(q_d, dtype=float)
        return np.stack(rows)

    # -------------------------------------------------------------------- costs
    def action_cost(self, q_c: Any, q_d: Any) -> np.ndarray:
        """c(a), eq. (8), in s: D_a / ma_speed + sum_i |delta theta_i| / joint_speed.

        The paper prints 1/d and 1/theta; it means 1/d-dot and 1/theta-dot.
        """
        q_c, q_d = self._pair(q_c, q_d)
        turn = np.sum(np.abs(q_d[..., :-1] - q_c[..., :-1]), axis=-1)
        return self.ma_travel(q_c, q_d) / self.ma_speed + turn / self.joint_speed

    def path_time(self, path: Any) -> np.ndarray:
        """tau, eq. (7), in s: the sum of action_cost over consecutive configurations.

        path has shape (..., K, n+1) with K >= 1 (one configuration costs 0).
        """
        path = self._q(path, "path")
        if path.ndim < 2 or path.shape[-2] == 0:
            raise ArmbridgeError(
                f"MASR {self.name!r}: path must have shape (..., K, {self.n + 1}) with K >= 1, got {path.shape}"
            )
        return np.sum(self.action_cost(path[..., :-1, :], path[..., 1:, :]), axis=-1)

    def reg_joint(self, q_c: Any, q_d: Any) -> np.ndarray:
        """Baseline regulariser, eq. (11), in rad: sum_i |theta_c,i - theta_d,i|."""
        q_c, q_d = self._pair(q_c, q_d)
        return np.sum(np.abs(q_c[..., :-1] - q_d[..., :-1]), axis=-1)

    def reg_action(self, q_c: Any, q_d: Any) -> np.ndarray:
        """Action-time regulariser, eq. (12), in s^2.

        sum_i (|theta_c,i - theta_d,i| / joint_speed) * (|d_c - r_i| / ma_speed),
        with r_i = l_1 + ... + l_{i-1} (section II-A) and d_c the current MA
        position. Gives 12.5 tau_l tau_theta for the paper's Fig. 4c example
        (the text prints 13.5; docs/masr.md explains the difference).
        """
        q_c, q_d = self._pair(q_c, q_d)
        turn = np.abs(q_c[..., :-1] - q_d[..., :-1]) / self.joint_speed
        reach = np.abs(q_c[..., -1:] - self.r) / self.ma_speed
        return np.sum(turn * reach, axis=-1)

    # ------------------------------------------------------------ description
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description; from_dict(to_dict()) gives an equal arm."""
        d: dict[str, Any] = {"name": self.name}
        d.update({f: getattr(self, f).tolist() for f in _ARRAY_FIELDS})
        d.update({f: getattr(self, f) for f in _SCALAR_FIELDS})
        return d

    @classmethod
    def from_dict(cls, d: Any) -> MasrArm:
        """Build from a JSON description with exactly the keys of to_dict() (SI units, rad);
        d_margin may be absent (D_MARGIN then)."""
        return cls(**description_fields(d, _FIELDS, "MASR description", optional=_OPTIONAL))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, MasrArm) and self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(json.dumps(self.to_dict()))


def _float_vector(where: str, field: str, value: Any) -> np.ndarray:
    """A finite 1-D float copy of value, or an ArmbridgeError naming the field."""
    if isinstance(value, (str, bytes)):
        raise ArmbridgeError(f"{where}: {field} must be a list of numbers, got {value!r}")
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ArmbridgeError(f"{where}: {field} must be a list of numbers, got {value!r}") from None
    if a.ndim != 1 or not np.all(np.isfinite(a)):
        raise ArmbridgeError(f"{where}: {field} must be a flat list of finite numbers, got {value!r}")
    return a


def _float_scalar(where: str, field: str, value: Any) -> float:
    """value as a finite float, or an ArmbridgeError naming the field (bools and strings refused)."""
    if isinstance(value, (bool, str, bytes)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ArmbridgeError(f"{where}: {field} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ArmbridgeError(f"{where}: {field} must be finite, got {value!r}")
    return v
