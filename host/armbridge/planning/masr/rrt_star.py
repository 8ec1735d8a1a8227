"""MASR-RRT* and the baseline RRT* (masr paper, section IV, Algorithms 1-2).

One implementation; two switches choose the planner:

* MASR-RRT* (`planner="masr-rrt*"`): with probability p_c, and only when
  v_nearest is neither a goal node (G) nor already tried (the checked set N),
  the new configuration is the IK's answer g(x_goal, v_nearest.q) instead of
  Steer's (Alg. 1 lines 4-8). No other goal bias.
* baseline RRT* (`planner="rrt*"`): p_c = 0 and q_rand is replaced by the goal
  configuration q_goal with probability goal_bias = 0.1 (section V-C).

Everything else is shared and follows Algorithms 1-2:

* SampleFree: uniform in C_f (eq. 5), rejected when in collision; drawn in
  batches ahead of time from one random stream, so two planners with the same
  seed see the same q_rand sequence (the paper's "constant seed").
* Nearest: the node with the least action cost c(v.q -> q_rand), eq. (8).
* Steer: q_new = q_near + s (q_rand - q_near) with s = min(1, delta / |a|_t),
  |a|_t = sum |d theta_i| / theta-dot + |d d| / d-dot: a step of at most
  delta seconds of joint-and-MA time (the paper's maximum step size delta;
  default 16 s). Option steer="convention": where the convention's own
  motion towards q_rand is after delta seconds (not the paper's).
* CollisionFree: collision.edge_hit along the motion convention.
* Near: the N_n nodes not in G with the least c(u.q -> q_new); Connect picks
  the parent with the least u.tau + c(u.q -> q_new) whose edge is free;
  RewireTree re-parents u in U \\ {parent} when v_new.tau + c(v_new.q -> u.q)
  < u.tau and the edge v_new -> u is free, and pushes the saving down u's
  subtree so every tau stays the cost of its path from the root, eq. (7).
* OnGoal: link i is a rectangle of width e_p along the link (the goal point
  within e_p / 2 of the link's centre line, its projection on the link) and,
  for eq. (9), the link's heading within e_phi of phi_goal; and the goal
  check holds over the joint margin (MasrArm.d_margin) at GoalFix's d.
* GoalFix: the MA moves to the goal's projection on that link, moved to at
  least d_margin from the link's joints (the MA's localisation bound); joints beyond
  the MA (r_j > d) keep their parent's angles. The fixed edge is checked
  again; if it collides, only d is fixed; if that collides too, the node is
  an ordinary node. Fixed nodes join G.
* Best_path: the node of G with the least tau.

The tree is planning.tree's Tree with capacity N_c + 1 (goal nodes are
Tree.kind GOAL); the per-iteration work runs in numba on its arrays
(kernels.py: `nearest_steer`, `extend`); Python does the IK call and bookkeeping.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.planning.masr.kernels import GOAL, best_goal, extend, nearest_steer, sample_free
from armbridge.planning.tree import Tree
from armbridge.robots.masr_kernels import action_cost  # noqa: F401 - eq. (8), the planner's cost

GoalIK = Callable[[np.ndarray, np.ndarray], np.ndarray]

PLANNERS = ("masr-rrt*", "rrt*")
STEERS = ("linear", "convention")
#: Default Steer step delta in s (see module doc).
STEP = 16.0
#: Default number of neighbours N_n (section V-C).
N_NEAR = 7
#: Default p_c for MASR-RRT* and goal bias for RRT* (section V-C).
P_C = 0.6
GOAL_BIAS = 0.1

_WARM = False  # kernels loaded in this process (see plan)


# --------------------------------------------------------------------- Python
def _draw_free(rng: np.random.Generator, count: int, lengths, theta_b, total, verts, starts, bbox, r2) -> np.ndarray:
    """SampleFree: count configurations uniform in C_f and collision-free (rejection in batches)."""
    n = lengths.size
    got: list[np.ndarray] = []
    have = 0
    for _ in range(10 * (count // 1024 + 1) + 100):
        Qs, ok = sample_free(rng.random((1024, n + 1)), lengths, theta_b, total,
                              verts, starts, bbox, r2)
        got.append(Qs[ok])
        have += int(ok.sum())
        if have >= count:
            return np.concatenate(got)[:count]
    raise ArmbridgeError("SampleFree: almost no collision-free configurations; are the obstacles covering the arm?")


@dataclass
class PlanResult:
    """What a planner run gives back.

    path: (K, n+1) configurations from the start to a goal node, or None.
    cost: tau of the path (eq. 7, s; inf without a path). best_costs:
    (iterations,) the best tau in G after each iteration (inf before the first).
    """

    planner: str
    path: Optional[np.ndarray]
    cost: float
    best_costs: np.ndarray
    iterations: int
    time_s: float
    tree_size: int
    goal_nodes: int
    ik_calls: int
    collision_checks: int
    seed: Optional[int]
    settings: dict = field(default_factory=dict)

    @property
    def success(self) -> bool:
        return self.path is not None

    @property
    def first_solution_iteration(self) -> Optional[int]:
        """1-based iteration at which the first path appeared, or None."""
        hit = np.flatnonzero(np.isfinite(self.best_costs))
        return int(hit[0]) + 1 if hit.size else None

    def summary(self) -> dict[str, Any]:
        return {
            "planner": self.planner,
            "success": self.success,
            "cost_s": self.cost if self.success else None,
            "waypoints": 0 if self.path is None else int(self.path.shape[0]),
            "iterations": self.iterations,
            "first_solution_iteration": self.first_solution_iteration,
            "time_s": self.time_s,
            "tree_size": self.tree_size,
            "goal_nodes": self.goal_nodes,
            "ik_calls": self.ik_calls,
            "collision_checks": self.collision_checks,
            "seed": self.seed,
            **self.settings,
        }


def plan(env: Any, *, planner: str = "masr-rrt*", iterations: int = 1000, goal_ik: Optional[GoalIK] = None,
         p_c: Optional[float] = None, goal_bias: Optional[float] = None, n_near: int = N_NEAR,
         step: float = STEP, steer: str = "linear", sweep_res: Optional[float] = None,
         goal_rect_width: Optional[float] = None,
         seed: Optional[int] = 0, checker: Any = None) -> PlanResult:
    """Run MASR-RRT* or RRT* on an Environment (planning.masr.environment) for `iterations` iterations.

    goal_ik(x_goal (3,), q_c (n+1,)) -> q (n+1,) is the IK of Alg. 1 line 7
    (the IK-NN, MasrIK.solve); needed when p_c > 0. p_c defaults to 0.6 for
    masr-rrt* and 0 for rrt*; goal_bias to 0 and 0.1. The baseline needs the
    environment's goal configuration (env.goal_q).

    n_near: N_n. step: Steer's delta in s (module doc). steer: "linear" (the
    paper) or "convention" (stop the convention's motion after delta s).
    sweep_res: the checker's sweep resolution in m (None: 0.01, 0: the paper's
    check after each rotation only). goal_rect_width: OnGoal's rectangle
    width (None: e_p). seed: all random streams (SampleFree, p_c and goal-bias
    draws) derive from it. checker: a prepared CollisionChecker to reuse.
    """
    if planner not in PLANNERS:
        raise ArmbridgeError(f"unknown planner {planner!r} (known: {', '.join(PLANNERS)})")
    masr = planner == "masr-rrt*"
    p_c = (P_C if masr else 0.0) if p_c is None else float(p_c)
    goal_bias = (0.0 if masr else GOAL_BIAS) if goal_bias is None else float(goal_bias)
    for name, v in (("p_c", p_c), ("goal_bias", goal_bias)):
        if not 0.0 <= v <= 1.0:
            raise ArmbridgeError(f"{name} must be in [0, 1], got {v}")
    if not isinstance(iterations, (int, np.integer)) or iterations < 1:
        raise ArmbridgeError(f"iterations must be a positive integer, got {iterations!r}")
    if not isinstance(n_near, (int, np.integer)) or n_near < 1:
        raise ArmbridgeError(f"n_near must be a positive integer, got {n_near!r}")
    if not (step > 0 and math.isfinite(step)):
        raise ArmbridgeError(f"step must be > 0 s, got {step}")
    if steer not in STEERS:
        raise ArmbridgeError(f"unknown steer {steer!r} (known: {', '.join(STEERS)})")
    mode = STEERS.index(steer)
    if p_c > 0 and goal_ik is None:
        raise ArmbridgeError(f"{planner} with p_c = {p_c} needs a goal IK (goal_ik), e.g. MasrIK.load(card).solve")
    q_goal = None
    if goal_bias > 0:
        q_goal = env.goal_q
        if q_goal is None:
            raise ArmbridgeError("goal biasing needs a goal configuration: the environment has no goal q")
        q_goal = np.ascontiguousarray(q_goal, dtype=float)

    arm = env.arm
    chk = checker if checker is not None else env.checker(sweep_res=sweep_res)
    n = arm.n
    lengths, rj, reach, theta_b = chk.lengths, chk.rj, chk.reach, chk.theta_b
    total = float(arm.total_length)
    verts, starts, bbox, r2, sres = chk.verts, chk.starts, chk.bbox, chk.r2, chk.sweep_res
    inv_ms, inv_js = 1.0 / arm.ma_speed, 1.0 / arm.joint_speed
    goal = np.ascontiguousarray(env.goal_pose, dtype=float)
    half_w = 0.5 * (env.e_p if goal_rect_width is None else float(goal_rect_width))
    e_p, e_phi = float(env.e_p), float(env.e_phi)
    dm = float(arm.d_margin)

    global _WARM
    if not _WARM:  # load the numba kernels (compiled or cached) outside the timed loop, once per process
        _WARM = True
        plan(env, planner="rrt*", iterations=2, goal_bias=0.0, n_near=n_near, step=step, steer=steer,
             checker=chk, seed=0)
        best_goal(np.zeros(1), np.zeros(1, dtype=np.int64), 1)

    t0 = time.perf_counter()
    ss = np.random.SeedSequence(seed)
    rng_q, rng_ik, rng_gb = (np.random.default_rng(s) for s in ss.spawn(3))
    u_ik = rng_ik.random(iterations)
    u_gb = rng_gb.random(iterations)
    samples = _draw_free(rng_q, iterations, lengths, theta_b, total, verts, starts, bbox, r2)

    cap = iterations + 1
    tree = Tree(env.start, capacity=cap)  # one node per iteration at most; the kernels never grow it
    Q, parent, tau, kind = tree.Q, tree.parent, tree.cost, tree.kind
    checked = np.zeros(cap, dtype=np.bool_)
    goal_list = np.zeros(cap, dtype=np.int64)
    stack = np.zeros(cap, dtype=np.int64)
    counts = np.zeros(3, dtype=np.int64)
    counts[0] = tree.count
    best_costs = np.full(iterations, np.inf)
    best = np.inf
    if bool(env.in_goal(env.start)):  # already there: the empty path, tau = 0
        kind[0] = GOAL
        goal_list[0] = 0
        counts[1] = 1
        best = 0.0
    ik_calls = 0
    q_new = np.empty(n + 1)
    x_goal = goal.copy()

    for it in range(iterations):
        q_rand = samples[it]
        if goal_bias > 0 and u_gb[it] < goal_bias:
            q_rand = q_goal
        count = int(counts[0])
        i_near = nearest_steer(Q, count, q_rand, rj, inv_ms, inv_js, step, mode, q_new)
        if u_ik[it] < p_c and kind[i_near] != GOAL and not checked[i_near]:
            checked[i_near] = True
            ik_calls += 1
            assert goal_ik is not None  # p_c > 0 needs one (checked above)
            q_ik = np.asarray(goal_ik(x_goal, Q[i_near].copy()), dtype=float).reshape(n + 1)
            if not np.all(np.isfinite(q_ik)):
                raise ArmbridgeError("goal IK returned a non-finite configuration")
            q_new[:n] = np.clip(q_ik[:n], -theta_b, theta_b)
            q_new[n] = min(max(q_ik[n], 0.0), total)
        status = extend(Q, parent, tau, tree.first_child, tree.next_sib, kind, goal_list, counts, stack,
                         q_new, i_near, int(n_near), lengths, rj, reach, theta_b, total, verts, starts, bbox,
                         r2, sres, inv_ms, inv_js, goal, half_w, e_p, e_phi, dm)
        if status > 0 and counts[1] > 0:
            # a new goal node, or a rewire that lowered some goal node's tau
            g = best_goal(tau, goal_list, int(counts[1]))
            best = tau[g]
        best_costs[it] = best
    elapsed = time.perf_counter() - t0

    path = None
    cost = math.inf
    tree.count = int(counts[0])
    if counts[1] > 0:
        g = best_goal(tau, goal_list, int(counts[1]))
        path = Q[tree.path_to(int(g))].copy()
        cost = float(arm.path_time(path)) if path.shape[0] > 1 else 0.0
    return PlanResult(
        planner=planner, path=path, cost=cost, best_costs=best_costs, iterations=iterations, time_s=elapsed,
        tree_size=int(counts[0]), goal_nodes=int(counts[1]), ik_calls=ik_calls,
        collision_checks=int(counts[2]), seed=seed,
        settings={"p_c": p_c, "goal_bias": goal_bias, "n_near": int(n_near), "step_s": step, "steer": steer,
                  "sweep_res_m": sres, "margin_m": chk.margin, "goal_rect_width_m": 2 * half_w,
                  "d_margin_m": dm},
    )


# ------------------------------------------------------------------ benchmarks
def percentile_success(costs: dict[str, np.ndarray], levels: tuple[float, ...] = (0.15, 0.25)) -> dict:
    """Fig. 7's measure: the share of trials whose best cost is below each level of the cost range.

    costs: planner -> (trials, iterations) best costs on one environment. The
    range [min, max] is over every finite cost recorded in all trials of all
    planners (section V-C); a trial counts at iteration k when its cost then
    is <= min + level (max - min). Returns planner -> {level: (iterations,) rates}.
    """
    seen = np.concatenate([c[np.isfinite(c)] for c in costs.values()])
    if seen.size == 0:
        return {p: {lv: np.zeros(c.shape[1]) for lv in levels} for p, c in costs.items()}
    lo, hi = float(seen.min()), float(seen.max())
    return {p: {lv: np.mean(c <= lo + lv * (hi - lo), axis=0) for lv in levels} for p, c in costs.items()}
