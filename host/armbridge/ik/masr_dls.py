"""Damped least squares on the MA pose (masr paper, eqs. 3-4 and 9), in numba: one step, two uses.

One step kernel (`dls_step`): the Jacobian of the MA pose (x, y, phi) in
goal-tolerance units (dp / e_p, dphi / e_phi) and the damped solve
step = J^T (J J^T + lambda^2 I)^-1 e. Variables theta_1..theta_n and d; with
the MA on link j (0-based, as MasrArm.locate), dp/dtheta_k = perp(p - P_k)
and dphi/dtheta_k = 1 for k <= j, 0 beyond; dp/dd = the link's direction,
dphi/dd = 0. Its columns can be scaled (a step then is in those units) and
frozen (held at zero). The two DLS differ only in that and in what they
clip, stop at and keep:

* `free_dls`, the numeric IK (`solve`, `goal_ik`): from any start, columns
  per second of motion (theta-dot, d-dot), so its steps are short in action
  time and it tends to stay near q_c; d may cross joints (clipped to
  [0, l] only); best iterate by the error at d; stops under 0.2. Used to
  check that a goal pose is reachable, to find goal configurations, and as
  MASR-RRT*'s goal IK without an IK-NN. It does not minimise eq. (12).
* `link_dls`, the refinement (`refine`; the IK-NN's, armbridge.ik.masr_ik):
  on the MA's link only, d kept in the link's margin_range (at least
  d_margin from the joints at its ends: a joint crossing would make phi
  jump, and a real MA only knows d to d_margin), joints may be frozen (the
  sparsify step); best iterate by the span score (the goal check over
  [d - m, d + m]); stops once the error at d is CONVERGED.

`solve` / `goal_ik` run free_dls, then `refine` from its best iterate, so
every answer holds the joint margin and is scored by the goal check over it.
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np
from numba import njit, prange

from armbridge.robots.masr import ANGLE_TOL, MasrArm
from armbridge.robots.masr_kernels import action_cost, ma_pose, margin_range, span_score, wrap

E_P = 0.008  # m, eq. (9) bound of section V-A
E_PHI = math.radians(4.0)  # rad
CONVERGED = 0.01  # score at which link_dls stops early: 0.08 mm and 0.04 deg for e_p = 8 mm, e_phi = 4 deg
SNAP_MARGIN = 0.9  # a sparser answer's span score (goal check over the joint margin) stays within this
_SNAP_ROUNDS = 2
_SNAP_ITERS = 3
#: free_dls stops once its scaled error is below this (refine finishes)
FREE_STOP = 0.2
#: DLS steps of the finishing refine (on the MA's link, holding the margin) in solve / goal_ik
FINISH_ITERS = 8


# ---------------------------------------------------------------- the step
@njit(cache=True)
def solve_damped(J, lam2, e0, e1, e2):
    """(J J^T + lam2 I)^-1 e for a 3-row J, by cofactors (no allocation: the hot loop)."""
    a = b = c = d = f = g = 0.0  # the symmetric matrix [[a, b, c], [b, d, f], [c, f, g]]
    for k in range(J.shape[1]):
        a += J[0, k] * J[0, k]
        b += J[0, k] * J[1, k]
        c += J[0, k] * J[2, k]
        d += J[1, k] * J[1, k]
        f += J[1, k] * J[2, k]
        g += J[2, k] * J[2, k]
    a += lam2
    d += lam2
    g += lam2
    c00 = d * g - f * f
    c01 = c * f - b * g
    c02 = b * f - c * d
    det = a * c00 + b * c01 + c * c02
    c11 = a * g - c * c
    c12 = b * c - a * f
    c22 = a * d - b * b
    return ((c00 * e0 + c01 * e1 + c02 * e2) / det, (c01 * e0 + c11 * e1 + c12 * e2) / det,
            (c02 * e0 + c12 * e1 + c22 * e2) / det)


@njit(cache=True)
def pose_error(q, xg, lengths, rj, total, e_p, e_phi, jp):
    """(ex, ey, ephi) of the MA pose f(q) against xg in tolerance units, then (px, py, phi, link); jp as ma_pose."""
    px, py, phi, link = ma_pose(q, lengths, rj, total, jp)
    return (xg[0] - px) / e_p, (xg[1] - py) / e_p, wrap(xg[2] - phi) / e_phi, px, py, phi, link


@njit(cache=True)
def dls_step(ex, ey, ea, px, py, phi, link, jp, frozen, s_theta, s_d, lam2, e_p, e_phi, J, step):
    """One damped least-squares step (module doc) into step (n+1,), from pose_error's values.

    Columns k <= link that are not frozen move the pose; J's columns are per
    s_theta rad (joints) and s_d m (d), and the step is returned in rad and m.
    """
    n = jp.shape[0] - 1
    for k in range(n):
        on = k <= link and not frozen[k]
        J[0, k] = -(py - jp[k, 1]) / e_p * s_theta if on else 0.0
        J[1, k] = (px - jp[k, 0]) / e_p * s_theta if on else 0.0
        J[2, k] = 1.0 / e_phi * s_theta if on else 0.0
    J[0, n] = math.cos(phi) / e_p * s_d
    J[1, n] = math.sin(phi) / e_p * s_d
    J[2, n] = 0.0
    y0, y1, y2 = solve_damped(J, lam2, ex, ey, ea)
    for k in range(n + 1):
        step[k] = (J[0, k] * y0 + J[1, k] * y1 + J[2, k] * y2) * (s_theta if k < n else s_d)


# ----------------------------------------------------------- the two DLS
@njit(cache=True)
def free_dls(x_goal, q0, lengths, rj, theta_b, total, t_theta, t_d, e_p, e_phi, iters, lam, out):
    """DLS from q0 over every link (steps per second of motion); best iterate into out; returns its error."""
    n = lengths.size
    jp = np.empty((n + 1, 2))
    J = np.zeros((3, n + 1))
    step = np.empty(n + 1)
    frozen = np.zeros(n, np.bool_)
    q = q0.copy()
    best = np.inf
    for it in range(iters + 1):
        ex, ey, ea, px, py, phi, link = pose_error(q, x_goal, lengths, rj, total, e_p, e_phi, jp)
        err = math.sqrt(ex * ex + ey * ey + ea * ea)
        if err < best:
            best = err
            for j in range(n + 1):
                out[j] = q[j]
        if it == iters or err < FREE_STOP:
            break
        dls_step(ex, ey, ea, px, py, phi, link, jp, frozen, t_theta, t_d, lam * lam, e_p, e_phi, J, step)
        for k in range(n):
            q[k] = min(max(q[k] + step[k], -theta_b[k]), theta_b[k])
        q[n] = min(max(q[n] + step[n], 0.0), total)
    return best


@njit(cache=True)
def free_dls_batch(X, Q0, lengths, rj, theta_b, total, t_theta, t_d, e_p, e_phi, iters, lam):
    B = Q0.shape[0]
    out = np.empty_like(Q0)
    err = np.empty(B)
    for b in range(B):
        err[b] = free_dls(X[b], Q0[b], lengths, rj, theta_b, total, t_theta, t_d, e_p, e_phi, iters, lam, out[b])
    return out, err


@njit(cache=True)
def link_dls(xg, q0, frozen, lengths, rj, theta_b, total, e_p, e_phi, dm, iters, lam, out):
    """DLS on the MA's link (theta_k for k <= link, not frozen, and d in the link's margin_range).

    Iterates are ranked by span_score and the best goes into out; returns its
    score. Stops early once the error at d is CONVERGED.
    """
    n = lengths.size
    jp = np.empty((n + 1, 2))
    J = np.zeros((3, n + 1))
    step = np.empty(n + 1)
    q = q0.copy()
    link = ma_pose(q, lengths, rj, total, jp)[3]
    d_lo, d_hi = margin_range(link, lengths, rj, total, dm)
    q[n] = min(max(q[n], d_lo), d_hi)
    best = np.inf
    for it in range(iters + 1):
        ex, ey, ea, px, py, phi, _ = pose_error(q, xg, lengths, rj, total, e_p, e_phi, jp)
        score = span_score(xg, px, py, phi, q[n], total, dm, e_p, e_phi)
        if score < best:
            best = score
            out[:] = q
        if it == iters or max(math.hypot(ex, ey), abs(ea)) <= CONVERGED:
            break
        dls_step(ex, ey, ea, px, py, phi, link, jp, frozen, 1.0, 1.0, lam * lam, e_p, e_phi, J, step)
        for k in range(n):
            q[k] = min(max(q[k] + step[k], -theta_b[k]), theta_b[k])
        q[n] = min(max(q[n] + step[n], d_lo), d_hi)
    return best


# ------------------------------------------------------------ refinement
@njit(cache=True)
def _refine_one(xg, q_in, qc, has_qc, lengths, rj, theta_b, total, inv_ms, inv_js, e_p, e_phi, dm,
                iters, lam, neighbours, snap, out):
    n = lengths.size
    jp = np.empty((n + 1, 2))
    q = q_in.copy()
    for k in range(n):
        q[k] = min(max(q[k], -theta_b[k]), theta_b[k])
    q[n] = min(max(q[n], 0.0), total)
    frozen = np.zeros(n, np.bool_)
    s = link_dls(xg, q, frozen, lengths, rj, theta_b, total, e_p, e_phi, dm, iters, lam, out)
    cand = np.empty(n + 1)
    if neighbours and iters > 0:
        # the NN often ends at a link's end when the answer is just past it (or within dm of it)
        for side in (1, -1):
            if s <= 1.0:
                break
            j = ma_pose(out, lengths, rj, total, jp)[3]
            far = (out[n] - rj[j] > 0.5 * lengths[j]) == (side == 1)
            k = j + side
            if not far or k < 0 or k >= n:
                continue
            alt = out.copy()
            lo, hi = margin_range(k, lengths, rj, total, dm)
            alt[n] = lo if side == 1 else hi
            cs = link_dls(xg, alt, frozen, lengths, rj, theta_b, total, e_p, e_phi, dm, iters, lam, cand)
            if cs < s:
                out[:] = cand
                s = cs
    if not has_qc:
        return s
    link = ma_pose(out, lengths, rj, total, jp)[3]
    for k in range(link + 1, n):
        out[k] = qc[k]  # they do not move the MA: same pose, less action time
    if snap <= 0.0 or iters == 0:
        return s
    # Sparsify: every joint left where it is saves its turn and maybe MA travel.
    # Greedily turn joints back to q_c, smallest turn first, while the others
    # can make up (span score within snap) and c(a) drops.
    cost = action_cost(qc, out, rj, inv_ms, inv_js)
    for k in range(n):
        frozen[k] = abs(out[k] - qc[k]) <= ANGLE_TOL
    for _ in range(_SNAP_ROUNDS):
        changed = False
        for i in np.argsort(np.abs(out[:n] - qc[:n])):
            if frozen[i]:
                continue
            alt = out.copy()
            alt[i] = qc[i]
            frozen[i] = True
            cs = link_dls(xg, alt, frozen, lengths, rj, theta_b, total, e_p, e_phi, dm, min(iters, _SNAP_ITERS), lam,
                          cand)
            cc = action_cost(qc, cand, rj, inv_ms, inv_js)
            if cs <= snap and cc < cost:
                out[:] = cand
                cost = cc
                s = cs
                changed = True
            else:
                frozen[i] = False
        if not changed:
            break
    return s


@njit(cache=True)
def _refine_serial(X, Q, QC, has_qc, lengths, rj, theta_b, total, inv_ms, inv_js, e_p, e_phi, dm,
                   iters, lam, neighbours, snap):
    out = np.empty_like(Q)
    score = np.empty(Q.shape[0])
    for b in range(Q.shape[0]):
        score[b] = _refine_one(X[b], Q[b], QC[b], has_qc, lengths, rj, theta_b, total, inv_ms, inv_js, e_p, e_phi,
                               dm, iters, lam, neighbours, snap, out[b])
    return out, score


@njit(cache=True, parallel=True)
def _refine_parallel(X, Q, QC, has_qc, lengths, rj, theta_b, total, inv_ms, inv_js, e_p, e_phi, dm,
                     iters, lam, neighbours, snap):
    out = np.empty_like(Q)
    score = np.empty(Q.shape[0])
    for b in prange(Q.shape[0]):
        score[b] = _refine_one(X[b], Q[b], QC[b], has_qc, lengths, rj, theta_b, total, inv_ms, inv_js, e_p, e_phi,
                               dm, iters, lam, neighbours, snap, out[b])
    return out, score


# Below this batch size the refinement runs on the calling thread: waking the
# thread pool costs more than it saves, and far more on a busy machine (the
# planner calls it with one query per iteration).
PARALLEL_FROM = 256


def refine(arm: MasrArm, x_goal: Any, q: Any, iters: int = 8, damping: float = 0.05,
           e_p: float = E_P, e_phi: float = E_PHI, q_c: Any = None, neighbours: bool = True,
           snap_margin: float = SNAP_MARGIN, margin: Any = None, with_score: bool = False) -> Any:
    """A few damped least-squares steps on theta_1..theta_{j_d} and d (within link j_d): link_dls.

    x_goal (..., 3), q (..., n+1) -> refined q (..., n+1), within C_f and
    holding the joint margin (margin, default arm.d_margin: d at least that far
    from every joint r_2..r_n; the start's d is first moved into its link's
    margin_range). Per query the best iterate by the span score (max(dp/e_p,
    dphi/e_phi) over every d' within the margin, MasrArm.span_pose_errors) is
    kept, so the DLS never returns a worse answer than q with its d so
    moved. With `neighbours`, a query still off the goal is tried again with
    the MA moved across the nearer joint onto the adjacent link. With q_c
    given, the joints past the MA's link go back to their q_c values (they do
    not move the MA; as the paper's GoalFix, section IV-B), then, if
    snap_margin > 0, joints are turned back to q_c one at a time while the
    rest still reach the goal with a span score within snap_margin and c(a)
    (eq. 8) drops: on a MASR every joint not turned saves its rotation and
    often the MA's drive to it. Runs in numba, in parallel over large batches.
    with_score=True returns (q, span score (...)): the answer's score, <= 1
    where it passes the goal check (as span_scores, without recomputing it).
    """
    x_goal = np.asarray(x_goal, dtype=float)
    q = np.asarray(q, dtype=float)
    shape = q.shape
    n = arm.n
    dm = arm.d_margin if margin is None else float(margin)
    X = np.ascontiguousarray(np.broadcast_to(x_goal, (*shape[:-1], 3)).reshape(-1, 3))
    Q = np.ascontiguousarray(q.reshape(-1, n + 1))
    has_qc = q_c is not None
    QC = np.ascontiguousarray(np.broadcast_to(np.asarray(q_c, dtype=float), shape).reshape(-1, n + 1)) if has_qc else Q
    kernel = _refine_parallel if Q.shape[0] >= PARALLEL_FROM else _refine_serial
    out, score = kernel(X, Q, QC, has_qc, np.ascontiguousarray(arm.link_lengths, float),
                        np.ascontiguousarray(arm.r, float), np.ascontiguousarray(arm.theta_b, float),
                        float(arm.total_length), 1.0 / arm.ma_speed, 1.0 / arm.joint_speed, float(e_p),
                        float(e_phi), dm, int(iters), float(damping), bool(neighbours), float(snap_margin))
    if with_score:
        return out.reshape(shape), score.reshape(shape[:-1])
    return out.reshape(shape)


def span_scores(arm: MasrArm, x_goal: Any, q: Any, e_p: float = E_P, e_phi: float = E_PHI) -> np.ndarray:
    """max(dp / e_p, |dphi| / e_phi) over every d' within arm.d_margin of d; inf where q is within the
    margin of a joint. <= 1 is the goal check (MasrArm.reaches)."""
    dp, dphi = arm.span_pose_errors(q, x_goal)
    return np.where(arm.holds_margin(np.asarray(q)[..., -1]), np.maximum(dp / e_p, dphi / e_phi), np.inf)


# ------------------------------------------------------------ numeric IK
def _arrays(arm: MasrArm) -> tuple:
    return (np.ascontiguousarray(arm.link_lengths, float), np.ascontiguousarray(arm.r, float),
            np.ascontiguousarray(arm.theta_b, float), float(arm.total_length),
            float(arm.joint_speed), float(arm.ma_speed))


def solve(arm: MasrArm, x_goal: Any, q0: Any, *, e_p: float = E_P, e_phi: float = E_PHI,
          iters: int = 40, damping: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Batched numeric IK: x_goal (..., 3), q0 (..., n+1) -> (q (..., n+1), span score (...)).

    free_dls, then refine; q holds the joint margin; the score is
    max(dp/e_p, dphi/e_phi) over every d within the margin (span_scores),
    so score <= 1 is the goal check (MasrArm.reaches).
    """
    x_goal = np.asarray(x_goal, float)
    q0 = arm._q(q0, "q0")
    shape = np.broadcast_shapes(x_goal.shape[:-1], q0.shape[:-1])
    X = np.ascontiguousarray(np.broadcast_to(x_goal, (*shape, 3)).reshape(-1, 3))
    Q0 = np.ascontiguousarray(np.broadcast_to(q0, (*shape, arm.n + 1)).reshape(-1, arm.n + 1))
    lengths, rj, tb, total, js, ms = _arrays(arm)
    q, _ = free_dls_batch(X, Q0, lengths, rj, tb, total, js, ms, float(e_p), float(e_phi), int(iters),
                          float(damping))
    q = refine(arm, X, q, iters=FINISH_ITERS, e_p=e_p, e_phi=e_phi)
    return q.reshape(*shape, arm.n + 1), span_scores(arm, X, q, e_p, e_phi).reshape(shape)


def goal_ik(arm: MasrArm, *, e_p: float = E_P, e_phi: float = E_PHI, iters: int = 30,
            damping: float = 0.5) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """A goal_ik(x_goal (3,), q_c (n+1,)) -> q for the planner: free_dls from q_c, then refine."""
    lengths, rj, tb, total, js, ms = _arrays(arm)
    e_p, e_phi, iters, damping = float(e_p), float(e_phi), int(iters), float(damping)

    def ik(x_goal: np.ndarray, q_c: np.ndarray) -> np.ndarray:
        out = np.empty(arm.n + 1)
        x = np.ascontiguousarray(x_goal, float)
        free_dls(x, np.ascontiguousarray(q_c, float), lengths, rj, tb, total, js, ms, e_p, e_phi, iters,
                 damping, out)
        return refine(arm, x, out, iters=FINISH_ITERS, e_p=e_p, e_phi=e_phi)

    return ik
