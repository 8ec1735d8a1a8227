"""FABRIK for a planar chain (Murai, Vairagi, Semwal, section 3.6 and its Algorithm;
Aristidou and Lasenby 2011), over a batch of targets at once.

It refines an initial answer (the ANN's, `ik.arm3r_ann`) on joint positions:
Phase I (forward reaching, steps 5-6) puts the tip on the target and pulls
each joint back along its link, p_i = (1 - k_i) p_{i+1} + k_i p_i with
k_i = d_i / r_i (the paper prints k_i = d_i r_i; the ratio is what keeps the
link length d_i); Phase II (backward reaching, steps 7-8) puts the root back on
the base b and pushes each joint out again. Phase II here also turns each
link's direction into its joint angle and clips that into the joint's limits
before placing the next joint, so the positions it leaves are always those of
a configuration inside the limits: "joint positions turned back into angles"
is then exact, not a projection after the fact.

Reachability is reported per target: `reachable` is step 2's test
(|p_1 - t| <= sum d_i); `converged` is |p_n - t| <= tol within max_iter
passes (a target inside the reach but outside the joint-limited workspace
is reachable and not converged). Pure numpy: arrays in, arrays out.

`fabrik_oriented` is FABRIK with the paper's orientation constraint: the
drawing arm holds its end-effector orientation phi = q1 + ... + qn (eq. 4;
section 4.2.1 keeps the wrist fixed while the others move), so the last joint
is placed at the target less the last link along phi, t - l_n (cos phi,
sin phi), the chain without its last link is solved to that point by the
FABRIK above, and the last joint makes up phi, q_n = phi - (q1 + ... + q_{n-1})
(clipped into its limits). Plain FABRIK on the whole chain reaches the
position only: it spends the orientation freely, which is what the 3R paper's
theta error (Tables 5 and 8) measures.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.robots.planar import PlanarChain

TWO_PI = 2 * np.pi


@dataclass(frozen=True)
class FabrikResult:
    """Per target: q (B, n) inside the limits, tip error (m), passes done, step-2 reachability, convergence."""

    q: np.ndarray
    error: np.ndarray
    iterations: np.ndarray
    reachable: np.ndarray
    converged: np.ndarray
    oriented: np.ndarray | None = None  # per target: solved with the orientation held (None: position only)

    @property
    def ok(self) -> np.ndarray:
        """Reachable and converged: the tip is on the target within tol."""
        return self.reachable & self.converged


def clip_angle(a: np.ndarray, lo: Any, hi: Any) -> np.ndarray:
    """The copy of angle a inside [lo, hi] (limits spanning less than 2 pi), or, when no copy
    is inside, the limit nearer to a around the circle."""
    width = np.asarray(hi) - np.asarray(lo)
    m = np.mod(a - lo, TWO_PI)
    inside = m <= width
    to_hi, to_lo = m - width, TWO_PI - m
    return np.where(inside, lo + m, np.where(to_hi <= to_lo, hi, lo))


def _unit(v: np.ndarray) -> np.ndarray:
    """v / |v| along the last axis; a zero vector (two joints on one point) becomes +x."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    safe = n > 1e-15
    return np.where(safe, v / np.where(safe, n, 1.0), np.array([1.0, 0.0]))


def _backward(chain: PlanarChain, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Phase II (steps 7-8) with the limits: root on the base, each link along its direction
    clipped to its joint's range. Returns the joint angles and the new positions."""
    d = chain.link_lengths
    q = np.empty((p.shape[0], chain.n))
    out = np.empty_like(p)
    out[:, 0] = 0.0
    heading = np.zeros(p.shape[0])
    for i in range(chain.n):
        v = p[:, i + 1] - out[:, i]
        q[:, i] = clip_angle(np.arctan2(v[:, 1], v[:, 0]) - heading, chain.q_min[i], chain.q_max[i])
        heading = heading + q[:, i]
        out[:, i + 1] = out[:, i] + d[i] * np.stack([np.cos(heading), np.sin(heading)], axis=-1)
    return q, out


def _forward(chain: PlanarChain, p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Phase I (steps 5-6) with the limits: tip on the target, each joint pulled back along its
    link, the angle between a link and the next one out clipped into that joint's range (the
    root's own angle waits for Phase II, where the base is fixed)."""
    d = chain.link_lengths
    p = p.copy()
    p[:, -1] = t
    v = p[:, -2] - t
    out_heading = np.arctan2(-v[:, 1], -v[:, 0])  # direction of the last link, base to tip
    p[:, -2] = t - d[-1] * np.stack([np.cos(out_heading), np.sin(out_heading)], axis=-1)
    for i in range(chain.n - 2, -1, -1):
        v = p[:, i + 1] - p[:, i]
        rel = clip_angle(out_heading - np.arctan2(v[:, 1], v[:, 0]), chain.q_min[i + 1], chain.q_max[i + 1])
        out_heading = out_heading - rel
        p[:, i] = p[:, i + 1] - d[i] * np.stack([np.cos(out_heading), np.sin(out_heading)], axis=-1)
    return p


def fabrik(chain: PlanarChain, targets: Any, q_init: Any, tol: float = 1e-6, max_iter: int = 50,
           restarts: int = 4) -> FabrikResult:
    """Refine q_init (B, n) so the tip reaches targets (B, 2); section 3.6 with joint limits.

    Each pass is Phase I then Phase II (steps 4-10) on the targets not yet within tol; a
    target beyond the reach (step 2) is not iterated: the arm is stretched toward it
    (the standard FABRIK answer), reachable False. q_init is clipped into the limits first.
    With limits FABRIK can fold the chain onto a limit corner and stall there; a target
    still off after max_iter passes is tried again from up to `restarts` fixed starts
    spread over the limits (seeded, so the answer is a function of the input), keeping
    the best.
    """
    res = _fabrik(chain, targets, q_init, tol, max_iter)
    starts = chain.q_min + np.random.default_rng(0).random((restarts, chain.n)) * (chain.q_max - chain.q_min)
    if restarts > 0:
        starts[0] = (chain.q_min + chain.q_max) / 2
    q, error, iterations = res.q.copy(), res.error.copy(), res.iterations.copy()
    for start in starts:
        redo = np.flatnonzero(res.reachable & (error > tol))
        if redo.size == 0:
            break
        again = _fabrik(chain, np.asarray(targets, dtype=float)[redo],
                        np.tile(start, (redo.size, 1)), tol, max_iter)
        better = again.error < error[redo]
        q[redo[better]], error[redo[better]] = again.q[better], again.error[better]
        iterations[redo] += again.iterations
    return FabrikResult(q=q, error=error, iterations=iterations, reachable=res.reachable, converged=error <= tol)


def _fabrik(chain: PlanarChain, targets: Any, q_init: Any, tol: float, max_iter: int) -> FabrikResult:
    t = np.asarray(targets, dtype=float)
    q = np.asarray(q_init, dtype=float)
    if t.ndim != 2 or t.shape[1] != 2:
        raise ArmbridgeError(f"FABRIK targets must have shape (B, 2), got {t.shape}")
    if q.shape != (t.shape[0], chain.n):
        raise ArmbridgeError(f"FABRIK q_init must have shape ({t.shape[0]}, {chain.n}), got {q.shape}")
    if tol <= 0 or max_iter < 0:
        raise ArmbridgeError(f"FABRIK needs tol > 0 and max_iter >= 0, got tol={tol}, max_iter={max_iter}")
    q = np.stack([clip_angle(q[:, i], chain.q_min[i], chain.q_max[i]) for i in range(chain.n)], axis=-1)
    reachable = np.linalg.norm(t, axis=-1) <= chain.reach  # step 1-2: dist = |p_1 - t| <= sum d_i
    far = np.flatnonzero(~reachable)
    if far.size:  # stretched straight at the target, then clipped into the limits
        q[far] = 0.0
        q[far, 0] = np.arctan2(t[far, 1], t[far, 0])
        q[far] = np.stack([clip_angle(q[far, i], chain.q_min[i], chain.q_max[i]) for i in range(chain.n)], axis=-1)
    error = np.linalg.norm(chain.ee_point(q) - t, axis=-1)
    iterations = np.zeros(t.shape[0], dtype=np.int64)
    active = np.flatnonzero(reachable & (error > tol))
    p = chain.joint_points(q[active])
    for _ in range(max_iter):
        if active.size == 0:
            break
        qa, p = _backward(chain, _forward(chain, p, t[active]))
        err = np.linalg.norm(p[:, -1] - t[active], axis=-1)
        q[active], error[active] = qa, err
        iterations[active] += 1
        keep = err > tol
        active, p = active[keep], p[keep]
    return FabrikResult(q=q, error=error, iterations=iterations, reachable=reachable,
                        converged=error <= tol)


def _without_last_link(chain: PlanarChain) -> PlanarChain:
    return PlanarChain(name=f"{chain.name}[:-1]", link_lengths=chain.link_lengths[:-1], q_min=chain.q_min[:-1],
                       q_max=chain.q_max[:-1], v_max=chain.v_max[:-1], joint_names=chain.joint_names[:-1])


def fabrik_oriented(chain: PlanarChain, targets: Any, phi: Any, q_init: Any, tol: float = 1e-6,
                    max_iter: int = 50, restarts: int = 4) -> FabrikResult:
    """Refine q_init (B, n) so the tip reaches targets (B, 2) with orientation phi (scalar or (B,),
    rad): the last joint on t - l_n (cos phi, sin phi), the rest of the chain solved there by
    `fabrik`, the last joint making up phi (module docstring). `error` is the tip's distance from
    the target; `converged` is error <= tol with the last joint inside its limits (the orientation
    then exact to rounding); `reachable` is step 2's test for the wrist point on the shorter chain.
    """
    t = np.asarray(targets, dtype=float)
    if t.ndim != 2 or t.shape[1] != 2:
        raise ArmbridgeError(f"FABRIK targets must have shape (B, 2), got {t.shape}")
    q0 = np.asarray(q_init, dtype=float)
    if q0.shape != (t.shape[0], chain.n):
        raise ArmbridgeError(f"FABRIK q_init must have shape ({t.shape[0]}, {chain.n}), got {q0.shape}")
    if chain.n < 2:
        raise ArmbridgeError(f"FABRIK with the orientation held needs at least 2 joints, robot {chain.name!r} has {chain.n}")
    phi = np.broadcast_to(np.asarray(phi, dtype=float), t.shape[:1])
    ln = chain.link_lengths[-1]
    wrist = t - ln * np.stack([np.cos(phi), np.sin(phi)], axis=-1)
    res = fabrik(_without_last_link(chain), wrist, q0[:, :-1], tol=tol, max_iter=max_iter, restarts=restarts)
    want = phi - res.q.sum(axis=-1)
    last = clip_angle(want, chain.q_min[-1], chain.q_max[-1])
    q = np.concatenate([res.q, last[:, None]], axis=-1)
    error = np.linalg.norm(chain.ee_point(q) - t, axis=-1)
    held = np.abs(np.mod(want - last + np.pi, TWO_PI) - np.pi) <= 1e-12
    converged = (error <= tol) & held
    return FabrikResult(q=q, error=error, iterations=res.iterations, reachable=res.reachable,
                        converged=converged, oriented=converged)
