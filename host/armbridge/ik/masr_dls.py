"""A numeric MASR IK: damped least squares on the MA pose, in numba.

Used to check that a goal pose is reachable, to find a goal configuration for
the baseline RRT*'s goal bias, and as the goal IK of MASR-RRT* when no IK-NN
model is at hand. It is not the paper's IK-NN (armbridge.ik.masr_ik): it
starts from q_c and takes damped steps that are short in time units (angles
divided by theta-dot, d by d-dot), so it tends to stay near q_c, but it does
not minimise eq. (12).

The answer holds the joint margin (MasrArm.d_margin) and is scored by the
goal check over it: after the free DLS below (d may cross joints), the
refinement of armbridge.ik.masr_ik (`refine`: DLS on the MA's link with d
kept in its margin_range, a retry on the neighbouring link) finishes from its
best iterate. That second DLS is the IK-NN's, reused; this one differs in
what it is for (it roams over links from any start, time-scaled steps).

Variables: theta_1..theta_n and d. With the MA on link j (0-based, as
MasrArm.locate), dp/dtheta_k = perp(p - P_k) and dphi/dtheta_k = 1 for k <= j,
0 beyond; dp/dd = the link's direction, dphi/dd = 0. The pose error is
measured in goal-tolerance units (dp / e_p, dphi / e_phi).
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np
from numba import njit

from armbridge.ik.masr_ik import refine, span_scores
from armbridge.robots.masr import MasrArm
from armbridge.robots.masr_kernels import ma_pose, wrap


@njit(cache=True)
def dls_solve(x_goal, q0, lengths, rj, theta_b, total, t_theta, t_d, e_p, e_phi, iters, lam, out):
    """Damped least squares from q0 towards x_goal; best iterate into out; returns its scaled error."""
    n = lengths.size
    jp = np.empty((n + 1, 2))
    q = q0.copy()
    J = np.zeros((3, n + 1))
    best = np.inf
    for it in range(iters + 1):
        px, py, phi, link = ma_pose(q, lengths, rj, total, jp)
        ex = (x_goal[0] - px) / e_p
        ey = (x_goal[1] - py) / e_p
        ea = wrap(x_goal[2] - phi) / e_phi
        err = math.sqrt(ex * ex + ey * ey + ea * ea)
        if err < best:
            best = err
            for j in range(n + 1):
                out[j] = q[j]
        if it == iters or err < 0.2:
            break
        # Jacobian in scaled units: columns are per second of motion
        for k in range(n):
            if k <= link:
                J[0, k] = -(py - jp[k, 1]) / e_p * t_theta
                J[1, k] = (px - jp[k, 0]) / e_p * t_theta
                J[2, k] = 1.0 / e_phi * t_theta
            else:
                J[0, k] = 0.0
                J[1, k] = 0.0
                J[2, k] = 0.0
        J[0, n] = math.cos(phi) / e_p * t_d
        J[1, n] = math.sin(phi) / e_p * t_d
        J[2, n] = 0.0
        A = J @ J.T
        for i in range(3):
            A[i, i] += lam * lam
        e = np.array([ex, ey, ea])
        y = np.linalg.solve(A, e)
        step = J.T @ y
        for k in range(n):
            q[k] = min(max(q[k] + step[k] * t_theta, -theta_b[k]), theta_b[k])
        q[n] = min(max(q[n] + step[n] * t_d, 0.0), total)
    return best


@njit(cache=True)
def dls_batch(X, Q0, lengths, rj, theta_b, total, t_theta, t_d, e_p, e_phi, iters, lam):
    B = Q0.shape[0]
    out = np.empty_like(Q0)
    err = np.empty(B)
    for b in range(B):
        err[b] = dls_solve(X[b], Q0[b], lengths, rj, theta_b, total, t_theta, t_d, e_p, e_phi, iters, lam, out[b])
    return out, err


def _arrays(arm: MasrArm):
    return (np.ascontiguousarray(arm.link_lengths, float), np.ascontiguousarray(arm.r, float),
            np.ascontiguousarray(arm.theta_b, float), float(arm.total_length),
            float(arm.joint_speed), float(arm.ma_speed))


#: DLS steps of the finishing masr_ik.refine (on the MA's link, holding the margin)
FINISH_ITERS = 8


def solve(arm: MasrArm, x_goal: Any, q0: Any, *, e_p: float = 0.008, e_phi: float = math.radians(4.0),
          iters: int = 40, damping: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Batched DLS IK: x_goal (..., 3), q0 (..., n+1) -> (q (..., n+1), span score (...)).

    q holds the joint margin; the score is max(dp/e_p, dphi/e_phi) over every
    d within the margin (masr_ik.span_scores), so score <= 1 is the goal check
    (MasrArm.reaches).
    """
    x_goal = np.asarray(x_goal, float)
    q0 = arm._q(q0, "q0")
    shape = np.broadcast_shapes(x_goal.shape[:-1], q0.shape[:-1])
    X = np.ascontiguousarray(np.broadcast_to(x_goal, (*shape, 3)).reshape(-1, 3))
    Q0 = np.ascontiguousarray(np.broadcast_to(q0, (*shape, arm.n + 1)).reshape(-1, arm.n + 1))
    lengths, rj, tb, total, js, ms = _arrays(arm)
    q, _ = dls_batch(X, Q0, lengths, rj, tb, total, js, ms, float(e_p), float(e_phi), int(iters), float(damping))
    q = refine(arm, X, q, iters=FINISH_ITERS, e_p=e_p, e_phi=e_phi)
    return q.reshape(*shape, arm.n + 1), span_scores(arm, X, q, e_p, e_phi).reshape(shape)


def goal_ik(arm: MasrArm, *, e_p: float = 0.008, e_phi: float = math.radians(4.0), iters: int = 30,
            damping: float = 0.5) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """A goal_ik(x_goal (3,), q_c (n+1,)) -> q for the planner, from q_c by DLS (holding the joint margin)."""
    lengths, rj, tb, total, js, ms = _arrays(arm)
    e_p, e_phi, iters, damping = float(e_p), float(e_phi), int(iters), float(damping)

    def ik(x_goal: np.ndarray, q_c: np.ndarray) -> np.ndarray:
        out = np.empty(arm.n + 1)
        x = np.ascontiguousarray(x_goal, float)
        dls_solve(x, np.ascontiguousarray(q_c, float), lengths, rj, tb, total, js, ms, e_p, e_phi, iters,
                  damping, out)
        return refine(arm, x, out, iters=FINISH_ITERS, e_p=e_p, e_phi=e_phi)

    return ik
