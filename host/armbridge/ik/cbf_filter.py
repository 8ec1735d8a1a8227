"""The discrete-time CBF safety filter on the commands a drawing streams (issue 23).

`ik/cbf.py` is the paper's continuous CBF-QP (Murai, Vairagi, Semwal, section
3.5, eq. 5-9) on a simulated velocity-driven arm. What the board is sent are
waypoints, one after another, so the filter here is its discrete-time form
(Agrawal and Sreenath's discrete CBF, the step-wise reading of eq. 9 with the
linear class-K function gamma(h) = gamma h):

    h(p) = r^2 - |p - c|^2,      r = R - margin                       (eq. 6's h_0)
    h(p_{k+1}) >= (1 - gamma) h(p_k),    0 < gamma <= 1                (eq. 9, discrete)

p_k is the pen position of waypoint k (forward kinematics of its joints), c
and R the safe disc (`ik.region.safe_region`), and `margin` what the executed
pen may stray from the commanded one (servo lag and corner rounding, the chord
of a joint-space segment, sensor noise: `ik.region.margin_for`, measured). With
h_0 >= 0 the condition keeps every h_k >= 0 (the safe set C of eq. 6 is
forward invariant step by step), so every commanded pen position is inside the
disc of radius R - margin and the executed pen, within `margin` of it, inside R.

The filter is the discrete CBF-QP (eq. 8, H = I, in the pen's plane): each
waypoint in turn is replaced by the nearest point that satisfies the condition
against the filtered waypoint before it. The condition is |p - c| <= rho_k with
rho_k^2 = r^2 - (1 - gamma) h(p_{k-1}), a disc, so the nearest point is the
radial projection onto it. The pen orientation (phi = q1 + q2 + q3) is kept and
the joints are solved again by the closed-form IK on the waypoint's own elbow
branch; a waypoint the IK cannot reach there holds the previous (safe) one.

Properties (tests/test_draw_safety.py): a waypoint that satisfies the condition
is returned unchanged (with gamma = 1, the default: every waypoint inside the
margin, so a drawing placed inside it is streamed exactly as planned); every
output is inside the disc of radius R - margin; filtering twice is filtering
once. gamma < 1 also slows the approach to the edge (each step closes at most
the fraction gamma of h), which bends strokes inside the margin too.
Pure numpy; the drawing (`draw.build`) runs it on every plan before it is
written and streamed.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik.analytic3r import ik
from armbridge.ik.region import SafeRegion
from armbridge.robots.planar import PlanarChain

EPS = 1e-7  # m: a projected point goes this far inside its disc, so IK rounding cannot leave it


@dataclass(frozen=True)
class FilterReport:
    """What the filter did: waypoints moved (projected), of them held (IK failed: the previous
    waypoint kept), the largest move (m), and the least h of the output (>= 0: inside R - margin)."""

    moved: int
    held: int
    max_shift: float
    h_min: float
    radius: float  # r = R - margin, m

    def to_dict(self) -> dict:
        return {"moved": self.moved, "held": self.held, "max_shift_mm": round(self.max_shift * 1000, 4),
                "radius_m": self.radius}


def _check(radius: float, gamma: float) -> None:
    if not radius > 0:
        raise ArmbridgeError(f"the CBF filter needs a disc of radius > 0 m inside the margin, got {radius:g} m")
    if not 0 < gamma <= 1:
        raise ArmbridgeError(f"the discrete CBF needs 0 < gamma <= 1, got {gamma:g}")


def _project(c: np.ndarray, tip: np.ndarray, rho2: float) -> tuple[np.ndarray, bool]:
    """tip if |tip - c|^2 <= rho2, else its radial projection EPS inside that disc (the nearest point)."""
    d = tip - c
    dist2 = float(d @ d)
    if dist2 <= rho2:
        return tip, False
    return c + d * (max(np.sqrt(max(rho2, 0.0)) - EPS, 0.0) / np.sqrt(dist2)), True


def _bound2(r: float, prev_h: float | None, gamma: float) -> float:
    """rho_k^2: the condition h(p_k) >= (1 - gamma) h(p_{k-1}) as |p_k - c|^2 <= rho_k^2 (the first
    point, prev_h None: h >= 0)."""
    return r**2 if prev_h is None else r**2 - (1 - gamma) * prev_h


def filter_points(center: Any, radius: float, points: Any, gamma: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Points (k, 2) filtered in order: p'_k is p_k where h(p_k) >= (1 - gamma) h(p'_{k-1}) (h for the
    disc (center, radius); the first point needs h >= 0), else its radial projection onto the disc
    where that holds with equality (EPS inside). Returns the points and the mask of those moved."""
    _check(radius, gamma)
    c = np.asarray(center, dtype=float)
    p = np.array(points, dtype=float).reshape(-1, 2)
    moved = np.zeros(len(p), dtype=bool)
    prev_h: float | None = None
    for k in range(len(p)):
        p[k], moved[k] = _project(c, p[k], _bound2(radius, prev_h, gamma))
        prev_h = radius**2 - float(np.sum((p[k] - c) ** 2))
    return p, moved


def filter_joints(chain: PlanarChain, region: SafeRegion, q: Any, margin: float,
                  gamma: float = 1.0) -> tuple[np.ndarray, FilterReport]:
    """Joint waypoints (k, 3) of a planar 3R arm, filtered: the pen position (FK) of each
    satisfies the discrete CBF condition of the module docstring on the disc of radius
    region.radius - margin. A moved waypoint keeps its pen orientation and elbow branch
    (closed-form IK); one the IK cannot reach there, on that branch, holds the previous output."""
    q = np.array(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != 3 or chain.n != 3:
        raise ArmbridgeError(f"the CBF filter needs joint waypoints (k, 3) of a planar 3R arm, got {q.shape}")
    if margin < 0:
        raise ArmbridgeError(f"the CBF filter's margin must be >= 0 m, got {margin:g}")
    r = region.radius - margin
    _check(r, gamma)
    c = np.asarray(region.center, dtype=float)
    tips = np.asarray(chain.ee_point(q))[:, :2]
    out = q.copy()
    held = 0
    prev_h: float | None = None
    for k in range(len(q)):  # sequential: each step's condition is on the output before it
        rho2 = _bound2(r, prev_h, gamma)
        p, moved = _project(c, tips[k], rho2)
        if moved:
            sol, ok = ik(chain, np.r_[p, q[k].sum()], q[k])
            same_elbow = bool(ok) and sol[1] * q[k][1] >= 0  # a flipped elbow would sweep the pen anywhere
            if same_elbow and float(np.sum((np.asarray(chain.ee_point(sol))[:2] - c) ** 2)) <= rho2:
                out[k] = sol
            elif prev_h is not None:
                out[k], held = out[k - 1], held + 1
            else:
                raise ArmbridgeError(f"the first waypoint's pen ({tips[0][0]:.4f}, {tips[0][1]:.4f}) m is outside "
                                     f"the safe disc less its margin, and no joints at its pen angle reach inside")
        prev_h = r**2 - float(np.sum((np.asarray(chain.ee_point(out[k]))[:2] - c) ** 2))
    new = np.asarray(chain.ee_point(out))[:, :2]
    h = r**2 - np.sum((new - c) ** 2, axis=1)
    return out, FilterReport(moved=int(np.any(out != q, axis=1).sum()), held=held,
                             max_shift=float(np.linalg.norm(new - tips, axis=1).max(initial=0.0)),
                             h_min=float(h.min(initial=np.inf)), radius=r)
