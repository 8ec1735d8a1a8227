"""MASR kinematics and action cost as numba kernels on plain arrays.

The inner loops of the planners and of the IK refinement run per configuration
in numba; these kernels are their shared pieces. MasrArm (robots/masr.py) is
the reference they are tested against. Arrays: lengths (n,) link lengths,
rj (n,) joint positions along the arm (MasrArm.r), q (n+1,) = (theta, d).
"""
from __future__ import annotations

import math

from numba import njit

from armbridge.geometry import wrap_angle_scalar
from armbridge.robots.masr import ANGLE_TOL, POS_TOL

#: geometry.wrap_angle's formula compiled for the kernels: a wrapped to [-pi, pi).
wrap = njit(cache=True)(wrap_angle_scalar)


@njit(cache=True)
def ma_pose(q, lengths, rj, total, jp):
    """MA point, heading (unwrapped), link index (0-based, as MasrArm.locate).

    jp (n+1, 2) receives the base, every joint and the tip.
    """
    n = lengths.size
    d = min(max(q[n], 0.0), total)
    link = n - 1
    for k in range(1, n):
        if d < rj[k]:
            link = k - 1
            break
    th = 0.0
    x = 0.0
    y = 0.0
    jp[0, 0] = 0.0
    jp[0, 1] = 0.0
    phi = 0.0
    for k in range(n):
        th += q[k]
        if k == link:
            phi = th
        x += lengths[k] * math.cos(th)
        y += lengths[k] * math.sin(th)
        jp[k + 1, 0] = x
        jp[k + 1, 1] = y
    dl = d - rj[link]
    px = jp[link, 0] + dl * math.cos(phi)
    py = jp[link, 1] + dl * math.sin(phi)
    return px, py, phi, link


@njit(cache=True)
def action_cost(qc, qd, rj, inv_ms, inv_js):
    """c(a), eq. (8), for one pair: MasrArm.action_cost in numba."""
    n = rj.size
    dc = qc[n]
    df = qd[n]
    lo = dc
    hi = dc
    turn = 0.0
    for j in range(n):
        dth = abs(qd[j] - qc[j])
        turn += dth
        if dth > ANGLE_TOL:
            s = rj[j]
            if abs(s - dc) <= POS_TOL:
                s = dc
            if s < lo:
                lo = s
            if s > hi:
                hi = s
    if df - dc > 0.0:
        travel = (dc - lo) + (hi - lo) + abs(df - hi)
    else:
        travel = (hi - dc) + (hi - lo) + abs(df - lo)
    return travel * inv_ms + turn * inv_js


@njit(cache=True)
def margin_range(link, lengths, rj, total, margin):
    """MasrArm.margin_range for one link: (lo, hi) of the d on it at least margin (+ POS_TOL) from r_2..r_n."""
    n = lengths.size
    lo = rj[link] + margin + POS_TOL if link > 0 else 0.0
    hi = rj[link] + lengths[link] - margin - POS_TOL if link < n - 1 else total
    return lo, hi


@njit(cache=True)
def span_score(xg, px, py, phi, d, total, margin, e_p, e_phi):
    """max(dp / e_p, |dphi| / e_phi) over d' in [d - margin, d + margin] clipped to [0, total].

    MasrArm.span_pose_errors in tolerance units: the heading is constant on a
    link and the point moves linearly, so the two ends are the worst case
    (exact while d holds the margin, which margin_range keeps). <= 1 is the goal check.
    """
    c = math.cos(phi)
    s = math.sin(phi)
    worst = abs(wrap(xg[2] - phi)) / e_phi
    for t in (max(d - margin, 0.0) - d, min(d + margin, total) - d):
        e = math.hypot(xg[0] - px - t * c, xg[1] - py - t * s) / e_p
        if e > worst:
            worst = e
    return worst
