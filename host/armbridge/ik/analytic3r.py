"""Closed-form inverse kinematics of a planar 3R chain for a pose (x, y, phi).

The wrist point (x - l3 cos phi, y - l3 sin phi) fixes a two-link problem with
an elbow-up and an elbow-down answer; the third joint then makes up phi.
Joints 1 and 3 are angles, so each may be shifted by 2*pi into its limits.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.geometry import wrap_angle
from armbridge.robots.planar import PlanarChain

# Rounding slack: a wrist exactly at full reach or a joint exactly on a limit
# must still count, though floating point may land a hair outside. Near a
# straight elbow arccos loses q2 to ~1.5e-8 rad (c2 rounds to 1), and q1 and q3
# inherit that error, so the joint slack must cover it (the answer is then
# clipped onto the limit: a tip error under 1e-8 m).
_REACH_TOL = 1e-12
_LIMIT_TOL = 2e-8
# arccos near +-1 turns a 1e-16 rounding error into ~1e-8 rad: an elbow that
# lands that close to its limit is snapped onto it before q1 and q3 are
# derived, so the three joints stay consistent.
_ELBOW_SNAP = 1e-7


def _check_3r(chain: PlanarChain) -> None:
    if chain.n != 3:
        raise ArmbridgeError(f"analytic 3R IK needs a 3-joint chain, robot {chain.name!r} has {chain.n}")


def _poses(pose: Any) -> np.ndarray:
    pose = np.asarray(pose, dtype=float)
    if pose.ndim == 0 or pose.shape[-1] != 3:
        raise ArmbridgeError(f"poses must have shape (..., 3) for (x, y, phi), got {pose.shape}")
    return pose


def _into_limits(q: np.ndarray, lo: np.ndarray, hi: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Shift q by multiples of 2*pi into [lo, hi], nearest to ref; NaN where no shift fits."""
    low = lo - _LIMIT_TOL + np.mod(q - (lo - _LIMIT_TOL), 2 * np.pi)  # smallest copy >= lo
    cands = np.stack([low, low + 2 * np.pi], axis=-1)
    fits = cands <= (hi + _LIMIT_TOL)[:, None]
    dist = np.where(fits, np.abs(cands - ref[..., None]), np.inf)
    best = np.take_along_axis(cands, np.argmin(dist, axis=-1)[..., None], axis=-1)[..., 0]
    return np.where(fits.any(axis=-1), np.clip(best, lo, hi), np.nan)


def _branches(chain: PlanarChain, pose: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The q2 >= 0 and q2 <= 0 solutions, shape (..., 2, 3) (NaN where one does not
    fit the limits), and whether the wrist point is within reach, shape (...)."""
    l1, l2, l3 = chain.link_lengths
    x, y, phi = np.moveaxis(pose, -1, 0)
    wx, wy = x - l3 * np.cos(phi), y - l3 * np.sin(phi)
    c2 = (wx**2 + wy**2 - l1**2 - l2**2) / (2 * l1 * l2)
    reach = np.abs(c2) <= 1 + _REACH_TOL
    q2_abs = np.arccos(np.clip(c2, -1.0, 1.0))
    q2 = np.stack([q2_abs, -q2_abs], axis=-1)  # (..., 2): the two elbow branches
    lo2, hi2 = chain.q_min[1], chain.q_max[1]
    q2 = np.where((q2 > hi2) & (q2 <= hi2 + _ELBOW_SNAP), hi2, q2)
    q2 = np.where((q2 < lo2) & (q2 >= lo2 - _ELBOW_SNAP), lo2, q2)
    q1 = np.arctan2(wy, wx)[..., None] - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
    q3 = phi[..., None] - q1 - q2
    q = np.stack([q1, q2, q3], axis=-1)
    q = _into_limits(q, chain.q_min, chain.q_max, np.broadcast_to(ref[..., None, :], q.shape))
    # a joint clipped onto its limit moved phi by up to the slack: the wrist takes it back
    q[..., 2] = np.clip(q[..., 2] + wrap_angle(phi[..., None] - q.sum(axis=-1)), chain.q_min[2], chain.q_max[2])
    q[~reach] = np.nan
    return q, reach


def ik(chain: PlanarChain, pose: Any, q_prev: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles reaching pose (x, y, phi), shape (..., 3), and an ok mask (...).

    Of the two elbow branches the one inside the joint limits is taken; when
    both are, the one nearest q_prev (default: the middle of the limits), so
    a path stays on its branch. Rows that are out of reach or reachable only
    outside the limits have ok False and q NaN.
    """
    _check_3r(chain)
    pose = _poses(pose)
    ref = (chain.q_min + chain.q_max) / 2 if q_prev is None else np.asarray(q_prev, dtype=float)
    ref = np.broadcast_to(ref, (*pose.shape[:-1], 3))
    cands, _ = _branches(chain, pose, ref)
    dist = np.linalg.norm(cands - ref[..., None, :], axis=-1)
    dist = np.where(np.isnan(dist), np.inf, dist)
    q = np.take_along_axis(cands, np.argmin(dist, axis=-1)[..., None, None], axis=-2)[..., 0, :]
    ok = ~np.isnan(q).any(axis=-1)
    q[~ok] = np.nan
    return q, ok


def solve_path(chain: PlanarChain, poses: Any, q0: Any) -> np.ndarray:
    """Joint path (k, 3) through poses (k, 3), starting from configuration q0.

    Each pose takes the elbow branch nearest the previous solution, so the arm
    does not flip its elbow mid-stroke (a joint whose range spans less than
    2*pi has one copy inside its limits; wider ones take the copy nearest q0).
    Raises ArmbridgeError naming the first pose with no solution inside the
    joint limits.
    """
    _check_3r(chain)
    poses = _poses(poses)
    if poses.ndim != 2:
        raise ArmbridgeError(f"a path is a list of poses, shape (k, 3); got {poses.shape}")
    q0 = np.asarray(q0, dtype=float)
    if q0.shape != (3,):
        raise ArmbridgeError(f"q0 must have shape (3,), got {q0.shape}")
    cands, reach = _branches(chain, poses, np.broadcast_to(q0, poses.shape))
    bad = np.flatnonzero(np.isnan(cands).any(axis=-1).all(axis=-1))
    if bad.size:
        i = int(bad[0])
        why = "reachable only outside the joint limits" if reach[i] else "out of reach"
        x, y, phi = poses[i]
        raise ArmbridgeError(
            f"pose {i} of {len(poses)} (x={x:.4f} m, y={y:.4f} m, phi={phi:.4f} rad) has no IK solution "
            f"for robot {chain.name!r}: {why}"
        )
    # nearest[i][a]: the branch at pose i nearest branch a at pose i-1 (q0 before pose 0).
    prev = np.concatenate([np.broadcast_to(q0, (1, 2, 3)), cands[:-1]])
    dist = np.linalg.norm(cands[:, None, :, :] - prev[:, :, None, :], axis=-1)
    nearest = np.argmin(np.where(np.isnan(dist), np.inf, dist), axis=-1).tolist()
    branch, b = [], 0
    for row in nearest:  # a greedy walk: cheap Python ints, no per-pose numpy calls
        b = row[b]
        branch.append(b)
    return cands[np.arange(len(poses)), branch]
