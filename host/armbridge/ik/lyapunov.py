"""The CBF filter's Lyapunov function along a filtered trajectory, and the check that it
decreases (Murai, Vairagi, Semwal, section 5.2 and Fig. 13, "Lyapunov function with CBF").

Which V. The paper says the Lyapunov function keeps the motion stable "by minimizing
the squared sum of joint angles" (section 3.7) and that it "showed a steady decrease
over time" (section 5.2, Fig. 13). Read literally, sum q_i^2 is a Lyapunov function of
the folded pose q = 0, which no drawing tracks, and which nothing in the CBF-QP drives
towards. What the filter decreases is the squared sum of the joint angles measured from
the reference it tracks (the ANN + FABRIK answer), the V of `ik.cbf`:

    V(q, q_ref) = 1/2 (q - q_ref)^T H (q - q_ref)        (H = diag(weights) of eq. 8)

so that is the V here (`ik.cbf.lyapunov`, not a copy). The tip error 1/2 |x_t - x|^2 is
not used: the nominal input u_n = K (q_ref - q) is a joint-space law, under which the
tip's distance to its target need not fall monotonically, so it is no certificate.

Why it decreases. u (the CBF-QP's answer, eq. 8-9) is the H-projection of u_n onto a
convex set that holds 0 (the circle's half-space and the joint box, both satisfied by
u = 0 on the safe set), so u_n^T H u >= |u|_H^2 and, with e = q - q_ref = -u_n / K,

    dV/dt = e^T H u = -(1/K) u_n^T H u <= -(1/K) |u|_H^2 <= 0        (continuous time)
    V(q + s dt u) - V(q) <= s dt |u|_H^2 (s dt / 2 - 1/K) <= 0        (one Euler step)

for every backtracking scale s in (0, 1] of `ik.cbf.step`, because CbfConfig enforces
K dt < 2. Both hold with the constraint active: the filter then trades tracking for
safety (u != u_n) but still never moves away from the reference.

What `check` tests, on every step k of every row: V after the step, measured against
the reference that step tracked, is at most V before it (up to rtol V + atol, the
rounding of V near 0 and OSQP's tolerance where the filter falls back to it), and
dV/dt along the step taken is <= the same tolerance. Where it cannot hold, and is
reported rather than counted as a violation:

* a target update: V is re-measured against a new reference and jumps (`updates`,
  `update_rises`); no step of the filter causes it;
* a reference outside the safe set (a tip target outside the disc, a joint past its
  limit): V decreases but stalls above 0, at the distance from q_ref to the safe
  point the constraint holds the arm at (`constrained_steps`, `constrained_at_end`,
  `final_V_max`): the constraint is active and tracking is traded for safety.

Pure numpy; the stepping is `ik.cbf.step`'s, this module records q along the way.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik.cbf import CbfConfig, lyapunov, safe, step
from armbridge.ik.region import SafeRegion
from armbridge.robots.planar import PlanarChain

RTOL = 1e-9   # a step may raise V by rtol V + atol and still count as not increasing
ATOL = 1e-15  # rad^2: the rounding of V = 1/2 |e|^2 where e is ~1e-8 rad


@dataclass
class LyapunovTrace:
    """A filtered run: q (steps + 1, B, n) and the reference of each step refs (steps, B, n).

    before[k] = V(q_k, refs_k), after[k] = V(q_{k+1}, refs_k): the step's own change;
    dvdt[k] = (q_k - refs_k)^T H (q_{k+1} - q_k) / dt, dV/dt along the step taken;
    constrained[k]: the filter changed the nominal step dt K (refs_k - q_k) (the CBF
    or the joint box bound); update[k]: refs_k is a new reference (k = 0 always)."""

    q: np.ndarray
    refs: np.ndarray
    dt: float
    gain: float
    before: np.ndarray
    after: np.ndarray
    dvdt: np.ndarray
    constrained: np.ndarray
    update: np.ndarray

    @property
    def t(self) -> np.ndarray:
        """Time at the end of each step, s (steps,)."""
        return self.dt * np.arange(1, len(self.refs) + 1)


def held_path(targets: list[np.ndarray], hold: int) -> np.ndarray:
    """References (steps, B, n) for B rows of targets (P_b, n) each, every target held for
    `hold` steps; a row shorter than the longest keeps its last target."""
    if hold < 1 or not targets or any(len(t) == 0 for t in targets):
        raise ArmbridgeError("a Lyapunov path needs hold >= 1 and at least one target per row")
    p = max(len(t) for t in targets)
    padded = np.stack([np.concatenate([t, np.repeat(t[-1:], p - len(t), axis=0)]) for t in
                       (np.asarray(t, dtype=float) for t in targets)], axis=1)   # (P, B, n)
    return np.repeat(padded, hold, axis=0)


def trace_of(q: np.ndarray, refs: np.ndarray, cfg: CbfConfig) -> LyapunovTrace:
    """The Lyapunov quantities of a recorded run q (steps + 1, B, n) under refs (steps, B, n)."""
    q, refs = np.asarray(q, dtype=float), np.asarray(refs, dtype=float)
    if q.ndim != 3 or refs.shape != (len(q) - 1, *q.shape[1:]):
        raise ArmbridgeError(f"q must be (steps + 1, B, n) and refs (steps, B, n), got {q.shape} and {refs.shape}")
    w = np.asarray(cfg.weights, dtype=float)
    start, moved = q[:-1], np.diff(q, axis=0)
    nominal = cfg.dt * cfg.gain * (refs - start)
    off = np.linalg.norm(moved - nominal, axis=-1)
    constrained = off > 1e-9 * np.linalg.norm(nominal, axis=-1) + 1e-15
    update = np.ones(refs.shape[:2], dtype=bool)
    update[1:] = np.any(refs[1:] != refs[:-1], axis=-1)
    return LyapunovTrace(q=q, refs=refs, dt=cfg.dt, gain=cfg.gain, before=lyapunov(start, refs, w), after=lyapunov(q[1:], refs, w),
                         dvdt=np.sum(w * (start - refs) * moved, axis=-1) / cfg.dt, constrained=constrained,
                         update=update)


def simulate(chain: PlanarChain, region: SafeRegion, q0: Any, refs: Any, cfg: CbfConfig = CbfConfig(),
             solver: str = "exact") -> LyapunovTrace:
    """Run `ik.cbf.step` from safe states q0 (B, n) through refs (steps, B, n), recording q."""
    q = np.array(q0, dtype=float)
    refs = np.asarray(refs, dtype=float)
    if q.ndim != 2 or q.shape[1] != chain.n or refs.ndim != 3 or refs.shape[1:] != q.shape:
        raise ArmbridgeError(f"q0 must be (B, {chain.n}) and refs (steps, B, {chain.n}), got {q.shape} and "
                             f"{refs.shape}")
    unsafe = np.flatnonzero(~safe(chain, region, q))
    if unsafe.size:
        raise ArmbridgeError(f"q0 row {int(unsafe[0])} is outside the safe set; the CBF keeps a safe state safe")
    qs = np.empty((len(refs) + 1, *q.shape))
    qs[0] = q
    for k, r in enumerate(refs):
        qs[k + 1], _ = step(chain, region, qs[k], r, cfg, solver)
    return trace_of(qs, refs, cfg)


def check(tr: LyapunovTrace, rtol: float = RTOL, atol: float = ATOL) -> dict[str, Any]:
    """Does V decrease? The counts of the module docstring, over every step of every row."""
    tol = rtol * tr.before + atol
    rise = tr.after - tr.before
    bad = rise > tol
    jumps = tr.before[1:] - tr.after[:-1]                   # V against the new reference minus the old
    upd = tr.update[1:]
    last = tr.constrained[-1]
    return {
        "rows": int(tr.before.shape[1]), "steps": int(tr.before.shape[0]), "checked": int(tr.before.size),
        "rtol": rtol, "atol": atol,
        "violations": int(bad.sum()), "violations_per_row": bad.sum(axis=0).tolist(),
        "max_increase": float(rise.max()),
        "max_ratio": float(np.max(np.where(tr.before > atol, tr.after / np.where(tr.before > atol, tr.before, 1),
                                           0.0))),
        "dvdt_violations": int((tr.dvdt > tol / tr.dt).sum()), "dvdt_max": float(tr.dvdt.max()),
        "updates": int(tr.update.sum()), "update_rises": int((upd & (jumps > 0)).sum()),
        "update_max_jump": float(jumps[upd].max()) if upd.any() else 0.0,
        "constrained_steps": int(tr.constrained.sum()),
        "constrained_per_row": tr.constrained.sum(axis=0).tolist(),
        "constrained_at_end": int(last.sum()),
        "final_V_max": float(tr.after[-1].max()),
        "final_V_max_unconstrained": float(tr.after[-1][~last].max()) if (~last).any() else 0.0,
    }
