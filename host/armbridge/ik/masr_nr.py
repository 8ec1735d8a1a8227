"""Numeric IK baseline of the masr paper (section V-B, Table I "IK w/ NR").

For each query, m Newton-Raphson solves from random starts are split evenly
over n sub-arms: sub-arm k (k = 1..n) is the first k revolute joints of the
MASR plus a prismatic joint along link k for the MA (d_link in [0, l_k]), so
the MA stands on link k. A converged answer becomes a full configuration
q = (theta_1..theta_k, theta_c,k+1..theta_c,n, r_k + d_link): the joints past
the MA keep their current values (they do not move the MA). Out of the
answers that pass the goal check, the one with the least eq. (12)
regulariser (the paper's "minimum MA action time (12)") is returned; if none
does, the one with the least pose error.

The joint margin (MasrArm.d_margin), as for the IK-NN, for a fair comparison:
the prismatic joint of sub-arm k ranges over link k's margin_range (d_link
at least d_margin from the joints at the link's ends), and the goal check is
MasrArm.reaches: within (e_p, e_phi) for every d within the margin.

Solver: roboticstoolbox-python's `ETS.ik_NR` (the paper's [23], Haviland &
Corke; C implementation, planar mask (x, y, rz), joint limits on), one search
per start. If roboticstoolbox cannot be imported, `backend="auto"` falls back
to our own damped Newton-Raphson with the same protocol (vectorised over the
starts; `method` in `describe()` says which ran).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik.masr_ik import E_P, E_PHI, pose_errors, refine
from armbridge.robots.masr import MasrArm

_MASK = np.array([1.0, 1.0, 0.0, 0.0, 0.0, 1.0])  # x, y and rotation about z


def rtb_available() -> bool:
    try:
        import roboticstoolbox  # noqa: F401
    except Exception:  # noqa: BLE001 - any import failure means fall back
        return False
    return True


@dataclass
class MasrNR:
    """solve(x_goal (..., 3), q_c (..., n+1)) -> q, by m restarts over n sub-arms."""

    arm: MasrArm
    restarts: int = 1000  # m, split evenly over the n sub-arms
    seed: int = 0
    backend: str = "auto"  # "rtb", "own" or "auto"
    ilimit: int = 30
    tol: float = 1e-8
    e_p: float = E_P
    e_phi: float = E_PHI
    _ets: list[Any] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        if self.backend not in ("auto", "rtb", "own"):
            raise ArmbridgeError(f"backend must be auto, rtb or own, got {self.backend!r}")
        if self.backend == "auto":
            self.backend = "rtb" if rtb_available() else "own"
        if self.backend == "rtb":
            self._ets = [self._sub_arm(k) for k in range(1, self.arm.n + 1)]
        self._rng = np.random.default_rng(self.seed)

    @property
    def method(self) -> str:
        return "roboticstoolbox ETS.ik_NR" if self.backend == "rtb" else "own damped NR (fallback)"

    def describe(self) -> dict[str, Any]:
        return {"method": self.method, "restarts_m": self.restarts, "ilimit": self.ilimit,
                "selection": "least eq. (12) among answers within (e_p, e_phi)"}

    def _sub_arm(self, k: int) -> Any:
        from roboticstoolbox import ET

        tb, ls = self.arm.theta_b, self.arm.link_lengths
        ets: Any = ET.Rz(qlim=[-tb[0], tb[0]])
        for j in range(1, k):
            ets = ets * ET.tx(float(ls[j - 1])) * ET.Rz(qlim=[-tb[j], tb[j]])
        lo, hi = self._link_range(k)
        return ets * ET.tx(qlim=[lo, hi])

    def _link_range(self, k: int) -> tuple[float, float]:
        """d_link range of sub-arm k (1-based): link k's margin_range, measured from joint k."""
        lo, hi = (float(v) for v in self.arm.margin_range(k - 1))
        r = float(self.arm.r[k - 1])
        return lo - r, hi - r

    def _starts(self, k: int, count: int) -> np.ndarray:
        """count random sub-arm starts (theta_1..theta_k, d_link)."""
        tb = self.arm.theta_b[:k]
        th = self._rng.uniform(-tb, tb, (count, k))
        d = self._rng.uniform(*self._link_range(k), (count, 1))
        return np.concatenate([th, d], axis=1)

    def _candidates_rtb(self, x_goal: np.ndarray, q_c: np.ndarray) -> np.ndarray:
        c, s = math.cos(x_goal[2]), math.sin(x_goal[2])
        tep = np.array([[c, -s, 0, x_goal[0]], [s, c, 0, x_goal[1]], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        n = self.arm.n
        out = []
        per = max(1, self.restarts // n)
        for k in range(1, n + 1):
            ets = self._ets[k - 1]
            for q0 in self._starts(k, per):
                sol = ets.ik_NR(tep, q0=q0, ilimit=self.ilimit, slimit=1, tol=self.tol, mask=_MASK, joint_limits=True)
                if sol.success:
                    out.append(self._full(k, np.asarray(sol.q, dtype=float), q_c))
        return np.array(out).reshape(-1, n + 1)

    def _candidates_own(self, x_goal: np.ndarray, q_c: np.ndarray) -> np.ndarray:
        n = self.arm.n
        per = max(1, self.restarts // n)
        qs = []
        for k in range(1, n + 1):
            st = self._starts(k, per)
            qs.append(np.stack([self._full(k, s, q_c) for s in st]))
        q = np.concatenate(qs)
        return refine(self.arm, np.broadcast_to(x_goal, (q.shape[0], 3)), q, iters=self.ilimit, damping=1e-3,
                      e_p=self.e_p, e_phi=self.e_phi, neighbours=False)

    def _full(self, k: int, sub: np.ndarray, q_c: np.ndarray) -> np.ndarray:
        n = self.arm.n
        q = np.array(q_c, dtype=float)
        q[:k] = sub[:k]
        lo, hi = self._link_range(k)
        q[n] = self.arm.r[k - 1] + float(np.clip(sub[k], lo, hi))
        return q

    def solve_one(self, x_goal: Any, q_c: Any) -> np.ndarray:
        x_goal = np.asarray(x_goal, dtype=float)
        q_c = np.asarray(q_c, dtype=float)
        cands = self._candidates_rtb(x_goal, q_c) if self.backend == "rtb" else self._candidates_own(x_goal, q_c)
        if cands.shape[0] == 0:
            # nothing converged: the best of a few plain starts, so the answer is still a configuration
            cands = self._candidates_own(x_goal, q_c)
        dp, dphi = pose_errors(self.arm, x_goal, cands)
        ok = self.arm.reaches(cands, x_goal, self.e_p, self.e_phi)
        if ok.any():
            cost = np.where(ok, self.arm.reg_action(q_c, cands), np.inf)
            return cands[int(np.argmin(cost))]
        return cands[int(np.argmin(dp / self.e_p + dphi / self.e_phi))]

    def solve(self, x_goal: Any, q_c: Any) -> np.ndarray:
        """Batched: x_goal (..., 3), q_c (..., n+1) -> q (..., n+1), one query at a time."""
        x_goal = np.asarray(x_goal, dtype=float)
        q_c = np.asarray(q_c, dtype=float)
        n = self.arm.n
        batch = np.broadcast_shapes(x_goal.shape[:-1], q_c.shape[:-1])
        xg = np.broadcast_to(x_goal, (*batch, 3)).reshape(-1, 3)
        qc = np.broadcast_to(q_c, (*batch, n + 1)).reshape(-1, n + 1)
        out = np.stack([self.solve_one(a, b) for a, b in zip(xg, qc)]) if xg.shape[0] else np.zeros((0, n + 1))
        return out.reshape(*batch, n + 1)
