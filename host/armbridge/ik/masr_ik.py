"""MASR inverse kinematics behind one interface: the shipped IK-NN in onnxruntime,
optionally refined by damped least squares, plus the evaluation protocol.

    ik = MasrIK.load("models/onnx/masr5-iknn-card.json")
    q = ik.solve(x_goal, q_c)               # NN alone, (..., 3) + (..., n+1) -> (..., n+1)
    q = ik.solve(x_goal, q_c, refine=True)  # NN + a few DLS steps

Refinement keeps the link the NN put the MA on (j_d) and moves only what can
move the MA on that link: the joints theta_1..theta_{j_d} and the MA position
d within the link (d_link in [0, l_{j_d}]). Each step solves the 3-row
damped least-squares system on the error measured in goal-tolerance units (dp / e_p, dphi / e_phi), then clips to
the joint limits; the best iterate per query is kept, so refinement never
returns a worse pose than the NN's. Then the joints past the MA's link go
back to their current values q_c (they do not move the MA; the action time
can only drop).

Pure numpy + onnxruntime: no torch at run time.
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.robots.masr import MasrArm
from armbridge.robots.planar import wrap_angle

E_P = 0.008  # m, eq. (9) bound of section V-A
E_PHI = math.radians(4.0)  # rad


# ------------------------------------------------------------ evaluation protocol


def random_configs(arm: MasrArm, count: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform random configurations in C_f (eq. 5), shape (count, n+1)."""
    tb = np.asarray(arm.theta_b, dtype=float)
    th = rng.uniform(-tb, tb, (count, arm.n))
    d = rng.uniform(0.0, arm.total_length, (count, 1))
    return np.concatenate([th, d], axis=1)


def random_trials(arm: MasrArm, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Table I protocol: (x_goal (count, 3), q0 (count, n+1)).

    q0 is uniform in C_f; x_goal = f(q) of an independent uniform q in C_f, so
    every goal is reachable.
    """
    rng = np.random.default_rng(seed)
    q_goal = random_configs(arm, count, rng)
    q0 = random_configs(arm, count, rng)
    return arm.fk(q_goal), q0


def pose_errors(arm: MasrArm, x_goal: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(dp in m, |dphi| in rad) of the MA pose f(q) against x_goal."""
    x = arm.fk(q)
    dp = np.linalg.norm(x[..., :2] - x_goal[..., :2], axis=-1)
    dphi = np.abs(wrap_angle(x[..., 2] - x_goal[..., 2]))
    return dp, dphi


def evaluate(arm: MasrArm, x_goal: np.ndarray, q0: np.ndarray, q: np.ndarray,
             e_p: float = E_P, e_phi: float = E_PHI) -> dict[str, float]:
    """Table I metrics: mean dp (mm), mean dphi (deg), success rate (%) within (e_p, e_phi)
    (eq. 9), mean action time c(q0 -> q) eq. (8) (s), and mean eq. (12) (s^2)."""
    dp, dphi = pose_errors(arm, x_goal, q)
    ok = (dp <= e_p) & (dphi <= e_phi)
    return {
        "trials": int(dp.size),
        "mean_dp_mm": float(dp.mean() * 1e3),
        "median_dp_mm": float(np.median(dp) * 1e3),
        "mean_dphi_deg": float(np.degrees(dphi).mean()),
        "success_rate": float(ok.mean() * 100),
        "mean_action_time_s": float(arm.action_cost(q0, q).mean()),
        "mean_reg_action_s2": float(arm.reg_action(q0, q).mean()),
    }


# ------------------------------------------------------------------- refinement


def masr_pose_jacobian(arm: MasrArm, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MA pose (B, 3) (phi unwrapped), its Jacobian (B, 3, n+1) w.r.t. q, and j_d (B,).

    Columns of joints past the MA's link are zero (they do not move the MA);
    d's column is (cos phi, sin phi, 0) (phi is piecewise constant in d).
    """
    n = arm.n
    j, d_link = arm.locate(q[:, n])
    cum = np.cumsum(q[:, :n], axis=1)
    u = np.stack([np.cos(cum), np.sin(cum)], axis=-1)  # (B, n, 2)
    joints = np.concatenate([np.zeros((q.shape[0], 1, 2)), np.cumsum(arm.link_lengths[None, :, None] * u, axis=1)], axis=1)
    rows = np.arange(q.shape[0])
    phi = cum[rows, j]
    p = joints[rows, j] + d_link[:, None] * u[rows, j]
    rel = p[:, None, :] - joints[:, :n, :]  # MA relative to each joint
    jac = np.zeros((q.shape[0], 3, n + 1))
    active = np.arange(n)[None, :] <= j[:, None]
    jac[:, 0, :n] = np.where(active, -rel[:, :, 1], 0.0)
    jac[:, 1, :n] = np.where(active, rel[:, :, 0], 0.0)
    jac[:, 2, :n] = active
    jac[:, 0, n] = u[rows, j, 0]
    jac[:, 1, n] = u[rows, j, 1]
    return np.concatenate([p, phi[:, None]], axis=1), jac, j


CONVERGED = 0.01  # score at which DLS stops early: 0.08 mm and 0.04 deg for e_p = 8 mm, e_phi = 4 deg


def _score(arm: MasrArm, xg: np.ndarray, q: np.ndarray, e_p: float, e_phi: float) -> np.ndarray:
    """max(dp / e_p, |dphi| / e_phi): <= 1 exactly when the goal is reached (eq. 9)."""
    dp, dphi = pose_errors(arm, xg, q)
    return np.maximum(dp / e_p, dphi / e_phi)


def _dls(arm: MasrArm, xg: np.ndarray, q: np.ndarray, iters: int, damping: float,
         e_p: float, e_phi: float) -> tuple[np.ndarray, np.ndarray]:
    """DLS on the MA's link (q (B, n+1), already within limits); best iterate and its score."""
    n = arm.n
    q = q.copy()
    j0, _ = arm.locate(q[:, n])
    d_lo = arm.r[j0]
    d_hi = arm.r[j0] + arm.link_lengths[j0]
    d_hi = np.where(j0 < n - 1, np.nextafter(d_hi, d_lo), d_hi)  # stay below the next joint
    w = np.array([1 / e_p, 1 / e_p, 1 / e_phi])
    eye = np.eye(3) * damping**2
    best = q.copy()
    best_score = _score(arm, xg, q, e_p, e_phi)
    for _ in range(iters):
        pose, jac, _ = masr_pose_jacobian(arm, q)
        e = xg - pose
        e[:, 2] = wrap_angle(e[:, 2])
        e, jac = e * w, jac * w[None, :, None]
        jjt = jac @ np.swapaxes(jac, 1, 2) + eye
        step = np.swapaxes(jac, 1, 2) @ np.linalg.solve(jjt, e[:, :, None])
        q = q + step[:, :, 0]
        q[:, :n] = np.clip(q[:, :n], -arm.theta_b, arm.theta_b)
        q[:, n] = np.clip(q[:, n], d_lo, d_hi)  # a joint crossing would make phi jump
        score = _score(arm, xg, q, e_p, e_phi)
        better = score < best_score
        best[better] = q[better]
        best_score = np.where(better, score, best_score)
        if best_score.max() <= CONVERGED:  # all within 1 % of the tolerance: more steps buy nothing
            break
    return best, best_score


def refine(arm: MasrArm, x_goal: Any, q: Any, iters: int = 8, damping: float = 0.05,
           e_p: float = E_P, e_phi: float = E_PHI, q_c: Any = None, neighbours: bool = True) -> np.ndarray:
    """A few damped least-squares steps on theta_1..theta_{j_d} and d (within link j_d).

    x_goal (..., 3), q (..., n+1) -> refined q (..., n+1), within C_f; per query
    the best iterate (score max(dp/e_p, dphi/e_phi)) is returned, never worse
    than q. With `neighbours`, a query still off the goal is tried again with
    the MA moved across the nearer joint onto the adjacent link (same MA point,
    phi then set by that joint): the NN often ends at a link's end when the
    answer is just past it. With q_c given, the joints past the MA's link are
    then set back to their q_c values: they do not move the MA, so the pose is
    unchanged and the action time can only drop (as the paper's GoalFix does,
    section IV-B).
    """
    x_goal = np.asarray(x_goal, dtype=float)
    q = np.asarray(q, dtype=float)
    shape = q.shape
    n = arm.n
    xg = np.broadcast_to(x_goal, (*shape[:-1], 3)).reshape(-1, 3)
    q = q.reshape(-1, n + 1).copy()
    q[:, :n] = np.clip(q[:, :n], -arm.theta_b, arm.theta_b)
    q[:, n] = np.clip(q[:, n], 0.0, arm.total_length)
    best, score = _dls(arm, xg, q, iters, damping, e_p, e_phi)
    if neighbours and iters > 0:
        j, d_link = arm.locate(best[:, n])
        for side in (1, -1):
            miss = np.flatnonzero(score > 1)
            if miss.size == 0:
                break
            jj = j[miss]
            # the joint between link jj and its neighbour on `side`, nearer end first
            far = (d_link[miss] > 0.5 * arm.link_lengths[jj]) == (side == 1)
            k = jj + side
            ok = far & (k >= 0) & (k < n)
            if not ok.any():
                continue
            rows, k = miss[ok], k[ok]
            alt = best[rows].copy()
            joint = np.where(side == 1, arm.r[k], arm.r[k] + arm.link_lengths[k])
            alt[:, n] = joint if side == 1 else np.nextafter(joint, 0.0)
            cand, cand_score = _dls(arm, xg[rows], alt, iters, damping, e_p, e_phi)
            better = cand_score < score[rows]
            best[rows[better]] = cand[better]
            score[rows[better]] = cand_score[better]
    if q_c is not None:
        qc = np.broadcast_to(np.asarray(q_c, dtype=float), shape).reshape(-1, n + 1)
        j, _ = arm.locate(best[:, n])
        distal = np.arange(n)[None, :] > j[:, None]
        best[:, :n] = np.where(distal, qc[:, :n], best[:, :n])
    return best.reshape(shape)


_refine = refine  # solve() has a parameter called refine


# ------------------------------------------------------------------- the solver


@dataclass
class MasrIK:
    """The IK-NN of a model card: solve(x_goal, q_c, refine=False) -> q."""

    arm: MasrArm
    card: dict[str, Any]
    onnx_path: Path
    _session: Any = None

    @classmethod
    def load(cls, card_path: str | Path, int8: bool = False, verify: bool = True) -> "MasrIK":
        """Load the card (JSON) and its float (or int8) ONNX model, checking sha256."""
        card_path = Path(card_path)
        try:
            card = json.loads(card_path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ArmbridgeError(f"cannot read model card {card_path}: {exc}") from None
        arm = MasrArm.from_dict(card["robot"])
        key = "onnx_int8" if int8 else "onnx"
        entry = card["files"][key]
        path = card_path.parent / entry["path"]
        if verify:
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
            if digest != entry["sha256"]:
                raise ArmbridgeError(f"{path}: sha256 {digest[:12]}... does not match its card ({entry['sha256'][:12]}...)")
        return cls(arm, card, path)

    @property
    def session(self) -> Any:
        if self._session is None:
            import onnxruntime as ort  # type: ignore[import-untyped]

            opts = ort.SessionOptions()
            opts.intra_op_num_threads = 1
            opts.inter_op_num_threads = 1
            self._session = ort.InferenceSession(str(self.onnx_path), opts, providers=["CPUExecutionProvider"])
        return self._session

    def predict(self, x_goal: Any, q_c: Any) -> np.ndarray:
        """The network's raw answer (within limits by construction)."""
        n = self.arm.n
        x_goal = np.asarray(x_goal, dtype=float)
        q_c = np.asarray(q_c, dtype=float)
        if x_goal.shape[-1:] != (3,) or q_c.shape[-1:] != (n + 1,):
            raise ArmbridgeError(f"solve needs x_goal (..., 3) and q_c (..., {n + 1}), got {x_goal.shape} and {q_c.shape}")
        batch = np.broadcast_shapes(x_goal.shape[:-1], q_c.shape[:-1])
        inp = np.concatenate([np.broadcast_to(x_goal, (*batch, 3)), np.broadcast_to(q_c, (*batch, n + 1))], axis=-1)
        flat = np.ascontiguousarray(inp.reshape(-1, n + 4), dtype=np.float32)
        name = self.session.get_inputs()[0].name
        out = self.session.run(None, {name: flat})[0].astype(float)
        out[:, :n] = np.clip(out[:, :n], -self.arm.theta_b, self.arm.theta_b)
        out[:, n] = np.clip(out[:, n], 0.0, self.arm.total_length)
        return out.reshape(*batch, n + 1)

    def solve(self, x_goal: Any, q_c: Any, refine: bool = False, iters: int = 8,
              hold_distal: bool = False) -> np.ndarray:
        """A configuration reaching x_goal from q_c with little action time; (..., n+1).

        refine=False: the network alone. refine=True: then `iters` DLS steps and
        the joints past the MA's link back to q_c. hold_distal=True (no DLS):
        only that last, exact step: same pose, never more action time.
        """
        q = self.predict(x_goal, q_c)
        if refine or hold_distal:
            x = np.broadcast_to(np.asarray(x_goal, float), (*q.shape[:-1], 3))
            q = _refine(self.arm, x, q, iters=iters if refine else 0,
                        q_c=np.broadcast_to(np.asarray(q_c, float), q.shape))
        return q
