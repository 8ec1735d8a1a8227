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

Tree arrays are numpy with capacity N_c + 1, the per-iteration work runs in
numba (`_nearest_steer`, `_extend`); Python does the IK call and bookkeeping.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np
from numba import njit

from armbridge.errors import ArmbridgeError
from armbridge.planning.collision import config_hit, edge_hit, rotation_order
from armbridge.robots.masr import POS_TOL
from armbridge.robots.masr_kernels import action_cost, margin_range, wrap

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

_EPS = 1e-9  # s: a rewire must save more than this
_WARM = False  # kernels loaded in this process (see plan)


# --------------------------------------------------------------------- kernels
@njit(cache=True)
def _steer_linear(qa, qb, inv_ms, inv_js, delta, out):
    """The paper's Steer: q_a + s (q_b - q_a), s = min(1, delta / |q_b - q_a|_t)."""
    n = qa.size - 1
    norm = abs(qb[n] - qa[n]) * inv_ms
    for j in range(n):
        norm += abs(qb[j] - qa[j]) * inv_js
    if norm <= delta:
        for j in range(n + 1):
            out[j] = qb[j]
        return
    s = delta / norm
    for j in range(n + 1):
        out[j] = qa[j] + s * (qb[j] - qa[j])


@njit(cache=True)
def _steer_convention(qa, qb, rj, inv_ms, inv_js, delta, out):
    """Steer along the motion convention: where the MA's action q_a -> q_b is after delta seconds."""
    n = rj.size
    for j in range(n + 1):
        out[j] = qa[j]
    order = np.empty(n, dtype=np.int64)
    m = rotation_order(qa, qb, rj, order)
    t = 0.0
    d = qa[n]
    for k in range(m + 1):
        target = qb[n] if k == m else rj[order[k]]
        if k < m and abs(target - qa[n]) <= POS_TOL:
            target = d  # the joint under the MA
        move = abs(target - d) * inv_ms
        if t + move >= delta:
            out[n] = d + (target - d) * ((delta - t) / move)
            return
        t += move
        d = target
        out[n] = d
        if k == m:
            break
        j = order[k]
        rot = abs(qb[j] - qa[j]) * inv_js
        if t + rot >= delta:
            out[j] = qa[j] + (qb[j] - qa[j]) * ((delta - t) / rot)
            return
        t += rot
        out[j] = qb[j]
    for j in range(n + 1):
        out[j] = qb[j]


@njit(cache=True)
def _nearest_steer(Q, count, q_rand, rj, inv_ms, inv_js, delta, mode, out):
    """Nearest by eq. (8); writes Steer(v_nearest, q_rand) into out; returns the nearest index."""
    best = np.inf
    bi = 0
    for i in range(count):
        c = action_cost(Q[i], q_rand, rj, inv_ms, inv_js)
        if c < best:
            best = c
            bi = i
    if mode == 0:
        _steer_linear(Q[bi], q_rand, inv_ms, inv_js, delta, out)
    else:
        _steer_convention(Q[bi], q_rand, rj, inv_ms, inv_js, delta, out)
    return bi


@njit(cache=True)
def _on_goal(q, lengths, rj, total, goal, half_w, e_p, e_phi, dm, cand_d, cand_link):
    """OnGoal: links whose rectangle holds the goal point and whose heading is within e_phi, and
    where the goal check holds over the joint margin.

    For each such link, GoalFix's MA position is the goal's projection moved
    into the link's margin_range (at least dm from the joints at its ends,
    masr_kernels.margin_range); the link counts only if the goal is within
    e_p of the MA for every d within dm of it: on one link the heading is
    constant and the point moves linearly, so the two ends of [d - dm, d + dm]
    (clipped to the arm) decide, exactly. Writes each such d and link into
    cand_d / cand_link; returns how many.
    """
    n = lengths.size
    th = 0.0
    x = 0.0
    y = 0.0
    m = 0
    for i in range(n):
        th += q[i]
        c = math.cos(th)
        s = math.sin(th)
        if abs(wrap(th - goal[2])) <= e_phi:
            gx = goal[0] - x
            gy = goal[1] - y
            t = gx * c + gy * s
            perp = abs(gx * s - gy * c)
            if t >= 0.0 and t <= lengths[i] and perp <= half_w:
                lo, hi = margin_range(i, lengths, rj, total, dm)
                if i < n - 1:
                    hi = min(hi, rj[i] + lengths[i] - 1e-7)  # stay on link i, not on joint i+1
                d = min(max(rj[i] + t, lo), hi)
                ok = True
                for end in (max(d - dm, 0.0), min(d + dm, total)):
                    if math.hypot(rj[i] + t - end, perp) > e_p:
                        ok = False
                if ok:
                    cand_d[m] = d
                    cand_link[m] = i
                    m += 1
        x += lengths[i] * c
        y += lengths[i] * s
    return m


@njit(cache=True)
def _unlink(first_child, next_sib, p, u):
    c = first_child[p]
    if c == u:
        first_child[p] = next_sib[u]
        return
    while c >= 0:
        if next_sib[c] == u:
            next_sib[c] = next_sib[u]
            return
        c = next_sib[c]


@njit(cache=True)
def _link(first_child, next_sib, p, u):
    next_sib[u] = first_child[p]
    first_child[p] = u


@njit(cache=True)
def _shift_subtree(tau, first_child, next_sib, u, delta, stack):
    top = 0
    stack[0] = u
    top = 1
    while top > 0:
        top -= 1
        v = stack[top]
        tau[v] += delta
        c = first_child[v]
        while c >= 0:
            stack[top] = c
            top += 1
            c = next_sib[c]


@njit(cache=True)
def _extend(Q, parent, tau, first_child, next_sib, is_goal, goal_list, counts, stack,
            q_new, i_near, n_near,
            lengths, rj, reach, theta_b, total, verts, starts, bbox, r2, sweep_res,
            inv_ms, inv_js, goal, half_w, e_p, e_phi, dm):
    """Alg. 1 lines 11-19 for one candidate q_new from v_nearest = i_near.

    counts = [tree size, |G|, collision checks]. Returns 0 (edge not free,
    nothing added), 1 (added) or 2 (added to G).
    """
    N = counts[0]
    n = lengths.size
    counts[2] += 1
    if edge_hit(Q[i_near], q_new, lengths, rj, reach, theta_b, total, verts, starts, bbox, r2,
                sweep_res, False) != -1:
        return 0
    tau_min = tau[i_near] + action_cost(Q[i_near], q_new, rj, inv_ms, inv_js)
    par = i_near

    # Near: the n_near nodes not in G with least c(u -> q_new), kept sorted
    near = np.full(n_near, -1, dtype=np.int64)
    near_c = np.full(n_near, np.inf)
    k_near = 0
    for i in range(N):
        if is_goal[i]:
            continue
        c = action_cost(Q[i], q_new, rj, inv_ms, inv_js)
        if k_near < n_near or c < near_c[k_near - 1]:
            pos = k_near if k_near < n_near else n_near - 1
            while pos > 0 and near_c[pos - 1] > c:
                near_c[pos] = near_c[pos - 1]
                near[pos] = near[pos - 1]
                pos -= 1
            near_c[pos] = c
            near[pos] = i
            if k_near < n_near:
                k_near += 1

    # Connect (Alg. 2): candidates by u.tau + c, cheapest first; the first free one wins
    cand_tau = np.empty(k_near)
    for a in range(k_near):
        cand_tau[a] = tau[near[a]] + near_c[a]
    idx = np.argsort(cand_tau)
    for a in range(k_near):
        u = near[idx[a]]
        if not cand_tau[idx[a]] < tau_min:
            break
        if u == i_near:
            continue
        counts[2] += 1
        if edge_hit(Q[u], q_new, lengths, rj, reach, theta_b, total, verts, starts, bbox, r2,
                    sweep_res, False) == -1:
            par = u
            tau_min = cand_tau[idx[a]]
            break

    # add v_new
    v = N
    for j in range(n + 1):
        Q[v, j] = q_new[j]
    parent[v] = par
    tau[v] = tau_min
    first_child[v] = -1
    next_sib[v] = -1
    is_goal[v] = False
    _link(first_child, next_sib, par, v)
    counts[0] = N + 1

    # OnGoal / GoalFix
    cand_d = np.empty(n)
    cand_link = np.empty(n, dtype=np.int64)
    m = _on_goal(q_new, lengths, rj, total, goal, half_w, e_p, e_phi, dm, cand_d, cand_link)
    if m > 0:
        fixes = np.empty((2 * m, n + 1))
        fcost = np.empty(2 * m)
        for a in range(m):
            for b in range(2):  # b = 0: d and distal joints; b = 1: d only
                f = 2 * a + b
                for j in range(n + 1):
                    fixes[f, j] = q_new[j]
                fixes[f, n] = cand_d[a]
                if b == 0:
                    for j in range(n):
                        if rj[j] > cand_d[a]:
                            fixes[f, j] = Q[par, j]
                fcost[f] = action_cost(Q[par], fixes[f], rj, inv_ms, inv_js)
        order = np.argsort(fcost)
        for a in range(2 * m):
            f = order[a]
            counts[2] += 1
            if edge_hit(Q[par], fixes[f], lengths, rj, reach, theta_b, total, verts, starts, bbox, r2,
                        sweep_res, False) == -1:
                for j in range(n + 1):
                    Q[v, j] = fixes[f, j]
                tau[v] = tau[par] + fcost[f]
                is_goal[v] = True
                goal_list[counts[1]] = v
                counts[1] += 1
                return 2

    # RewireTree(U \ {parent}, v_new)
    for a in range(k_near):
        u = near[a]
        if u == par:
            continue
        c = action_cost(Q[v], Q[u], rj, inv_ms, inv_js)
        if tau[v] + c < tau[u] - _EPS:
            counts[2] += 1
            if edge_hit(Q[v], Q[u], lengths, rj, reach, theta_b, total, verts, starts, bbox, r2,
                        sweep_res, False) == -1:
                _unlink(first_child, next_sib, parent[u], u)
                parent[u] = v
                _link(first_child, next_sib, v, u)
                _shift_subtree(tau, first_child, next_sib, u, tau[v] + c - tau[u], stack)
    return 1


@njit(cache=True)
def _best_goal(tau, goal_list, n_goal):
    best = np.inf
    bi = -1
    for a in range(n_goal):
        g = goal_list[a]
        if tau[g] < best:
            best = tau[g]
            bi = g
    return bi


@njit(cache=True)
def _sample_free(U, lengths, theta_b, total, verts, starts, bbox, r2):
    """Map uniform numbers U (B, n+1) in [0, 1) to C_f and flag the collision-free rows."""
    n = lengths.size
    B = U.shape[0]
    Q = np.empty((B, n + 1))
    ok = np.empty(B, dtype=np.bool_)
    pts = np.empty((n + 1, 2))
    for b in range(B):
        for j in range(n):
            Q[b, j] = (2.0 * U[b, j] - 1.0) * theta_b[j]
        Q[b, n] = U[b, n] * total
        ok[b] = config_hit(Q[b], lengths, verts, starts, bbox, r2, pts) < 0
    return Q, ok


# --------------------------------------------------------------------- Python
def _draw_free(rng: np.random.Generator, count: int, lengths, theta_b, total, verts, starts, bbox, r2) -> np.ndarray:
    """SampleFree: count configurations uniform in C_f and collision-free (rejection in batches)."""
    n = lengths.size
    got: list[np.ndarray] = []
    have = 0
    for _ in range(10 * (count // 1024 + 1) + 100):
        Qs, ok = _sample_free(rng.random((1024, n + 1)), lengths, theta_b, total,
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
    """Run MASR-RRT* or RRT* on an Environment (planning.environment) for `iterations` iterations.

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
        _best_goal(np.zeros(1), np.zeros(1, dtype=np.int64), 1)

    t0 = time.perf_counter()
    ss = np.random.SeedSequence(seed)
    rng_q, rng_ik, rng_gb = (np.random.default_rng(s) for s in ss.spawn(3))
    u_ik = rng_ik.random(iterations)
    u_gb = rng_gb.random(iterations)
    samples = _draw_free(rng_q, iterations, lengths, theta_b, total, verts, starts, bbox, r2)

    cap = iterations + 1
    Q = np.empty((cap, n + 1))
    parent = np.full(cap, -1, dtype=np.int64)
    tau = np.zeros(cap)
    first_child = np.full(cap, -1, dtype=np.int64)
    next_sib = np.full(cap, -1, dtype=np.int64)
    is_goal = np.zeros(cap, dtype=np.bool_)
    checked = np.zeros(cap, dtype=np.bool_)
    goal_list = np.zeros(cap, dtype=np.int64)
    stack = np.zeros(cap, dtype=np.int64)
    counts = np.zeros(3, dtype=np.int64)
    Q[0] = env.start
    counts[0] = 1
    best_costs = np.full(iterations, np.inf)
    best = np.inf
    if bool(env.in_goal(env.start)):  # already there: the empty path, tau = 0
        is_goal[0] = True
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
        i_near = _nearest_steer(Q, count, q_rand, rj, inv_ms, inv_js, step, mode, q_new)
        if u_ik[it] < p_c and not is_goal[i_near] and not checked[i_near]:
            checked[i_near] = True
            ik_calls += 1
            assert goal_ik is not None  # p_c > 0 needs one (checked above)
            q_ik = np.asarray(goal_ik(x_goal, Q[i_near].copy()), dtype=float).reshape(n + 1)
            if not np.all(np.isfinite(q_ik)):
                raise ArmbridgeError("goal IK returned a non-finite configuration")
            q_new[:n] = np.clip(q_ik[:n], -theta_b, theta_b)
            q_new[n] = min(max(q_ik[n], 0.0), total)
        status = _extend(Q, parent, tau, first_child, next_sib, is_goal, goal_list, counts, stack,
                         q_new, i_near, int(n_near), lengths, rj, reach, theta_b, total, verts, starts, bbox,
                         r2, sres, inv_ms, inv_js, goal, half_w, e_p, e_phi, dm)
        if status > 0 and counts[1] > 0:
            # a new goal node, or a rewire that lowered some goal node's tau
            g = _best_goal(tau, goal_list, int(counts[1]))
            best = tau[g]
        best_costs[it] = best
    elapsed = time.perf_counter() - t0

    path = None
    cost = math.inf
    if counts[1] > 0:
        g = _best_goal(tau, goal_list, int(counts[1]))
        chain = []
        v = int(g)
        while v >= 0:
            chain.append(v)
            v = int(parent[v])
        path = Q[chain[::-1]].copy()
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
