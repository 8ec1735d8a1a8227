"""The CBF safety filter of the 3R drawing arm (Murai, Vairagi, Semwal, section 3.5, eq. 5-9).

The arm is driven kinematically, eq. (5) with f = 0 and g = I: q' = u (joint
velocities). Tracking a reference q_ref (the ANN + FABRIK answer) the nominal
input is u_n = K (q_ref - q), which makes the Lyapunov function

    V(q) = 1/2 (q - q_ref)^T H (q - q_ref)                      (section 5.2)

decrease. The barrier functions, eq. (6), whose super-level sets must hold:

    h_0(q)   = R^2 - |p(q) - c|^2       the tip p in the circular safe region
    h_i^-(q) = q_i - q_min_i,  h_i^+(q) = q_max_i - q_i   the joint limits

and the CBF-QP, eq. (8)-(9), with the linear class-K function gamma(h) = g h:

    u = argmin 1/2 (u - u_n)^T H (u - u_n)
        s.t.  dh_0/dq u >= -g h_0,   -g h_i^- <= u_i <= g h_i^+,   |u_i| <= v_max_i

The joint rows are a box on u (separable), so the QP has closed forms when
only the box binds (a clip) or only the circle binds (a projection onto its
half-space). Where both bind, its KKT conditions still reduce to a root of a
piecewise-linear function of the one multiplier, found exactly (default), or
the QP goes to OSQP through qpsolvers (solver="osqp"; ~1.7 ms a row here,
against microseconds for the batched kink search, which the tests check
against OSQP). u = 0 is always
feasible (h >= 0), so u is the H-projection of u_n onto a convex set holding 0,
hence u_n^T H u >= |u|_H^2 and dV/dt = -(1/K) u_n^T H u <= 0: V never rises.

Discrete time (a step of dt): the joint rows are linear, so g dt <= 1 keeps
them exactly; the circle is not, so a step that would leave the disc (or a
rounding that would leave a limit) is halved until it does not, down to
staying put. The safe set is therefore invariant step by step, and with
K dt < 2 each step lowers V while the arm moves. Pure numpy.

The circle is the drawing's safe region, `ik.region.safe_region(robot)` (the
disk the drawing is placed in, reached at the pen angle `ik.region.pen_angle`
with every joint 5 degrees inside its limits): one definition for both.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik.region import SafeRegion
from armbridge.robots.planar import PlanarChain


@dataclass(frozen=True)
class CbfConfig:
    """gamma g (1/s), tracking gain K (1/s), step dt (s), H = diag(weights)."""

    gamma: float = 10.0
    gain: float = 5.0
    dt: float = 0.01
    weights: tuple[float, ...] = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        if not (self.gamma > 0 and self.gain > 0 and self.dt > 0):
            raise ArmbridgeError("the CBF needs gamma, gain and dt > 0")
        if self.gamma * self.dt > 1 or self.gain * self.dt >= 2:
            raise ArmbridgeError(f"the CBF step needs gamma*dt <= 1 and gain*dt < 2, got "
                                 f"{self.gamma * self.dt:g} and {self.gain * self.dt:g}")
        if min(self.weights) <= 0:
            raise ArmbridgeError(f"the CBF weights must be > 0, got {self.weights}")


def lyapunov(q: np.ndarray, q_ref: np.ndarray, weights: Any) -> np.ndarray:
    """V = 1/2 (q - q_ref)^T H (q - q_ref), H = diag(weights), shape (...)."""
    e = np.asarray(q) - np.asarray(q_ref)
    return 0.5 * np.sum(np.asarray(weights) * e * e, axis=-1)


def barrier_values(chain: PlanarChain, region: SafeRegion, q: np.ndarray) -> np.ndarray:
    """(h_0, h^-_1..n, h^+_1..n) at q, shape (..., 1 + 2n); all >= 0 is the safe set C (eq. 6)."""
    return np.concatenate([region.h(chain.ee_point(q))[..., None], q - chain.q_min, chain.q_max - q], axis=-1)


def safe(chain: PlanarChain, region: SafeRegion, q: np.ndarray) -> np.ndarray:
    return np.all(barrier_values(chain, region, q) >= 0, axis=-1)


def _qp(hw: np.ndarray, un: np.ndarray, a: np.ndarray, b: float, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """min 1/2 (u - un)^T H (u - un) s.t. a u >= b, lo <= u <= hi, by OSQP; the answer is
    clipped into the box (the step's backtracking catches what is left of OSQP's tolerance)."""
    from qpsolvers import solve_qp
    from scipy import sparse  # type: ignore[import-untyped]

    u = solve_qp(sparse.diags(hw, format="csc"), -hw * un, G=sparse.csc_matrix(-a[None, :]), h=np.array([-b]),
                 lb=lo, ub=hi, solver="osqp", eps_abs=1e-9, eps_rel=1e-9, polish=True, max_iter=4000,
                 verbose=False)
    return np.zeros_like(un) if u is None else np.clip(u, lo, hi)


def _box_halfspace(hw: np.ndarray, un: np.ndarray, a: np.ndarray, b: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both the box and the circle bind: the KKT conditions of the QP give
    u(lam) = clip(un + lam H^-1 a, lo, hi) with lam >= 0 and a u(lam) = b. a u(lam) is
    piecewise linear and non-decreasing in lam, with kinks where a component reaches lo or
    hi, so lam is found exactly between two kinks (rows (m, n)). Returns u and whether
    the row's kink search found the root (else the caller asks OSQP)."""
    d = a / hw
    with np.errstate(divide="ignore", invalid="ignore"):
        kinks = np.concatenate([(lo - un) / d, (hi - un) / d], axis=-1)
    kinks = np.where(np.isfinite(kinks) & (kinks > 0), kinks, 0.0)
    lam = np.sort(np.concatenate([np.zeros((len(un), 1)), kinks], axis=-1), axis=-1)   # (m, 2n + 1)
    phi = np.einsum("mn,mkn->mk", a, np.clip(un[:, None, :] + lam[..., None] * d[:, None, :],
                                              lo[:, None, :], hi[:, None, :]))
    k = np.argmax(phi >= b[:, None], axis=-1)
    found = (phi[np.arange(len(un)), k] >= b) & (k > 0)
    k = np.maximum(k, 1)
    r = np.arange(len(un))
    l0, l1, p0, p1 = lam[r, k - 1], lam[r, k], phi[r, k - 1], phi[r, k]
    root = l0 + (b - p0) * (l1 - l0) / np.where(p1 > p0, p1 - p0, 1.0)
    return np.clip(un + root[:, None] * d, lo, hi), found


def filter_velocity(chain: PlanarChain, region: SafeRegion, q: np.ndarray, u_nom: np.ndarray,
                    cfg: CbfConfig = CbfConfig(), solver: str = "exact") -> tuple[np.ndarray, dict[str, int]]:
    """The CBF-QP (8)-(9) for a batch: u (B, n) nearest u_nom in the H metric under the
    constraints of the module docstring. Rows where only the box or only the circle binds
    have closed forms; rows where both bind are solved by the exact kink search
    (solver="exact", OSQP where it fails) or by OSQP (solver="osqp"). Returns u and how
    many rows each way took."""
    if solver not in ("exact", "osqp"):
        raise ArmbridgeError(f"CBF solver must be exact or osqp, got {solver!r}")
    hw = np.asarray(cfg.weights, dtype=float)
    tip = chain.ee_point(q)
    jac = chain.jacobian(q)[:, :2, :]                                   # dp/dq (B, 2, n)
    a = -2 * np.einsum("bk,bkn->bn", tip - np.asarray(region.center), jac)  # dh_0/dq
    b = -cfg.gamma * region.h(tip)
    lo = np.minimum(np.maximum(-chain.v_max, -cfg.gamma * (q - chain.q_min)), 0.0)
    hi = np.maximum(np.minimum(chain.v_max, cfg.gamma * (chain.q_max - q)), 0.0)
    u = np.clip(u_nom, lo, hi)                                          # only the box binds
    need = np.einsum("bn,bn->b", a, u) < b
    stats = {"box_or_free": int((~need).sum()), "circle": 0, "both_exact": 0, "osqp": 0}
    if need.any():
        i = np.flatnonzero(need)
        ai, un = a[i], u_nom[i]
        hinv_a = ai / hw
        lam = (b[i] - np.einsum("bn,bn->b", ai, un)) / np.maximum(np.einsum("bn,bn->b", ai, hinv_a), 1e-300)
        u1 = un + lam[:, None] * hinv_a                                 # only the circle binds
        fits = np.all((u1 >= lo[i]) & (u1 <= hi[i]), axis=-1)
        u[i[fits]] = u1[fits]
        stats["circle"] = int(fits.sum())
        both = i[~fits]
        if both.size and solver == "exact":
            ub, found = _box_halfspace(hw, u_nom[both], a[both], b[both], lo[both], hi[both])
            u[both[found]] = ub[found]
            stats["both_exact"] = int(found.sum())
            both = both[~found]
        for k in both:                                                  # the QP solver
            u[k] = _qp(hw, u_nom[k], a[k], float(b[k]), lo[k], hi[k])
        stats["osqp"] = int(both.size)
    return u, stats


@dataclass
class TrackResult:
    """q after the last step; V per step (steps + 1, B); the least h_0 and least joint margin seen
    per row (>= 0: never left the safe set); solver counts over all steps."""

    q: np.ndarray
    V: np.ndarray
    h_min: np.ndarray
    limit_margin_min: np.ndarray
    stats: dict[str, int]


def step(chain: PlanarChain, region: SafeRegion, q: np.ndarray, q_ref: np.ndarray,
         cfg: CbfConfig = CbfConfig(), solver: str = "exact") -> tuple[np.ndarray, dict[str, int]]:
    """One filtered Euler step of q' = u from safe states q (B, n) toward q_ref (B, n)."""
    u, stats = filter_velocity(chain, region, q, cfg.gain * (q_ref - q), cfg, solver)
    nxt = q + cfg.dt * u
    bad = np.flatnonzero(~safe(chain, region, nxt))
    stats["backtracked"] = int(bad.size)
    s = 1.0
    while bad.size:
        s /= 2
        if s < 2**-30:                      # stay put: q is safe
            nxt[bad] = q[bad]
            break
        nxt[bad] = q[bad] + s * cfg.dt * u[bad]
        bad = bad[~safe(chain, region, nxt[bad])]
    return nxt, stats


def track(chain: PlanarChain, region: SafeRegion, q0: Any, q_ref: Any, steps: int,
          cfg: CbfConfig = CbfConfig(), solver: str = "exact") -> TrackResult:
    """Run `steps` filtered steps from q0 (B, n) toward q_ref: (B, n) held, or (steps, B, n) one
    per step (a path). q0 must be safe; a row that is not is an ArmbridgeError."""
    q = np.array(q0, dtype=float)
    ref = np.asarray(q_ref, dtype=float)
    if q.ndim != 2 or q.shape[1] != chain.n:
        raise ArmbridgeError(f"q0 must have shape (B, {chain.n}), got {q.shape}")
    if ref.shape not in (q.shape, (steps, *q.shape)):
        raise ArmbridgeError(f"q_ref must have shape {q.shape} or {(steps, *q.shape)}, got {ref.shape}")
    unsafe = np.flatnonzero(~safe(chain, region, q))
    if unsafe.size:
        raise ArmbridgeError(f"q0 row {int(unsafe[0])} is outside the safe set (tip outside the region "
                             f"or a joint outside its limits); the CBF keeps a safe state safe")
    refs = ref if ref.ndim == 3 else None
    V = np.empty((steps + 1, q.shape[0]))
    V[0] = lyapunov(q, ref[0] if refs is not None else ref, cfg.weights)
    hv = barrier_values(chain, region, q)
    h_min, margin = hv[:, 0].copy(), hv[:, 1:].min(axis=1)
    total = {"box_or_free": 0, "circle": 0, "both_exact": 0, "osqp": 0, "backtracked": 0}
    for k in range(steps):
        r = refs[k] if refs is not None else ref
        q, stats = step(chain, region, q, r, cfg, solver)
        for key, v in stats.items():
            total[key] += v
        V[k + 1] = lyapunov(q, r, cfg.weights)
        hv = barrier_values(chain, region, q)
        h_min = np.minimum(h_min, hv[:, 0])
        margin = np.minimum(margin, hv[:, 1:].min(axis=1))
    return TrackResult(q=q, V=V, h_min=h_min, limit_margin_min=margin, stats=total)
