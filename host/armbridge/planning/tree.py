"""The search tree every sampling planner here grows (RRT, RRT*, JT-RRT, WJRRT, Bi-RRT's two trees).

Nodes live in preallocated numpy arrays so that numba kernels (MASR-RRT*'s
`_extend`) can work on them in place, and Python planners use the methods:

* Q (cap, dim): the configurations; parent (cap,): -1 at a root;
* cost (cap,): the cost of the path from the root (RRT*'s tau, eq. 7 of the
  MASR paper; the edge count or joint-space length for the others);
* kind (cap,) int8: how the node was made (a planner's own labels, e.g.
  WJRRT's goal-directed vs random extensions: Table 1's Goal / Random nodes);
* first_child / next_sib: each node's children as a linked list, so RRT*'s
  rewiring can re-parent a node and push the cost change down its subtree
  (`shift_subtree`) without scanning the tree.

`add` grows the arrays by doubling when they are full (the Python planners);
the numba kernels are given a capacity up front and never grow them.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def unlink(first_child, next_sib, p, u):
    """Remove u from p's child list."""
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
def link(first_child, next_sib, p, u):
    """Make u the first child of p."""
    next_sib[u] = first_child[p]
    first_child[p] = u


@njit(cache=True)
def shift_subtree(cost, first_child, next_sib, u, delta, stack):
    """Add delta to the cost of u and of every node below it (stack: scratch of the tree's capacity)."""
    stack[0] = u
    top = 1
    while top > 0:
        top -= 1
        v = stack[top]
        cost[v] += delta
        c = first_child[v]
        while c >= 0:
            stack[top] = c
            top += 1
            c = next_sib[c]


@njit(cache=True)
def nearest_weighted(Q, count, q, w):
    """Index of the node among Q[:count] with the least sum_j w_j (Q_ij - q_j)^2."""
    best = np.inf
    bi = 0
    for i in range(count):
        s = 0.0
        for j in range(q.size):
            d = Q[i, j] - q[j]
            s += w[j] * d * d
        if s < best:
            best = s
            bi = i
    return bi


class Tree:
    """A rooted tree of configurations (module doc); node 0 is the root."""

    def __init__(self, root: np.ndarray, capacity: int = 1024, cost: float = 0.0, kind: int = 0):
        root = np.asarray(root, dtype=float).reshape(-1)
        cap = max(int(capacity), 1)
        self.dim = root.size
        self.Q = np.empty((cap, self.dim))
        self.parent = np.full(cap, -1, dtype=np.int64)
        self.cost = np.zeros(cap)
        self.kind = np.zeros(cap, dtype=np.int8)
        self.first_child = np.full(cap, -1, dtype=np.int64)
        self.next_sib = np.full(cap, -1, dtype=np.int64)
        self.count = 0
        self.add(root, -1, cost, kind)

    @property
    def capacity(self) -> int:
        return int(self.Q.shape[0])

    def __len__(self) -> int:
        return self.count

    def _grow(self) -> None:
        cap = 2 * self.capacity
        for name, fill in (("Q", None), ("parent", -1), ("cost", 0.0), ("kind", 0), ("first_child", -1),
                           ("next_sib", -1)):
            old = getattr(self, name)
            new = np.empty((cap, *old.shape[1:]), dtype=old.dtype)
            if fill is not None:
                new[:] = fill
            new[: old.shape[0]] = old
            setattr(self, name, new)

    def add(self, q: np.ndarray, parent: int, cost: float, kind: int = 0) -> int:
        """Append q as a child of parent (-1: a root) with its path cost; returns its index."""
        if self.count == self.capacity:
            self._grow()
        v = self.count
        self.Q[v] = q
        self.parent[v] = parent
        self.cost[v] = cost
        self.kind[v] = kind
        self.first_child[v] = -1
        self.next_sib[v] = -1
        if parent >= 0:
            link(self.first_child, self.next_sib, parent, v)
        self.count = v + 1
        return v

    def nearest(self, q: np.ndarray, weights: np.ndarray) -> int:
        """The node nearest q in the weighted Euclidean metric sum w_j dq_j^2."""
        return int(nearest_weighted(self.Q, self.count, np.ascontiguousarray(q, dtype=float), weights))

    def path_to(self, v: int) -> np.ndarray:
        """Node indices from the root to v."""
        chain = []
        while v >= 0:
            chain.append(v)
            v = int(self.parent[v])
        return np.array(chain[::-1], dtype=np.int64)

    def reparent(self, u: int, p: int, new_cost: float) -> None:
        """Make p the parent of u at cost new_cost, and move u's subtree by the same change (RRT* rewire)."""
        unlink(self.first_child, self.next_sib, int(self.parent[u]), u)
        self.parent[u] = p
        link(self.first_child, self.next_sib, p, u)
        stack = np.zeros(self.capacity, dtype=np.int64)
        shift_subtree(self.cost, self.first_child, self.next_sib, u, new_cost - self.cost[u], stack)
