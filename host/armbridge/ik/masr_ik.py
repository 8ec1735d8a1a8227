"""MASR inverse kinematics behind one interface: the shipped IK-NN in onnxruntime,
optionally refined by damped least squares, plus the evaluation protocol.

    ik = MasrIK.load("models/onnx/masr5-iknn-card.json")
    q = ik.solve(x_goal, q_c)               # NN alone, (..., 3) + (..., n+1) -> (..., n+1)
    q = ik.solve(x_goal, q_c, refine=True)  # NN + a few DLS steps

Refinement (armbridge.ik.masr_dls.refine, on the damped least-squares step
the numeric IK uses too) keeps the link the NN put the MA on (j_d) and
moves only what can move the MA on that link: the joints
theta_1..theta_{j_d} and the MA position d within the link (d_link in
[0, l_{j_d}]). Each step solves the 3-row damped least-squares system on the
error measured in goal-tolerance units (dp / e_p, dphi / e_phi), then clips
to the joint limits; the best iterate per query is kept, so refinement never
returns a worse pose than the NN's. Then the joints past the MA's link go
back to their current values q_c (they do not move the MA; the action time
can only drop), and joints whose turn the others can make up are turned back
to q_c too (see `refine`).

Every answer holds the robot's joint margin (MasrArm.d_margin, 5 mm: the MA's
localisation bound): d stays that far from every joint it would cross, and
success is the goal check over the margin (MasrArm.reaches: eq. (9) for every
d' in [d - m, d + m]). Queries the refinement still misses (about 2 % of
random goals, mostly where the margin pushes the answer off the link the
network chose) go to `fallback`, a multi-start refinement over every link.

numpy, numba and onnxruntime: no torch at run time.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik.masr_dls import E_P, E_PHI, SNAP_MARGIN, refine, span_scores
from armbridge.robots.masr import MasrArm
from armbridge.geometry import wrap_angle

__all__ = ["E_P", "E_PHI", "SNAP_MARGIN", "MasrIK", "evaluate", "fallback", "pose_errors", "random_configs",
           "random_trials", "refine", "span_scores"]


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
             e_p: float = E_P, e_phi: float = E_PHI, margin: Any = None) -> dict[str, float]:
    """Table I metrics: mean dp (mm), mean dphi (deg) at d, success rate (%), mean action
    time c(q0 -> q) eq. (8) (s), and mean eq. (12) (s^2).

    Success is the goal check (MasrArm.reaches): d at least `margin` (default
    arm.d_margin) from every joint r_2..r_n and the pose within (e_p, e_phi)
    (eq. 9) for every d' within the margin; margin = 0 is the paper's eq. (9)
    at d alone ("success_at_d" reports it beside). "holds_margin" is the share (%)
    of answers clear of the joints.
    """
    dp, dphi = pose_errors(arm, x_goal, q)
    m = arm.d_margin if margin is None else float(margin)
    ok = arm.reaches(q, x_goal, e_p, e_phi, m)
    return {
        "trials": int(dp.size),
        "mean_dp_mm": float(dp.mean() * 1e3),
        "median_dp_mm": float(np.median(dp) * 1e3),
        "mean_dphi_deg": float(np.degrees(dphi).mean()),
        "success_rate": float(ok.mean() * 100),
        "success_at_d": float(((dp <= e_p) & (dphi <= e_phi)).mean() * 100),
        "margin_mm": m * 1e3,
        "holds_margin": float(arm.holds_margin(q[..., -1], m).mean() * 100),
        "mean_action_time_s": float(arm.action_cost(q0, q).mean()),
        "mean_reg_action_s2": float(arm.reg_action(q0, q).mean()),
    }


_refine = refine  # solve() has a parameter called refine

#: Fallback (MasrIK.solve): random starts per link in its second round; DLS steps per start.
FALLBACK_STARTS = 5
FALLBACK_ITERS = 30


def fallback(arm: MasrArm, x_goal: np.ndarray, q_nn: np.ndarray, q_c: np.ndarray, snap_margin: float,
             starts: int = FALLBACK_STARTS, iters: int = FALLBACK_ITERS, seed: int = 0) -> np.ndarray:
    """Multi-start refinement for queries the network and its refinement miss: (B, 3), (B, n+1) x2 -> (B, n+1).

    Two rounds, each refining every start (`iters` DLS steps, distal joints
    held, sparsify within snap_margin): first, per link k, the network's
    angles with d at the low end, middle and high end of k's margin_range
    (mostly a goal the margin pushes onto the next link); then, for the
    queries still missed, `starts` random angle sets per link with d uniform
    in its range. The answer is the cheapest (eq. 8) that passes the goal
    check, else the least span score. Deterministic (seed).
    """
    rng = np.random.default_rng(seed)
    n, B = arm.n, x_goal.shape[0]
    tb = arm.theta_b
    ranges = [tuple(float(v) for v in arm.margin_range(k)) for k in range(n)]
    best = q_nn.copy()
    key = np.full(B, np.inf)
    todo = np.arange(B)
    for round_ in range(2):
        S: list[np.ndarray] = []
        for lo, hi in ranges:
            if round_ == 0:
                for d in (lo, 0.5 * (lo + hi), hi):
                    s = q_nn[todo].copy()
                    s[:, n] = d
                    S.append(s[:, None])
            else:
                S.append(np.concatenate([rng.uniform(-tb, tb, (todo.size, starts, n)),
                                         rng.uniform(lo, hi, (todo.size, starts, 1))], axis=2))
        st = np.concatenate(S, axis=1)
        qc = np.broadcast_to(q_c[todo][:, None], st.shape)
        q = refine(arm, x_goal[todo][:, None], st, iters=iters, q_c=qc, snap_margin=snap_margin)
        score = span_scores(arm, x_goal[todo][:, None], q)
        k = np.where(score <= 1.0, arm.action_cost(qc, q), 1e9 + score)
        i = np.argmin(k, axis=1)
        better = k[np.arange(todo.size), i] < key[todo]
        best[todo[better]] = q[np.arange(todo.size), i][better]
        key[todo[better]] = k[np.arange(todo.size), i][better]
        todo = todo[key[todo] >= 1e9]
        if todo.size == 0:
            break
    return best


# ------------------------------------------------------------------- the solver


@dataclass
class MasrIK:
    """The IK-NN of a model card: solve(x_goal, q_c, refine=False) -> q."""

    arm: MasrArm
    card: dict[str, Any]
    onnx_path: Path
    _session: Any = None
    #: queries solve() handed to the fallback, and how many of them it then solved
    fallbacks: int = 0
    fallbacks_solved: int = 0

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
              hold_distal: bool = False, sparsify: bool = True, use_fallback: bool = True) -> np.ndarray:
        """A configuration reaching x_goal from q_c with little action time; (..., n+1).

        Every answer holds the joint margin (arm.d_margin): the network's d is
        moved onto its link's margin_range. refine=False: the network alone.
        refine=True: then `iters` DLS steps, the joints past the MA's link back
        to q_c and, with `sparsify`, joints turned back to q_c where the others
        make up (see `refine`); with `use_fallback`, queries that still miss the
        goal check go to `fallback` (multi-start refinement; counted in
        self.fallbacks). hold_distal=True (no DLS): only the exact step: same
        pose, never more action time.
        """
        q = self.predict(x_goal, q_c)
        x = np.broadcast_to(np.asarray(x_goal, float), (*q.shape[:-1], 3))
        if not (refine or hold_distal):
            return _refine(self.arm, x, q, iters=0)
        qc = np.broadcast_to(np.asarray(q_c, float), q.shape)
        snap = SNAP_MARGIN if sparsify else 0.0
        out, score = _refine(self.arm, x, q, iters=iters if refine else 0, q_c=qc, snap_margin=snap,
                             with_score=True)
        if refine and use_fallback:
            miss = score > 1.0
            if miss.any():
                fix = fallback(self.arm, x[miss], q[miss], qc[miss], snap)
                out[miss] = fix
                self.fallbacks += int(miss.sum())
                self.fallbacks_solved += int((span_scores(self.arm, x[miss], fix) <= 1.0).sum())
        return out
