"""WJRRT-Connect: WJRRT (Algorithms 2-3) grown from both ends, the whole loop in numba.

Issue 24 section 3 asks WJRRT to improve where it fell behind OMPL's
RRTConnect on scenes nobody tuned for: adaptive clearance weights where the
goal extension stalls, a step that fits the scene, growing from both ends,
while staying the paper's algorithm. This planner is that:

* Algorithm 2's loop: each iteration, with probability P_G (`p_goal`),
  extend_Towards_Goal on the start tree, else a random extension.
* extend_Towards_Goal is Algorithm 3 as in jacobian_rrt.py: N_c is the
  start-tree node whose tip is closest to X_G (nodes whose goal extension
  failed `goal_tries` times are skipped), theta_c perturbed by k U(-1, 1)
  (eq. 16), one clipped Jacobian-transpose step (eq. 17-19, jtstep.jt_step),
  accepted when every link keeps more than d_min (eq. 7), W_s > C1 (eq. 20),
  W_d < C2 (eq. 21), H (eq. 9-10) falls and the edge is certified free;
  steps chain while they are accepted.
* Adaptive weights: when `goal_tries` goal extensions in a row bring the
  start tree's closest tip no nearer X_G (by dx / 2; the goal extension
  stalls, the paper's failure mode in narrow passages), d_min, C1 and
  lambda are halved, and P_G with them down to GOAL_FLOOR of it: the weights
  that keep the tip away from obstacles in the open relax where the goal
  lies in a gap, and a goal extension that walks into a dead end (OMPL's
  horn) stops costing a fifth of the iterations.
* Both ends (RRT-Connect, Kuffner and LaValle 2000): the random extension
  alternates between the start tree and a goal tree rooted at the problem's
  goal configurations (the scene's goal_q and the tip descent of ik.py);
  the tree that grew is followed by the other one stepping towards the new
  node until it arrives (CONNECT) or is blocked. Every node the goal
  extension adds is also connected to. The path is the start tree's branch
  then the goal tree's reversed, or the start tree's branch alone when a
  goal step brought the tip within tol. Without goal configurations only
  the start tree grows (WJRRT with the fitted step).
* A step that fits the scene: the random extension's step (rad) defaults to
  RANGE_FRACTION = 0.3 of the joint box's diagonal (OMPL's RRTConnect uses
  0.2 of the space's maximum extent; 0.3 needed fewer checks on the tuning
  scenes), instead of the paper's fixed 0.1 rad.
  Long edges cost nothing in safety: every edge is certified free by
  conservative advancement (space.edge_code, the checker's margin kept).

One call of `_grow` runs at most CHUNK iterations in numba; the Python
loop around it checks the time limit and grows the arrays, so the time
limit is honoured to within one chunk (about a millisecond on the horn).
Random numbers come from numba's own generator, seeded per run: the same
seed gives the same plan.
"""
from __future__ import annotations

import math
import time
from typing import Any, Optional

import numpy as np
from numba import njit

from armbridge.errors import ArmbridgeError
from armbridge.planning.base import PlanResult, Problem
from armbridge.planning.polygons import chain_points
from armbridge.planning.soft.jacobian_rrt import GOAL, MAX_SERIES, RANDOM, START, goal_step, objective, weigh
from armbridge.planning.soft.space import FREE, edge_code, state_code

DEFAULTS: dict[str, Any] = {"p_goal": 0.2, "k": 0.02, "dx": 0.01, "step": None, "goal_tries": 3,
                            "C1": 0.0, "C2": math.inf, "lambda": 0.0, "d_min": 0.0}
#: Parameters a scene's "params" (tuned for WJRRT's fixed step) do not set here: the step fits the scene and
#: the goal bias is this planner's; a call's own overrides still set them.
OWN = ("step", "p_goal")
#: The step as a fraction of the joint box's diagonal (OMPL's RRTConnect range rule).
RANGE_FRACTION = 0.3
#: Nodes per tree before the arrays first grow (they double whenever full).
CAPACITY = 1024
#: Iterations per numba call between time checks.
CHUNK = 64
#: A stalled goal extension is tried less often: P_G times the weights' relax factor, down to this share of P_G.
GOAL_FLOOR = 0.25
#: Kind of the goal tree's roots.
GOAL_ROOT = 3
RUNNING, TIP, MEET, FULL = 0, 1, 2, 3


@njit(cache=True)
def _seed(seed):
    np.random.seed(seed)


@njit(cache=True)
def _nearest(Q, count, q):
    """The node of Q[:count] nearest q (Euclidean in joint space; a linear scan: trees stay small here)."""
    best, bd = 0, np.inf
    for i in range(count):
        d = 0.0
        for j in range(q.size):
            t = Q[i, j] - q[j]
            d += t * t
        if d < bd:
            best, bd = i, d
    return best


@njit(cache=True)
def _steer(qa, qb, step, out):
    """out = the point at most `step` (rad) from qa towards qb; True when it is qb itself."""
    d = 0.0
    for j in range(qa.size):
        d += (qb[j] - qa[j]) ** 2
    d = math.sqrt(d)
    if d <= step:
        out[:] = qb
        return True
    f = step / d
    for j in range(qa.size):
        out[j] = qa[j] + f * (qb[j] - qa[j])
    return False


@njit(cache=True)
def _free(qa, qb, G, W):
    """space.edge_code on the edge qa -> qb == FREE (G: geometry, W: scratch; see `solve`). The end state is
    tested first (one state_code, as OMPL's planners call isValid before checkMotion): most refused edges end
    inside an obstacle, and the certified check would advance all the way to it."""
    if state_code(qb, G[0], G[2], G[3], G[4], G[5], G[6], G[7], G[8] * G[8], G[9] * G[9], W[0]) != FREE:
        return False
    return edge_code(qa, qb, G[0], G[1], G[2], G[3], G[4], G[5], G[6], G[7], G[8], G[9], G[10],
                     W[0], W[1], W[2], W[3], W[4], W[5])[1] == FREE


@njit(cache=True)
def _tip_d(q, G, pts, goal):
    """The tip's distance to the goal point X_G (m)."""
    L, base = G[0], G[2]
    chain_points(q, L, base[0], base[1], base[2], pts)
    n = L.size
    return math.sqrt((goal[0] - pts[n, 0]) ** 2 + (goal[1] - pts[n, 1]) ** 2)


@njit(cache=True)
def _add(Q, parent, kind, count, y, q, par, k):
    v = count[y]
    Q[y, v, :] = q
    parent[y, v] = par
    kind[y, v] = k
    count[y] = v + 1
    return v


@njit(cache=True)
def _connect(Q, parent, kind, count, tipd, y, target, step, goal, tol, G, W, st, fs):
    """CONNECT: tree y steps towards target until it arrives or is blocked -> (last node or -1, status):
    MEET when it arrived, TIP when a start-tree node came within tol of X_G, else RUNNING."""
    cap = Q.shape[1]
    qnew = W[9]
    last = -1
    while count[y] < cap - 1:
        near = last if last >= 0 else _nearest(Q[y], count[y], target)
        arrived = _steer(Q[y, near], target, step, qnew)
        st[2] += 1
        if not _free(Q[y, near], qnew, G, W):
            return last, RUNNING
        last = _add(Q, parent, kind, count, y, qnew, near, RANDOM)
        if y == 0:
            tipd[last] = _tip_d(qnew, G, W[0], goal)
            fs[1] = min(fs[1], tipd[last])
            if tipd[last] <= tol:
                return last, TIP
        if arrived:
            return last, MEET
    return last, RUNNING


@njit(cache=True)
def _towards_goal(Q, parent, kind, count, tipd, fails, goal, tol, G, W, p, relax, st, fs):
    """extend_Towards_Goal (Algorithm 3, module doc) on the start tree -> the last node added or -1."""
    k, dx, tries, C1, C2, lam, d_min = p[1], p[2], p[4], p[5], p[6], p[7], p[8]
    pts, cl, J, qp, qn, u = W[0], W[2], W[6], W[7], W[8], W[10]
    c, bd = -1, np.inf
    for i in range(count[0]):
        if fails[i] < tries and tipd[i] < bd:
            c, bd = i, tipd[i]
    if c < 0:
        return -1
    h_best, last, qc = np.inf, -1, Q[0, c]
    for _ in range(MAX_SERIES):
        for j in range(u.size):
            u[j] = np.random.random()
        d, least, ws, wd, _ln = goal_step(qc, u, k, goal, dx, G[0], G[2], G[3], G[4], G[5], G[6], G[11], pts, J,
                                          cl, qp, qn)
        st[2] += 1
        if not (least > d_min * relax and ws > C1 * relax and wd < C2):
            break
        h = d * d + (lam * relax / least if lam > 0.0 else 0.0)
        if h >= h_best or not _free(qc, qn, G, W):
            break
        h_best = h
        last = _add(Q, parent, kind, count, 0, qn, c if last < 0 else last, GOAL)
        tipd[last] = d
        fs[1] = min(fs[1], d)
        qc = Q[0, last]
        if d <= tol:
            break
    if last < 0:
        fails[c] += 1
    return last


@njit(cache=True)
def _grow(Q, parent, kind, count, tipd, fails, goal, tol, G, W, p, st, fs, two, iters):
    """At most `iters` iterations of the module doc's loop -> (status, start-tree node, goal-tree node).
    st: [side, stall, checks, iterations]; fs: [relax, the start tree's closest tip distance to X_G];
    FULL when the arrays need to grow first."""
    cap, n = Q.shape[1], Q.shape[2]
    p_goal, dx, step, tries = p[0], p[2], p[3], p[4]
    lo, hi, qr, qnew = G[3], G[4], W[1], W[9]
    for _ in range(iters):
        if count[0] + MAX_SERIES + 2 > cap or count[1] + 2 > cap:
            return FULL, -1, -1
        st[3] += 1
        if np.random.random() < p_goal * max(fs[0], GOAL_FLOOR):
            before = fs[1]
            v = _towards_goal(Q, parent, kind, count, tipd, fails, goal, tol, G, W, p, fs[0], st, fs)
            if fs[1] < before - 0.5 * dx:  # the tree's closest tip came nearer: the goal extension works
                st[1] = 0
            else:
                st[1] += 1
                if st[1] >= tries:
                    fs[0] *= 0.5
                    st[1] = 0
            if v < 0:
                continue
            if tipd[v] <= tol:
                return TIP, v, -1
            if two:
                b, s = _connect(Q, parent, kind, count, tipd, 1, Q[0, v].copy(), step, goal, tol, G, W, st, fs)
                if s == MEET:
                    return MEET, v, b
            continue
        for j in range(n):
            qr[j] = lo[j] + np.random.random() * (hi[j] - lo[j])
        x = st[0] if two else 0
        st[0] = 1 - st[0]
        near = _nearest(Q[x], count[x], qr)
        _steer(Q[x, near], qr, step, qnew)
        st[2] += 1
        if not _free(Q[x, near], qnew, G, W):
            continue
        a = _add(Q, parent, kind, count, x, qnew, near, RANDOM)
        if x == 0:
            tipd[a] = _tip_d(Q[0, a], G, W[0], goal)
            fs[1] = min(fs[1], tipd[a])
            if tipd[a] <= tol:
                return TIP, a, -1
        if two:
            b, s = _connect(Q, parent, kind, count, tipd, 1 - x, Q[x, a].copy(), step, goal, tol, G, W, st, fs)
            if s == TIP:
                return TIP, b, -1
            if s == MEET:
                return (MEET, a, b) if x == 0 else (MEET, b, a)
    return RUNNING, -1, -1


def _settings(problem: Problem, params: dict[str, Any]) -> dict[str, Any]:
    for key in params:
        if key not in DEFAULTS:
            raise ArmbridgeError(f"wjrrt-connect: unknown parameter {key!r} (known: {', '.join(DEFAULTS)})")
    s = {**DEFAULTS, **params}
    if s["step"] is None:
        s["step"] = RANGE_FRACTION * float(np.linalg.norm(problem.checker.upper - problem.checker.lower))
    if not (float(s["step"]) > 0 and math.isfinite(float(s["step"]))):
        raise ArmbridgeError(f"wjrrt-connect: step = {s['step']} rad must be a finite number > 0")
    if not 0.0 <= float(s["p_goal"]) <= 1.0:
        raise ArmbridgeError(f"wjrrt-connect: p_goal = {s['p_goal']} is outside [0, 1]")
    return s


def _branch(parent: np.ndarray, v: int) -> list[int]:
    """Node indices from the root to v."""
    out = []
    while v >= 0:
        out.append(v)
        v = int(parent[v])
    return out[::-1]


def solve(problem: Problem, *, iterations: int = 1000, seed: int = 0, time_limit: Optional[float] = None,
          **params: Any) -> PlanResult:
    """Plan with WJRRT-Connect (module doc); params as DEFAULTS ("lambda" by name)."""
    s = _settings(problem, params)
    chk, goal = problem.checker, problem.goal
    n = chk.n
    start = np.ascontiguousarray(problem.start, dtype=float)
    if not chk.is_valid(start):
        raise ArmbridgeError(f"wjrrt-connect: the start configuration is not valid: {chk.describe(chk.code(start))}")
    roots = np.asarray(problem.goal_states, dtype=float).reshape(-1, n) if problem.goal_states.size else np.zeros((0, n))
    two = roots.shape[0] > 0
    G = (chk.lengths, chk.reach, chk.base, chk.lower, chk.upper, chk.verts, chk.starts, chk.bbox, float(chk.radius),
         float(chk.link_width), float(chk.res), float(chk.half_width))
    W = (np.empty((n + 1, 2)), np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.zeros((n, n)),
         np.empty((2, n)), np.empty(n), np.empty(n), np.empty(n), np.empty(n))
    p = np.array([s["p_goal"], s["k"], s["dx"], s["step"], s["goal_tries"], s["C1"], s["C2"], s["lambda"],
                  s["d_min"]], dtype=float)
    X_G = np.ascontiguousarray(goal.point, dtype=float)
    tol = float(goal.tol)
    cap = CAPACITY + roots.shape[0]
    Q = np.zeros((2, cap, n))
    parent = np.full((2, cap), -1, dtype=np.int64)
    kind = np.zeros((2, cap), dtype=np.int8)
    count = np.zeros(2, dtype=np.int64)
    tipd = np.full(cap, np.inf)
    fails = np.zeros(cap, dtype=np.int64)
    _add(Q, parent, kind, count, 0, start, -1, START)
    for r in roots:
        _add(Q, parent, kind, count, 1, r, -1, GOAL_ROOT)
    st = np.zeros(4, dtype=np.int64)
    fs = np.array([1.0, math.inf])  # relax, the start tree's closest tip distance
    _seed(int(seed) % (2 ** 32))
    t0 = time.perf_counter()
    tipd[0] = fs[1] = _tip_d(start, G, W[0], X_G)
    status, a, b = (TIP, 0, -1) if tipd[0] <= tol else (RUNNING, -1, -1)
    while status == RUNNING and st[3] < iterations and (time_limit is None or time.perf_counter() - t0 < time_limit):
        status, a, b = _grow(Q, parent, kind, count, tipd, fails, X_G, tol, G, W, p, st, fs, two,
                             min(CHUNK, iterations - int(st[3])))
        if status == FULL:
            cap *= 2
            Q = np.concatenate([Q, np.zeros_like(Q)], axis=1)
            parent = np.concatenate([parent, np.full_like(parent, -1)], axis=1)
            kind = np.concatenate([kind, np.zeros_like(kind)], axis=1)
            tipd = np.concatenate([tipd, np.full_like(tipd, np.inf)])
            fails = np.concatenate([fails, np.zeros_like(fails)])
            status = RUNNING
    elapsed = time.perf_counter() - t0
    relax = float(fs[0])
    checks = int(st[2]) + 1
    chk.checks += checks
    path, idx, tail = None, [], []
    if status in (TIP, MEET):
        idx = _branch(parent[0], a)
        tail = _branch(parent[1], b)[::-1] if status == MEET else []
        states = [Q[0, i] for i in idx] + [Q[1, i] for i in tail]
        path = np.array([q for k, q in enumerate(states) if k == 0 or not np.array_equal(q, states[k - 1])])
    kinds = np.concatenate([kind[0, idx[1:]], kind[1, tail[:-1]]]) if path is not None else np.zeros(0, np.int8)
    end = path[-1] if path is not None else Q[0, int(np.argmin(tipd[: count[0]]))]
    nodes = int(count[0] + count[1])
    d_end, least_end = weigh(end, end, X_G, chk.lengths, chk.base, chk.verts, chk.starts, chk.half_width, W[0],
                             W[2])[:2]
    stats = {"nodes": nodes, "track_nodes": 0 if path is None else int(path.shape[0] - 1),
             "goal_nodes": int(np.sum(kinds == GOAL)), "random_nodes": int(np.sum(kinds == RANDOM)),
             "obstacle_checks": checks, "tip_error_m": float(d_end),
             "final_H": objective(float(d_end), float(least_end), float(s["lambda"]) * relax),
             "weight_relax": relax}
    cost = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))) if path is not None else math.inf
    return PlanResult("wjrrt-connect", path, int(st[3]), elapsed, nodes, checks, seed, cost, stats,
                      {**s, "goal_tree": two})
