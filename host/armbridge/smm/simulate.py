"""The real-time fault-tolerant planning simulation of Figs. 15-16 (section VI-B).

One trial: the arm rests at a random configuration q0; at t = 0 a target
appears and the SMM method starts computing. For the method's `latency` the
arm moves toward the target by damped least squares (DLS); when the SMMs
arrive it moves into the SMM bounding box reached soonest and then, inside
that box, to the SMM configuration reached soonest (faulttolerant.approach).
A random joint locks at a random time. The trial succeeds if the tip reaches
the target: before the lock, or after it by the recovery of section III-A
(the healthy joints move to an SMM configuration with the locked value).
Only the latency differs between methods, so a fast method (learned, ~ms)
and a slow one (nullspace, ~s) are compared on the same trials; whichever
SMMs are passed in are used for the planning.

Choices (the paper gives none of these numbers; all are in `Scenario`):

* joint speed limit 1 rad/s on every joint, for the DLS phase and every
  planned motion (a typical speed of a collaborative arm's joints);
* DLS: dq = J^T (J J^T + lambda^2 I)^-1 dx with lambda = 0.05 L, the task
  error dx capped at a tip speed of 0.1 L per s (L: the reach), then dq scaled
  down so that no joint exceeds its speed limit; Euler steps of 10 ms. Crossing
  the workspace by DLS takes about 10 s, as in Fig. 16 where 4.3 s of DLS did
  not bring the 7R to its target;
* random draws (one generator, `seed`): q0 and the target's configuration
  uniform in [-pi, pi)^n (target = its location: always reachable, any arm);
  the locked joint uniform over the joints; the lock time uniform in
  [0, 10 s) (Fig. 15 locks at 5.6 s);
* a joint that locks while the SMMs are still being computed stays where it
  is; the recovery starts when the SMMs arrive;
* success: the tip within 1e-3 L of the target within 30 s; the final
  configuration (arrival or recovery) is corrected by 5 Gauss-Newton steps on
  its free joints (a local IK, as eq. (18) corrects learned SMMs), which only
  removes the error of interpolating between SMM samples;
* no joint limits (the paper's simulation and experiment ignore them).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.robots.dh import DHChain
from armbridge.smm import bbox
from armbridge.smm import faulttolerant as ft
from armbridge.smm.manifold import SmmSet


@dataclass(frozen=True)
class Scenario:
    """The numbers of the simulation (see the module docstring for why)."""

    vmax: float = 1.0  # rad/s, every joint
    dt: float = 0.01  # s, DLS step
    damping: float = 0.05  # lambda of the DLS, fraction of the reach
    tip_speed: float = 0.1  # DLS tip speed cap, fraction of the reach per s
    lock_window: float = 10.0  # s, lock time ~ U[0, lock_window)
    horizon: float = 30.0  # s, the target must be reached by then
    tol: float = 1e-3  # tip tolerance, fraction of the reach
    refine_iters: int = 5  # Gauss-Newton steps on the final configuration

    def __post_init__(self) -> None:
        for name in ("vmax", "dt", "damping", "tip_speed", "lock_window", "horizon", "tol"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ArmbridgeError(f"scenario {name} = {value!r} must be a finite number > 0")
        if not (isinstance(self.refine_iters, int) and self.refine_iters >= 0):
            raise ArmbridgeError(f"scenario refine_iters = {self.refine_iters!r} must be an integer >= 0")


@dataclass(frozen=True)
class Trials:
    """The random draws of a set of trials, shared by every latency compared."""

    q0: np.ndarray  # (T, n) start configurations
    x: np.ndarray  # (T, m) targets
    joint: np.ndarray  # (T,) locked joint, 0-based
    t_lock: np.ndarray  # (T,) lock time, s

    def __len__(self) -> int:
        return int(self.q0.shape[0])


@dataclass(frozen=True)
class Outcome:
    """What happened over the trials at one latency."""

    latency: float
    trials: int
    success: int
    before_lock: int  # reached the target before the joint locked
    recovered: int  # reached it after the lock, by the recovery
    in_box_at_lock: int  # locked while inside the box it was heading for
    out_of_reach: int  # no SMMs for the target (count 0)

    @property
    def rate(self) -> float:
        return self.success / self.trials if self.trials else math.nan

    def to_dict(self) -> dict[str, float | int]:
        return {"latency_s": self.latency, "trials": self.trials, "success": self.success,
                "success_rate": self.rate, "before_lock": self.before_lock, "recovered": self.recovered,
                "in_box_at_lock": self.in_box_at_lock, "out_of_reach": self.out_of_reach}


def draw_trials(arm: DHChain, count: int, seed: int, scenario: Scenario = Scenario()) -> Trials:
    """The random start, target, locked joint and lock time of `count` trials."""
    if not (isinstance(count, int) and count >= 1):
        raise ArmbridgeError(f"trials = {count!r} must be an integer >= 1")
    rng = np.random.default_rng(seed)
    q0 = rng.uniform(-np.pi, np.pi, (count, arm.n))
    x = np.asarray(arm.task(rng.uniform(-np.pi, np.pi, (count, arm.n))))
    joint = rng.integers(0, arm.n, count)
    t_lock = rng.uniform(0.0, scenario.lock_window, count)
    return Trials(q0, x, joint, t_lock)


def dls_path(arm: DHChain, q0: np.ndarray, x: np.ndarray, duration: float, sc: Scenario,
             limits: bbox.Limits | None = None) -> tuple[np.ndarray, np.ndarray]:
    """DLS motion of a batch (B, n) toward x (B, m) for `duration` s under the
    speed limits, held within joint limits if given (the stops):
    (times (K+1,), configurations (K+1, B, n))."""
    steps = max(1, math.ceil(duration / sc.dt - 1e-9))
    h = duration / steps
    lam2 = (sc.damping * arm.reach) ** 2
    cap = sc.tip_speed * arm.reach * h
    q = np.array(q0, dtype=float)
    path = [q.copy()]
    eye = np.eye(arm.m)
    for _ in range(steps):
        e = np.asarray(arm.task_error(q, x))
        norm = np.linalg.norm(e, axis=-1, keepdims=True)
        e = e * np.minimum(1.0, cap / np.maximum(norm, 1e-300))
        jac = np.asarray(arm.jacobian(q))
        dq = np.einsum("bmn,bm->bn", jac, np.linalg.solve(jac @ jac.transpose(0, 2, 1) + lam2 * eye, e[..., None])[..., 0])
        over = np.max(np.abs(dq), axis=-1, keepdims=True) / (sc.vmax * h)
        q = q + dq / np.maximum(1.0, over)
        if limits is not None:
            q = np.clip(q, limits[0], limits[1])
        path.append(q.copy())
    return np.arange(steps + 1) * h, np.stack(path)


def refine(arm: DHChain, q: np.ndarray, x: np.ndarray, free: np.ndarray, iters: int) -> np.ndarray:
    """Gauss-Newton on the free joints (bool mask (n,)) toward x: a local IK that
    removes the interpolation error of a configuration taken from SMM samples."""
    q = np.array(q, dtype=float)
    for _ in range(iters):
        jac = np.asarray(arm.jacobian(q))[:, free]
        q[free] += np.linalg.lstsq(jac, np.asarray(arm.task_error(q, x)), rcond=None)[0]
    return q


def tip_error(arm: DHChain, q: np.ndarray, x: np.ndarray) -> float:
    """Distance from q's location to x as a fraction of the reach."""
    return float(np.linalg.norm(np.asarray(arm.task_error(q, x)))) / arm.reach


def _at(times: np.ndarray, path: np.ndarray, t: float) -> np.ndarray:
    """A configuration of a sampled path (K+1, n) at time t (linear between samples)."""
    return np.array([np.interp(t, times, path[:, j]) for j in range(path.shape[1])])


def run_trial(arm: DHChain, smm: SmmSet, l: int, trials: Trials, latency: float, times: np.ndarray,
              path: np.ndarray, sc: Scenario) -> tuple[str, bool]:
    """One trial on a DLS path already computed: -> (how it ended, in box at the lock).

    how: 'before_lock', 'recovered', 'failed' or 'out_of_reach'.
    """
    x, j, t_lock = trials.x[l], int(trials.joint[l]), float(trials.t_lock[l])
    tol = sc.tol
    if smm.count[l] == 0:
        return "out_of_reach", False
    errs = np.linalg.norm(np.asarray(arm.task_error(path, np.tile(x, (len(path), 1)))), axis=-1)
    arrived = np.nonzero(errs <= tol * arm.reach)[0]
    curves = bbox.smm_curves(smm, l)
    plan = None
    if arrived.size:  # the DLS got there while the SMMs were computed
        t_arrive = float(times[arrived[0]])
    else:
        plan = ft.approach(path[-1], curves, sc.vmax)
        t_arrive = latency + plan.duration
    if t_arrive <= t_lock:
        q_end = path[arrived[0]] if plan is None else plan.inside.goal
        q_end = refine(arm, q_end, x, np.ones(arm.n, bool), sc.refine_iters)
        return ("before_lock" if tip_error(arm, q_end, x) <= tol else "failed"), False
    # The joint locks on the way.
    if plan is None or t_lock < latency:  # (plan None: the DLS arrives later, so still under way)
        q_lock, in_box = _at(times, path, t_lock), False
    else:
        s = t_lock - latency
        q_lock = plan.entry.at(s) if s < plan.entry.duration else plan.inside.at(s - plan.entry.duration)
        in_box = bool(plan.box.contains(q_lock, tol=1e-6))
    move = ft.recover(smm, l, q_lock, j, sc.vmax)
    if move is None:
        return "failed", in_box
    free = np.arange(arm.n) != j
    q_end = refine(arm, move.goal, x, free, sc.refine_iters)
    done = max(t_lock, latency) + move.duration <= sc.horizon
    return ("recovered" if done and tip_error(arm, q_end, x) <= tol else "failed"), in_box


def simulate(arm: DHChain, smm: SmmSet, trials: Trials, latency: float, scenario: Scenario = Scenario()) -> Outcome:
    """The trials at one latency (s) of the SMM method, planned with smm (the
    SMMs of trials.x, one location per trial)."""
    if not (math.isfinite(latency) and latency >= 0):
        raise ArmbridgeError(f"latency {latency!r} s must be a finite number >= 0")
    if len(smm) != len(trials):
        raise ArmbridgeError(f"the SMM set has {len(smm)} locations, the trials have {len(trials)} targets")
    if latency > 0:
        times, paths = dls_path(arm, trials.q0, trials.x, latency, scenario)
    else:
        times, paths = np.zeros(1), trials.q0[None]
    counts = {"before_lock": 0, "recovered": 0, "failed": 0, "out_of_reach": 0}
    in_box = 0
    for l in range(len(trials)):
        how, boxed = run_trial(arm, smm, l, trials, latency, times, paths[:, l], scenario)
        counts[how] += 1
        in_box += boxed
    return Outcome(float(latency), len(trials), counts["before_lock"] + counts["recovered"], counts["before_lock"],
                   counts["recovered"], in_box, counts["out_of_reach"])


def compare(arm: DHChain, latencies: Mapping[str, float], trials: int = 1000, seed: int = 0,
            scenario: Scenario = Scenario(), smm: SmmSet | None = None) -> dict[str, Outcome]:
    """Success rates of several methods, given by their latency (s), on the same
    trials: e.g. {"learned": 0.0014, "nullspace": 4.3}. smm: the SMMs of the
    trials' targets; by default computed by the nullspace method."""
    draws = draw_trials(arm, trials, seed, scenario)
    if smm is None:
        from armbridge.smm import nullspace

        smm = nullspace.compute(arm, draws.x, seed=seed)
    return {name: simulate(arm, smm, draws, float(lat), scenario) for name, lat in latencies.items()}
