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
from armbridge.planning import base
from armbridge.planning.masr.kernels import GOAL, best_goal, extend, nearest_steer
from armbridge.planning.masr.space import STEERS, MasrChecker, MasrSpace  # noqa: F401 - STEERS: plan's choices
from armbridge.planning.tree import Tree
from armbridge.robots.masr_kernels import action_cost  # noqa: F401 - eq. (8), the planner's cost (MasrSpace.cost)

GoalIK = Callable[[np.ndarray, np.ndarray], np.ndarray]

PLANNERS = ("masr-rrt*", "rrt*")
#: Default Steer step delta in s (see module doc).
STEP = 16.0
#: Default number of neighbours N_n (section V-C).
N_NEAR = 7
#: Default p_c for MASR-RRT* and goal bias for RRT* (section V-C).
P_C = 0.6
GOAL_BIAS = 0.1
#: SampleFree's batch: uniform draws mapped onto C_f and checked together.
SAMPLE_BATCH = 1024

_WARM = False  # kernels loaded in this process (see plan)


def sample_free(space: MasrSpace, checker: MasrChecker, rng: np.random.Generator, count: int) -> np.ndarray:
    """SampleFree: count configurations uniform in C_f and collision-free (rejection in batches)."""
    got: list[np.ndarray] = []
    have = 0
    for _ in range(10 * (count // SAMPLE_BATCH + 1) + 100):
        Qs = space.sample(rng, SAMPLE_BATCH)
        ok = checker.valid_rows(Qs)
        got.append(Qs[ok])
        have += int(ok.sum())
        if have >= count:
            return np.concatenate(got)[:count]
    raise ArmbridgeError("SampleFree: almost no collision-free configurations; are the obstacles covering the arm?")


@dataclass
class PlanResult(base.PlanResult):
    """A MASR-RRT* / RRT* run: base.PlanResult plus the planner's own series and counters.

    path: (K, n+1) configurations from the start to a goal node, or None.
    cost: tau of the path (eq. 7, s; inf without a path). best_costs:
    (iterations,) the best tau in G after each iteration (inf before the
    first). goal_nodes: |G|; ik_calls: goal IK calls (Alg. 1 line 7).
    """

    best_costs: np.ndarray = field(default_factory=lambda: np.zeros(0))
    goal_nodes: int = 0
    ik_calls: int = 0

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
            **self.stats,
            **self.settings,
        }


def plan(env: Any, *, planner: str = "masr-rrt*", iterations: int = 1000, goal_ik: Optional[GoalIK] = None,
         p_c: Optional[float] = None, goal_bias: Optional[float] = None, n_near: int = N_NEAR,
         step: float = STEP, steer: str = "linear", sweep_res: Optional[float] = None,
         goal_rect_width: Optional[float] = None,
         seed: Optional[int] = 0, checker: Any = None) -> PlanResult:
    """Run MASR-RRT* or RRT* for `iterations` iterations on an Environment (planning.masr.environment)
    or on a MASR base.Problem (Environment.problem: MasrSpace, MasrChecker, MasrGoal).

    goal_ik(x_goal (3,), q_c (n+1,)) -> q (n+1,) is the IK of Alg. 1 line 7
    (the IK-NN, MasrIK.solve); needed when p_c > 0. p_c defaults to 0.6 for
    masr-rrt* and 0 for rrt*; goal_bias to 0 and 0.1. The baseline needs a
    goal configuration (the environment's goal_q: the problem's goal_states[0]).

    n_near: N_n. step: Steer's delta in s (module doc). With an Environment:
    steer: "linear" (the paper) or "convention" (stop the convention's
    motion after delta s); sweep_res: the checker's sweep resolution in m
    (None: 0.01, 0: the paper's check after each rotation only);
    goal_rect_width: OnGoal's rectangle width (None: e_p); checker: a
    prepared CollisionChecker (or MasrChecker) to reuse. A Problem brings
    them in its space, checker and goal. seed: all random streams
    (SampleFree, p_c and goal-bias draws) derive from it.
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
    if p_c > 0 and goal_ik is None:
        raise ArmbridgeError(f"{planner} with p_c = {p_c} needs a goal IK (goal_ik), e.g. MasrIK.load(card).solve")
    problem = env if isinstance(env, base.Problem) else env.problem(
        sweep_res=sweep_res, steer=steer, goal_rect_width=goal_rect_width, checker=checker)
    space, chk, goal = problem.space, problem.checker, problem.goal
    q_goal = None
    if goal_bias > 0:
        if np.size(problem.goal_states) == 0:
            raise ArmbridgeError("goal biasing needs a goal configuration: the environment has no goal q")
        q_goal = np.ascontiguousarray(np.asarray(problem.goal_states, dtype=float).reshape(-1, space.dim)[0])

    n = space.dim - 1
    mode = space.steer_mode
    theta_b, total = space.theta_b, space.total
    C, E, G = space.cost_args, chk.kernel_args, goal.kernel_args

    global _WARM
    if not _WARM:  # load the numba kernels (compiled or cached) outside the timed loop, once per process
        _WARM = True
        checks = chk.checks
        plan(problem, planner="rrt*", iterations=2, goal_bias=0.0, n_near=n_near, step=step, seed=0)
        best_goal(np.zeros(1), np.zeros(1, dtype=np.int64), 1)
        chk.checks = checks

    t0 = time.perf_counter()
    ss = np.random.SeedSequence(seed)
    rng_q, rng_ik, rng_gb = (np.random.default_rng(s) for s in ss.spawn(3))
    u_ik = rng_ik.random(iterations)
    u_gb = rng_gb.random(iterations)
    samples = sample_free(space, chk, rng_q, iterations)

    cap = iterations + 1
    tree = Tree(problem.start, capacity=cap)  # one node per iteration at most; the kernels never grow it
    Q, parent, tau, kind = tree.Q, tree.parent, tree.cost, tree.kind
    checked = np.zeros(cap, dtype=np.bool_)
    goal_list = np.zeros(cap, dtype=np.int64)
    stack = np.zeros(cap, dtype=np.int64)
    counts = np.zeros(3, dtype=np.int64)
    counts[0] = tree.count
    best_costs = np.full(iterations, np.inf)
    best = np.inf
    if goal.is_satisfied(problem.start):  # already there: the empty path, tau = 0
        kind[0] = GOAL
        goal_list[0] = 0
        counts[1] = 1
        best = 0.0
    ik_calls = 0
    q_new = np.empty(n + 1)
    x_goal = goal.pose.copy()

    for it in range(iterations):
        q_rand = samples[it]
        if goal_bias > 0 and u_gb[it] < goal_bias:
            q_rand = q_goal
        count = int(counts[0])
        i_near = nearest_steer(Q, count, q_rand, C, step, mode, q_new)
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
                        q_new, i_near, int(n_near), E, C, G)
        if status > 0 and counts[1] > 0:
            # a new goal node, or a rewire that lowered some goal node's tau
            g = best_goal(tau, goal_list, int(counts[1]))
            best = tau[g]
        best_costs[it] = best
    elapsed = time.perf_counter() - t0
    tree.count = int(counts[0])
    chk.checks += int(counts[2])

    path = None
    cost = math.inf
    if counts[1] > 0:
        g = best_goal(tau, goal_list, int(counts[1]))
        path = Q[tree.path_to(int(g))].copy()
        cost = space.path_cost(path)
    return PlanResult(
        planner=planner, path=path, cost=cost, best_costs=best_costs, iterations=iterations, time_s=elapsed,
        tree_size=int(counts[0]), goal_nodes=int(counts[1]), ik_calls=ik_calls,
        collision_checks=int(counts[2]), seed=seed,
        settings={"p_c": p_c, "goal_bias": goal_bias, "n_near": int(n_near), "step_s": step, "steer": space.steer,
                  "sweep_res_m": chk.sweep_res, "margin_m": chk.margin, "goal_rect_width_m": 2 * G[4],
                  "d_margin_m": G[7]},
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
