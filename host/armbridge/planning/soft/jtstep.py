"""The Jacobian-transpose step of a planar chain's tip (WJRRT eq. 17-19), in numba.

Split from space.py (which re-exports both); the chain's polyline is planning.polygons.chain_points.
"""
from __future__ import annotations

import math

from numba import njit

from armbridge.planning.polygons import chain_points


@njit(cache=True)
def tip_jacobian(q, lengths, base, pts, J):
    """Tip position (x, y) of q and d(tip)/dq into J (2, n): column j is perp(tip - joint j)."""
    n = lengths.size
    chain_points(q, lengths, base[0], base[1], base[2], pts)
    tx, ty = pts[n, 0], pts[n, 1]
    for j in range(n):
        J[0, j] = -(ty - pts[j, 1])
        J[1, j] = tx - pts[j, 0]
    return tx, ty


@njit(cache=True)
def jt_step(q, goal, dx, lengths, base, lo, hi, pts, J, out):
    """One Jacobian-transpose step of the tip towards goal into out, clipped to [lo, hi]; returns the tip's
    distance to goal before the step (m).

    WJRRT eq. (17)-(19): dX = goal - tip shortened to at most dx (m); dq = rho J^T dX with
    rho = <dX, J J^T dX> / |J J^T dX|^2, the rho that brings the linearised tip step J dq closest to dX
    (Buss's choice for the transpose method), so the predicted tip step is never longer than dX; out = q + dq.
    """
    n = lengths.size
    tx, ty = tip_jacobian(q, lengths, base, pts, J)
    ex, ey = goal[0] - tx, goal[1] - ty
    d = math.sqrt(ex * ex + ey * ey)
    if d > dx:
        ex *= dx / d
        ey *= dx / d
    vx = 0.0
    vy = 0.0
    for j in range(n):
        g = J[0, j] * ex + J[1, j] * ey
        out[j] = g
        vx += J[0, j] * g
        vy += J[1, j] * g
    den = vx * vx + vy * vy
    rho = (ex * vx + ey * vy) / den if den > 0.0 else 0.0
    for j in range(n):
        out[j] = min(max(q[j] + rho * out[j], lo[j]), hi[j])
    return d
