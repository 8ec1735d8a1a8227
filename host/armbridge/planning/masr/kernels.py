"""MASR-RRT*'s numba kernels (masr paper, Algorithms 1-2): one iteration's work on the tree arrays.

* `steer_linear` / `steer_convention`: the paper's Steer and the convention's (MasrSpace.steer);
* `nearest_steer`: Nearest by the action cost of eq. (8), then Steer;
* `on_goal`: OnGoal with GoalFix's MA position, the goal check over the joint margin (MasrGoal);
* `extend`: Alg. 1 lines 11-19 for one q_new: CollisionFree, Near, Connect (Alg. 2), OnGoal /
  GoalFix, RewireTree;
* `best_goal`: Best_path's node; `goal_score`: the goal check's score of one configuration.

rrt_star.plan drives them (module doc there). They take plain arrays, so
that the loop stays in numba: the tree's (planning.tree.Tree) and, as
tuples, the space's, the checker's and the goal's (space.py: MasrSpace.cost_args,
MasrChecker.kernel_args, MasrGoal.kernel_args), which are the arrays those
objects' own methods hand to the same kernels.

CollisionFree is collision.edge_hit, whose rotations are certified free for the continuous sweep (issue 24
section 1). numba caches `extend` with edge_hit compiled in and checks only this file's date: an edit of
collision.py (or of the soft space.py kernels it uses) needs this file touched too.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from armbridge.planning.masr.collision import edge_hit, rotation_order
from armbridge.planning.tree import link, shift_subtree, unlink
from armbridge.robots.masr import MARGIN_TOL, POS_TOL
from armbridge.robots.masr_kernels import action_cost, ma_pose, margin_range, span_score, wrap

EPS = 1e-9  # s: a rewire must save more than this
#: Tree.kind of MASR-RRT*'s nodes: an ordinary node, a node of the goal set G (made by GoalFix).
ORDINARY, GOAL = 0, 1


@njit(cache=True)
def steer_linear(qa, qb, inv_ms, inv_js, delta, out):
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
def steer_convention(qa, qb, rj, inv_ms, inv_js, delta, out):
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
def nearest_steer(Q, count, q_rand, C, delta, mode, out):
    """Nearest by eq. (8); writes Steer(v_nearest, q_rand) into out; returns the nearest index.

    C: MasrSpace.cost_args (rj, 1 / d-dot, 1 / theta-dot); mode: MasrSpace.steer_mode.
    """
    best = np.inf
    bi = 0
    for i in range(count):
        c = action_cost(Q[i], q_rand, *C)
        if c < best:
            best = c
            bi = i
    if mode == 0:
        steer_linear(Q[bi], q_rand, C[1], C[2], delta, out)
    else:
        steer_convention(Q[bi], q_rand, *C, delta, out)
    return bi


@njit(cache=True)
def on_goal(q, G, cand_d, cand_link):
    """OnGoal: links whose rectangle holds the goal point and whose heading is within e_phi, and
    where the goal check holds over the joint margin.

    For each such link, GoalFix's MA position is the goal's projection moved
    into the link's margin_range (at least dm from the joints at its ends,
    masr_kernels.margin_range); the link counts only if the goal is within
    e_p of the MA for every d within dm of it: on one link the heading is
    constant and the point moves linearly, so the two ends of [d - dm, d + dm]
    (clipped to the arm) decide, exactly. Writes each such d and link into
    cand_d / cand_link; returns how many. G: MasrGoal.kernel_args (lengths,
    rj, total, goal pose, half the rectangle width, e_p, e_phi, d_margin).
    """
    lengths, rj, total, goal, half_w, e_p, e_phi, dm = G
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
def goal_score(q, G, jp):
    """The goal check's score of one configuration in tolerance units (MasrGoal.score; <= 1: in the goal).

    inf where d is within d_margin (less MARGIN_TOL) of a joint r_2..r_n
    (MasrArm.holds_margin), else span_score: max(dp / e_p, dphi / e_phi) over
    every d' within d_margin of d. G: MasrGoal.kernel_args; jp: (n+1, 2) scratch.
    """
    lengths, rj, total, goal, _, e_p, e_phi, dm = G
    n = lengths.size
    d = q[n]
    for j in range(1, n):
        if abs(d - rj[j]) < dm - MARGIN_TOL:
            return np.inf
    px, py, phi, _ = ma_pose(q, lengths, rj, total, jp)
    return span_score(goal, px, py, phi, min(max(d, 0.0), total), total, dm, e_p, e_phi)


@njit(cache=True)
def extend(Q, parent, tau, first_child, next_sib, kind, goal_list, counts, stack, q_new, i_near, n_near, E, C, G):
    """Alg. 1 lines 11-19 for one candidate q_new from v_nearest = i_near.

    The tree is planning.tree.Tree's arrays (tau is its cost, eq. 7; kind[v]
    is GOAL for the nodes of G, ORDINARY otherwise); counts = [tree size, |G|,
    collision checks]. E, C, G: the checker's, the space's and the goal's
    arrays (MasrChecker.kernel_args for collision.edge_hit, MasrSpace.cost_args
    for eq. 8, MasrGoal.kernel_args for on_goal). Returns 0 (edge not free,
    nothing added), 1 (added) or 2 (added to G).
    """
    N = counts[0]
    rj = C[0]
    n = rj.size
    counts[2] += 1
    if edge_hit(Q[i_near], q_new, *E, False) != -1:
        return 0
    tau_min = tau[i_near] + action_cost(Q[i_near], q_new, *C)
    par = i_near

    # Near: the n_near nodes not in G with least c(u -> q_new), kept sorted
    near = np.full(n_near, -1, dtype=np.int64)
    near_c = np.full(n_near, np.inf)
    k_near = 0
    for i in range(N):
        if kind[i] == GOAL:
            continue
        c = action_cost(Q[i], q_new, *C)
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
        if edge_hit(Q[u], q_new, *E, False) == -1:
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
    kind[v] = ORDINARY
    link(first_child, next_sib, par, v)
    counts[0] = N + 1

    # OnGoal / GoalFix
    cand_d = np.empty(n)
    cand_link = np.empty(n, dtype=np.int64)
    m = on_goal(q_new, G, cand_d, cand_link)
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
                fcost[f] = action_cost(Q[par], fixes[f], *C)
        order = np.argsort(fcost)
        for a in range(2 * m):
            f = order[a]
            counts[2] += 1
            if edge_hit(Q[par], fixes[f], *E, False) == -1:
                for j in range(n + 1):
                    Q[v, j] = fixes[f, j]
                tau[v] = tau[par] + fcost[f]
                kind[v] = GOAL
                goal_list[counts[1]] = v
                counts[1] += 1
                return 2

    # RewireTree(U \ {parent}, v_new)
    for a in range(k_near):
        u = near[a]
        if u == par:
            continue
        c = action_cost(Q[v], Q[u], *C)
        if tau[v] + c < tau[u] - EPS:
            counts[2] += 1
            if edge_hit(Q[v], Q[u], *E, False) == -1:
                unlink(first_child, next_sib, parent[u], u)
                parent[u] = v
                link(first_child, next_sib, v, u)
                shift_subtree(tau, first_child, next_sib, u, tau[v] + c - tau[u], stack)
    return 1


@njit(cache=True)
def best_goal(tau, goal_list, n_goal):
    best = np.inf
    bi = -1
    for a in range(n_goal):
        g = goal_list[a]
        if tau[g] < best:
            best = tau[g]
            bi = g
    return bi
