"""ANN -> FABRIK for the 3R drawing arm (Murai, Vairagi, Semwal, section 3.7, Fig. 4-6),
and the measurements its model card and the benchmarks report.

`solve(ann, xy, theta)`: the ANN's answer for (x, y, theta) (Table 2), refined by
FABRIK with the orientation held (section 3.6 with the pen angle of eq. 4 fixed:
`ik.fabrik.fabrik_oriented`, the wrist joint on the target less l3 along theta,
the first two links solved there, the wrist making up theta), back in joint
angles within the limits, with per-target reachability. A target that cannot be
reached at theta inside the limits (outside the drawing's disc) falls back to
FABRIK on position alone from the same ANN seed, the orientation then free
(`oriented` False). The CBF filter (`ik.cbf`) then keeps the motion there safe.
`drawing_samples` draws targets the way a drawing uses the arm: points in the
safe disc (`ik.region`) at the pen angle, within a band of orientations around it.

Why the orientation is held: plain FABRIK moves every joint to put the tip on
the target and so spends the orientation the ANN matched; on the paper's twelve
samples that left the wrist angle theta = q1 + q2 + q3 3.4 deg RMS off the pen
angle (its Table 8: 1.25 deg). Held, theta is exact to rounding and the tip is
within FABRIK's tolerance.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Any, Callable

import numpy as np

from armbridge.ik.arm3r_ann import poses_of, tip_errors
from armbridge.ik.fabrik import FabrikResult, fabrik, fabrik_oriented
from armbridge.ik.cbf import CbfConfig, TrackResult, track
from armbridge.ik.region import SafeRegion, pen_angle, safe_region
from armbridge.robots.planar import PlanarChain

Predict = Callable[[np.ndarray], np.ndarray]


ORIENTED_PASSES = 200  # FABRIK passes with the orientation held: a folded elbow (wrist near the base) converges slowly
FREE_PASSES = 50  # FABRIK passes on position alone (the fallback, and orient=False)


def solve(chain: PlanarChain, predict: Predict, xy: Any, theta: Any, tol: float = 1e-6,
          max_iter: int | None = None, orient: bool = True) -> FabrikResult:
    """ANN for (x, y, theta) then FABRIK to the points xy (B, 2) with the orientation theta held
    (a scalar or (B,)); targets it cannot reach so are solved on position alone (module docstring).
    orient=False: FABRIK on position alone for every target (the paper's Algorithm as printed).
    max_iter: passes of the held solve and of the fallback [default ORIENTED_PASSES, FREE_PASSES]."""
    xy = np.asarray(xy, dtype=float)
    theta = np.broadcast_to(np.asarray(theta, dtype=float), xy.shape[:-1])
    q0 = predict(np.concatenate([xy, theta[..., None]], axis=-1))
    if not orient:
        return fabrik(chain, xy, q0, tol=tol, max_iter=FREE_PASSES if max_iter is None else max_iter)
    held = fabrik_oriented(chain, xy, theta, q0, tol=tol, max_iter=ORIENTED_PASSES if max_iter is None else max_iter)
    redo = np.flatnonzero(~held.converged)
    if redo.size == 0:
        return held
    free = fabrik(chain, xy[redo], q0[redo], tol=tol, max_iter=FREE_PASSES if max_iter is None else max_iter)
    q, error, oriented = held.q.copy(), held.error.copy(), held.converged.copy()
    better = free.error < error[redo]
    take = redo[better]
    q[take], error[take] = free.q[better], free.error[better]
    reachable = held.reachable.copy()
    reachable[redo] = free.reachable
    iterations = held.iterations.copy()
    iterations[redo] += free.iterations
    return FabrikResult(q=q, error=error, iterations=iterations, reachable=reachable,
                        converged=error <= tol, oriented=oriented)


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


# The CBF-QP a drawing's ANN + FABRIK answers pass through (section 3.5, `ik.cbf`): each
# waypoint's answer held as the reference for PATH_CBF_STEPS steps from the previous one's
# (K dt = 0.2: 100 steps leave 2e-10 of a move). `bench arm3r` measures the same.
PATH_CBF = CbfConfig(gamma=10.0, gain=20.0, dt=0.01)
PATH_CBF_STEPS = 100


def cbf_path(chain: PlanarChain, region: SafeRegion, q_ref: np.ndarray, q_first: np.ndarray,
             steps: int = PATH_CBF_STEPS, cfg: CbfConfig = PATH_CBF) -> TrackResult:
    """Each waypoint i's reference held for `steps` filter steps from waypoint i-1's reference
    (the first from q_first), batched over the waypoints."""
    q0 = np.concatenate([np.asarray(q_first, dtype=float)[None], q_ref[:-1]])
    return track(chain, region, q0, q_ref, steps, cfg)


@dataclass(frozen=True)
class PathReport:
    """What the paper's pipeline did to a drawing's waypoints (the plan's provenance)."""

    model: str  # the ONNX file of the ANN, relative to its card
    model_sha256: str
    waypoints: int
    oriented: int  # solved with the pen angle held (the rest: on position alone)
    fabrik_passes_max: int
    fabrik_tip_max_m: float  # ANN + FABRIK's largest tip error
    ann_tip_mean_m: float  # the ANN alone
    cbf_tip_max_m: float  # after the CBF-QP: the largest distance of the pen from its waypoint
    theta_max_rad: float  # the largest |q1 + q2 + q3 - phi| after the CBF-QP
    cbf_h_min: float  # the least h_0 along the CBF-QP path (>= 0: inside the safe region)

    def to_dict(self) -> dict[str, Any]:
        return {"pipeline": "ANN + FABRIK (pen angle held) + CBF-QP (Murai, Vairagi, Semwal)",
                "model": self.model, "model_sha256": self.model_sha256, "waypoints": self.waypoints,
                "oriented": self.oriented, "fabrik_passes_max": self.fabrik_passes_max,
                "fabrik_tip_max_mm": self.fabrik_tip_max_m * 1e3, "ann_tip_mean_mm": self.ann_tip_mean_m * 1e3,
                "cbf": {**asdict(PATH_CBF), "steps": PATH_CBF_STEPS, "h_min": self.cbf_h_min},
                "tip_max_mm": self.cbf_tip_max_m * 1e3, "theta_max_deg": float(np.rad2deg(self.theta_max_rad))}


def plan_joints(chain: PlanarChain, xy: Any, phi: float, ann: Any = None,
                tol: float = 1e-6) -> tuple[np.ndarray, PathReport]:
    """The joint path (k, 3) through a drawing's pen points xy (k, 2) at the pen angle phi by the
    paper's pipeline: the ANN (default: the shipped float net), FABRIK with the pen angle held,
    then the CBF-QP (`cbf_path`) from the first answer. Raises ArmbridgeError when the robot is
    not the one the ANN was trained for, or a point is not reached within tol (m)."""
    from armbridge.errors import ArmbridgeError
    from armbridge.ik.arm3r_ann import Arm3rANN

    if ann is None:
        try:
            ann = Arm3rANN.load()
        except ImportError as exc:
            raise ArmbridgeError(f"--ik paper needs {exc.name} (`make setup` installs it)") from None
    if ann.chain != chain:
        raise ArmbridgeError(f"--ik paper: the ANN ({ann.card.get('name', '?')}) is trained for robot "
                             f"{ann.chain.name!r}, not {chain.name!r}; use --ik closed")
    xy = np.asarray(xy, dtype=float)
    try:
        q_ann = ann.predict(np.c_[xy, np.full(len(xy), phi)])
    except ImportError as exc:
        raise ArmbridgeError(f"--ik paper needs {exc.name} (`make setup` installs it)") from None
    res = solve(chain, ann.predict, xy, phi, tol=tol)
    bad = np.flatnonzero(~res.ok)
    if bad.size:
        i = int(bad[0])
        raise ArmbridgeError(f"--ik paper: waypoint {i} of {len(xy)} ({xy[i, 0]:.4f}, {xy[i, 1]:.4f}) m is not "
                             f"reached by ANN + FABRIK ({res.error[i] * 1e3:.3g} mm off)")
    region = safe_region(chain)
    path = cbf_path(chain, region, res.q, res.q[0])
    q = path.q
    report = PathReport(
        model=str(ann.onnx_path.name), model_sha256=str(ann.card["files"]["onnx"]["sha256"]),
        waypoints=len(xy), oriented=int(res.oriented.sum()) if res.oriented is not None else 0,
        fabrik_passes_max=int(res.iterations.max(initial=0)), fabrik_tip_max_m=float(res.error.max(initial=0.0)),
        ann_tip_mean_m=float(tip_errors(chain, q_ann, xy).mean()),
        cbf_tip_max_m=float(tip_errors(chain, q, xy).max(initial=0.0)),
        theta_max_rad=float(np.abs(q.sum(axis=-1) - phi).max(initial=0.0)),
        cbf_h_min=float(path.h_min.min(initial=np.inf)))
    return q, report
