"""Eq. (18) error correction: q += J^+ Delta x_e, batched over configurations.

One implementation for every SMM source: the nullspace method corrects its
resampled branches with it (torch), the learned method its decoded ones
(numpy: the runtime needs no torch). Written against the array API, like the
kinematics (armbridge.robots.dh), so it runs on whichever kind q is.
"""
from __future__ import annotations

import math
from typing import Any

from array_api_compat import device

from armbridge.geometry import wrap_angle
from armbridge.robots.dh import DHChain
from armbridge.robots.rotations import xp_of

SmmArm = DHChain
DAMPING = 1e-10  # lambda^2 of the damped pseudoinverse in eq. (18): keeps J J^T invertible at singular points
CHUNK = 16384  # points per chunk of the correction (keeps the intermediates in the CPU cache)


def damped_pinv_step(jac: Any, err: Any, damping: float = DAMPING) -> Any:
    """J^+ e as J^T y with (J J^T + damping I) y = e, batched (eq. 18); J (P, m, n), e (P, m).

    For m = 2 and 3 by Cramer's rule on (P,) tensors: about twice as fast on
    the CPU as a batched solve of millions of tiny systems.
    """
    xp = xp_of(jac)
    m = jac.shape[-2]
    if m > 3:
        eye = xp.eye(m, dtype=jac.dtype, device=device(jac))
        y = xp.linalg.solve(jac @ jac.mT + damping * eye, err[..., None])
        return (jac.mT @ y)[..., 0]
    rows = [jac[:, r] for r in range(m)]
    a = [[(rows[r] * rows[c]).sum(-1) + (damping if r == c else 0.0) for c in range(m)] for r in range(m)]
    e = [err[:, r] for r in range(m)]
    if m == 2:
        det = a[0][0] * a[1][1] - a[0][1] * a[1][0]
        y = [a[1][1] * e[0] - a[0][1] * e[1], a[0][0] * e[1] - a[1][0] * e[0]]
    else:  # cofactors by cyclic indices; a is symmetric, so its adjugate is the cofactor matrix
        cof = [[a[(r + 1) % 3][(c + 1) % 3] * a[(r + 2) % 3][(c + 2) % 3]
                - a[(r + 1) % 3][(c + 2) % 3] * a[(r + 2) % 3][(c + 1) % 3] for c in range(3)] for r in range(3)]
        det = a[0][0] * cof[0][0] + a[0][1] * cof[0][1] + a[0][2] * cof[0][2]
        y = [cof[r][0] * e[0] + cof[r][1] * e[1] + cof[r][2] * e[2] for r in range(3)]
    inv = 1.0 / det
    dq = rows[0] * (y[0] * inv)[..., None]
    for r in range(1, m):
        dq = dq + rows[r] * (y[r] * inv)[..., None]
    return dq


def error_and_step(arm: SmmArm, q: Any, x: Any, damping: float = DAMPING, step: bool = True
                   ) -> tuple[Any, Any | None]:
    """Squared task error of q (P,) (position rows in units of the reach, as eq. 19) and the
    eq. (18) step J^+ Delta x_e (P, n), or None for step=False; q (P, n), x (P, m)."""
    rot, tip, jac = arm.kinematics(q) if step else (*arm.tip(q), None)
    err = arm.tip_error(rot, tip, x)
    npos = min(arm.m, 3)
    score = (err[:, :npos] ** 2).sum(-1) / arm.reach**2 + (err[:, npos:] ** 2).sum(-1)
    return score, damped_pinv_step(jac, err, damping) if jac is not None else None


def correct(arm: SmmArm, q: Any, x: Any, iters: int, damping: float = DAMPING, chunk: int = CHUNK) -> Any:
    """`iters` steps of q += J^+ Delta x_e (eq. 18) for configurations q (P, n) at targets x (P, m).

    Each point keeps its best iterate (least task error, the start included),
    so a step that overshoots near a singular configuration never makes a
    point worse than the network's; that costs one evaluation without a
    Jacobian after the last step. Chunks of `chunk` points take all their
    steps in turn, so their intermediates stay in the CPU cache.
    """
    xp = xp_of(q)
    out = []
    for start in range(0, q.shape[0], chunk):
        qc, xc = q[start : start + chunk], x[start : start + chunk]
        best, best_score = qc, xp.full_like(qc[:, 0], math.inf)
        for i in range(iters + 1):
            score, dq = error_and_step(arm, qc, xc, damping, step=i < iters)
            better = score < best_score
            best, best_score = xp.where(better[:, None], qc, best), xp.where(better, score, best_score)
            if dq is not None:
                qc = wrap_angle(qc + dq)
        out.append(best)
    return xp.concat(out) if out else q
