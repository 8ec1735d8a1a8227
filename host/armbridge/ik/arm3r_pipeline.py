"""ANN -> FABRIK for the 3R drawing arm (Murai, Vairagi, Semwal, section 3.7, Fig. 4-6),
and the measurements its model card and the benchmarks report.

`solve(ann, xy, theta)`: the ANN's answer for (x, y, theta) (Table 2), refined by
FABRIK on position (section 3.6), back in joint angles within the limits, with
per-target reachability. The CBF filter (`ik.cbf`) then keeps the motion there
safe. `drawing_samples` draws targets the way a drawing uses the arm: points
in the safe disc (`ik.region`) at the pen angle, within a band of orientations around it.
"""
from __future__ import annotations

import time
from typing import Any, Callable

import numpy as np

from armbridge.ik.arm3r_ann import poses_of, tip_errors
from armbridge.ik.fabrik import FabrikResult, fabrik
from armbridge.ik.region import pen_angle, safe_region
from armbridge.robots.planar import PlanarChain

Predict = Callable[[np.ndarray], np.ndarray]


def solve(chain: PlanarChain, predict: Predict, xy: Any, theta: Any, tol: float = 1e-6,
          max_iter: int = 50) -> FabrikResult:
    """ANN for (x, y, theta) then FABRIK to the points xy (B, 2); theta a scalar or (B,)."""
    xy = np.asarray(xy, dtype=float)
    theta = np.broadcast_to(np.asarray(theta, dtype=float), xy.shape[:-1])
    q0 = predict(np.concatenate([xy, theta[..., None]], axis=-1))
    return fabrik(chain, xy, q0, tol=tol, max_iter=max_iter)


def drawing_samples(chain: PlanarChain, count: int, seed: int, spread: float = 0.25) -> np.ndarray:
    """count poses (x, y, theta): points uniform in the safe disc (`ik.region`), theta uniform in
    the pen angle +- spread."""
    region, theta = safe_region(chain), pen_angle(chain)
    rng = np.random.default_rng(seed)
    r = region.radius * np.sqrt(rng.random(count))
    a = rng.random(count) * 2 * np.pi
    xy = region.center + np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)
    return np.concatenate([xy, (theta + spread * (2 * rng.random(count) - 1))[:, None]], axis=-1)


def _mm(e: np.ndarray) -> dict[str, float]:
    e = np.asarray(e) * 1e3
    return {"mean_mm": float(e.mean()), "p95_mm": float(np.percentile(e, 95)), "max_mm": float(e.max())}


def measure(chain: PlanarChain, predict: Predict, poses: np.ndarray, q_true: np.ndarray | None = None,
            fabrik_iter: int = 50) -> dict[str, Any]:
    """The card's numbers on poses (N, 3): the ANN's tip error and (given the true q) joint MAE,
    then ANN + FABRIK's tip error, convergence and passes, and batched time per point."""
    t0 = time.perf_counter()
    q = predict(poses)
    t1 = time.perf_counter()
    res = fabrik(chain, poses[:, :2], q, max_iter=fabrik_iter)
    t2 = time.perf_counter()
    n = len(poses)
    ann: dict[str, Any] = {"tip": _mm(tip_errors(chain, q, poses[:, :2])),
                           "theta_mae_rad": float(np.abs(poses_of(chain, q)[:, 2] - poses[:, 2]).mean()),
                           "batched_ms_per_point": (t1 - t0) / n * 1e3}
    if q_true is not None:
        ann["q_mae_rad"] = np.abs(q - q_true).mean(axis=0).tolist()
    refined = {"tip": _mm(res.error), "converged_pct": float(res.converged.mean() * 100),
               "mean_passes": float(res.iterations.mean()), "max_passes": fabrik_iter,
               "theta_mae_rad": float(np.abs(poses_of(chain, res.q)[:, 2] - poses[:, 2]).mean()),
               "batched_ms_per_point": (t2 - t0) / n * 1e3}
    return {"points": n, "ann": ann, "ann_fabrik": refined}
