"""Issue 24 section 1: the soft arm's edge check is certified for the continuous motion (planning/soft/space.py).

Per fixed scene (the 2-, 3- and 7-link chains and the 7-link horn) EDGES random
edges near obstacles (start valid and within NEAR_M of an obstacle or of a
non-adjacent link, a random direction, a length of up to MOVE_M of point
motion): wherever the certified check says free, the old fixed-resolution check
at a tenth of EDGE_RES (numba) finds every sampled state free, on all of them,
and shapely finds no overlap (chain within half the link width of an obstacle,
or non-adjacent links within the width) at states no more than 0.1 mm of point
motion apart, on the SHAPELY edges of them that pass nearest an obstacle. The
motion bound itself is checked against sampled displacements.

The MASR (planning/masr/collision.py, certified rotations): the same on E1-E3,
MASR_EDGES actions each from configurations within NEAR_M of an obstacle,
against the convention's shapes 1 mm (a tenth of SWEEP_RES) and 0.1 mm apart.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from armbridge.planning.polygons import self_hit
from armbridge.planning.soft import planners
from armbridge.planning.soft.scene import fixed_scene
from armbridge.planning.soft.space import EDGE_RES, FREE, NEAR, ChainChecker
from armbridge.robots import PlanarChain

SCENES = ("two-arm", "three-arm", "seven-tube", "horn")
EDGES = 10_000
SHAPELY = 300
NEAR_M = 0.01
MOVE_M = 0.03
DENSE_M = 1e-4


def near_edges(scene, checker: ChainChecker, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
    """count edges (a, b) with a valid and within NEAR_M of an obstacle or a non-adjacent link."""
    space = scene.space()
    A, B = [], []
    while len(A) < count:
        for a in space.sample(rng, 4 * count):
            if len(A) == count:
                break
            if not checker.is_valid(a):
                continue
            if checker.clearance(a) > NEAR_M and _self_clearance(checker, a) > NEAR_M:
                continue
            d = rng.normal(size=a.size)
            move = float(np.abs(d) @ checker.reach)
            b = space.clip(a + d * (rng.random() * MOVE_M / move))
            A.append(a)
            B.append(b)
    return np.array(A), np.array(B)


def _self_clearance(checker: ChainChecker, q: np.ndarray) -> float:
    """0 when two non-adjacent links are within NEAR_M of touching (width included), else inf."""
    return 0.0 if self_hit(checker.points(q), (checker.link_width + NEAR_M) ** 2) else math.inf


def dense_states(checker: ChainChecker, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """States of the edge a -> b no more than DENSE_M of point motion apart (the bound's reach), both ends in."""
    move = float(np.abs(b - a) @ checker.reach)
    t = np.linspace(0.0, 1.0, max(2, int(math.ceil(move / DENSE_M)) + 1))
    return a + t[:, None] * (b - a)


def shapely_overlaps(checker: ChainChecker, Q: np.ndarray) -> np.ndarray:
    """(K,) True where the chain at Q[k] comes within w/2 of an obstacle or two non-adjacent links within w."""
    obstacles = shapely.union_all([shapely.LineString(p) if len(p) == 2 else shapely.Polygon(p)
                                   for p in checker.polygons])
    shapely.prepare(obstacles)
    th = checker.base[2] + np.cumsum(Q, axis=1)
    steps = checker.lengths * np.stack([np.cos(th), np.sin(th)], axis=2).transpose(2, 0, 1)  # (2, K, n)
    P = np.concatenate([np.zeros((Q.shape[0], 1, 2)), np.cumsum(steps, axis=2).transpose(1, 2, 0)], axis=1)
    P += checker.base[:2]
    assert np.allclose(P[0], checker.points(Q[0]))
    w = checker.link_width
    hit = shapely.distance(shapely.linestrings(P), obstacles) <= 0.5 * w
    n = checker.n
    for i in range(n - 2):
        for j in range(i + 2, n):
            d = shapely.distance(shapely.linestrings(P[:, i:i + 2]), shapely.linestrings(P[:, j:j + 2]))
            hit |= d <= w
    return hit


@pytest.fixture(scope="module", params=SCENES)
def edges(request):
    scene = fixed_scene(request.param)
    checker = scene.checker()
    A, B = near_edges(scene, checker, np.random.default_rng(24), EDGES)
    codes = np.array([checker.motion_code(a, b) for a, b in zip(A, B)])
    return request.param, scene, checker, A, B, codes


def test_certified_free_edges_are_free_at_a_ten_times_finer_resolution(edges):
    name, scene, checker, A, B, codes = edges
    fine = scene.checker(res=EDGE_RES / 10, certified=False)
    fine_codes = np.array([fine.motion_code(a, b) for a, b in zip(A, B)])
    free = codes == FREE
    assert len(A) >= 10_000
    missed = np.flatnonzero(free & (fine_codes != FREE))
    assert missed.size == 0, (name, missed[:5], fine_codes[missed[:5]])
    # Both answers occur (the edges are near obstacles), and the certificate refuses few edges the fine check frees.
    assert 0.05 * len(A) < free.sum() < 0.98 * len(A), (name, free.sum())
    refused = np.count_nonzero((fine_codes == FREE) & ~free)
    assert refused <= 0.02 * np.count_nonzero(fine_codes == FREE), (name, refused)
    # A refusal names a colliding state, a clearance within CLEAR_MIN (NEAR) or the joint limits.
    assert set(np.unique(codes[~free])) <= set(range(-8, 1000)) - {FREE}


def test_certified_free_edges_do_not_overlap_in_shapely(edges):
    name, scene, checker, A, B, codes = edges
    free = np.flatnonzero(codes == FREE)
    # The SHAPELY certified-free edges that pass nearest an obstacle (least obstacle clearance over 11 states).
    t = np.linspace(0.0, 1.0, 11)
    least = np.array([min(checker.clearance(A[k] + s * (B[k] - A[k])) for s in t) for k in free])
    pick = free[np.argsort(least)[:SHAPELY]]
    Q = np.concatenate([dense_states(checker, A[k], B[k]) for k in pick])
    assert len(Q) > 10 * SHAPELY
    hit = shapely_overlaps(checker, Q)
    assert not hit.any(), (name, Q[hit][:3])


def _link_samples(checker: ChainChecker, q: np.ndarray, m: int = 11) -> np.ndarray:
    p = checker.points(q)
    s = np.linspace(0.0, 1.0, m)[None, :, None]
    return p[:-1, None, :] + s * (p[1:, None, :] - p[:-1, None, :])  # (n, m, 2)


@pytest.mark.parametrize("name", SCENES)
def test_the_motion_bound_is_never_exceeded(name):
    """B[k] t bounds every sampled point of link k; S[a, b] t its motion relative to link a, in link a's frame."""
    checker = fixed_scene(name).checker()
    rng = np.random.default_rng(7)
    n = checker.n
    for _ in range(300):
        a = rng.uniform(-math.pi, math.pi, n)
        b = a + rng.normal(0.0, rng.choice([0.01, 0.3, 2.0]), n)
        Bk, S = checker.motion_bounds(a, b)
        X0 = _link_samples(checker, a)
        for t in np.linspace(0.0, 1.0, 9)[1:]:
            X = _link_samples(checker, a + t * (b - a))
            moved = np.linalg.norm(X - X0, axis=2).max(axis=1)
            assert np.all(moved <= t * Bk + 1e-12), (moved, t * Bk)
            for i in range(n - 2):
                for j in range(i + 2, n):
                    r0, r = _in_frame(X0, i, j), _in_frame(X, i, j)
                    assert np.linalg.norm(r - r0, axis=1).max() <= t * S[i, j] + 1e-12
        # The bound is the reach formula: a point of link k is within R_ik of joint i.
        L = checker.lengths
        dq = np.abs(b - a)
        want = [sum(dq[i] * L[i:k + 1].sum() for i in range(k + 1)) for k in range(n)]
        assert np.allclose(Bk, want)


def _in_frame(X: np.ndarray, i: int, j: int) -> np.ndarray:
    """Link j's samples in the frame of link i (origin at its start, x along it)."""
    o, e = X[i, 0], X[i, -1]
    u = (e - o) / np.linalg.norm(e - o)
    R = np.array([[u[0], u[1]], [-u[1], u[0]]])
    return (X[j] - o) @ R.T


def test_a_collision_between_two_samples_is_caught():
    """A thin wall that the tip sweeps over between two 2 mm samples: the sampled check misses it, the
    certificate does not; moved clear of the arc, the certificate frees the edge."""
    robot = PlanarChain(name="t1", link_lengths=np.array([0.1]), q_min=np.array([-1.0]), q_max=np.array([1.0]),
                        v_max=np.ones(1), joint_names=("a",))
    a, b = np.array([0.0]), np.array([0.04])  # the tip moves 4 mm: samples at t = 0.5 and 1
    tip = lambda q: 0.1 * np.array([math.cos(q), math.sin(q)])  # noqa: E731
    p = tip(0.01)  # between the samples
    wall = [p * 0.95, p * 1.05]
    old = ChainChecker.create(robot, [wall], certified=False)
    new = ChainChecker.create(robot, [wall])
    assert old.motion_valid(a, b) and not new.motion_valid(a, b)
    # The advancement stops within CLEAR_MIN of the wall, short of the contact (no probe state lands on it).
    assert new.motion_code(a, b) == NEAR
    clear = [p * 1.05, p * 1.1]
    assert ChainChecker.create(robot, [clear]).motion_valid(a, b)
    # A wall 0.5 um beyond the tip's arc: no state touches it, but it is within CLEAR_MIN: refused as NEAR.
    u = tip(0.02) / 0.1
    graze = [u * (0.1 + 5e-7), u * 0.12]
    assert old.__class__.create(robot, [graze], certified=False).motion_valid(a, b)
    assert ChainChecker.create(robot, [graze]).motion_code(a, b) == NEAR


def test_the_reported_overlap_is_gone():
    """Issue 24's setting of the one overlapping path (WJRRT, seed 10, step 0.7, d_min 0, C1 0; 13 um into an
    obstacle under the 2 mm check; not reproduced on these scenes by the old check either): the paths are
    accepted by the certified check and free in shapely at 0.1 mm."""
    for name in ("two-arm", "three-arm", "seven-tube"):
        scene = fixed_scene(name)
        r = planners.plan(scene, "wjrrt", seed=10, step=0.7, d_min=0.0, C1=0.0)
        if not r.success:
            continue
        checker = scene.checker()
        assert checker.path_problem(r.path) is None
        Q = np.concatenate([dense_states(checker, r.path[k], r.path[k + 1]) for k in range(len(r.path) - 1)])
        assert not shapely_overlaps(checker, Q).any(), name


# ------------------------------------------------------------------------------------------------------ the MASR
MASR_ENVS = ("E1", "E2", "E3")
MASR_EDGES = 4_000  # per environment: 12,000 for the robot


def masr_near_edges(env, chk, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
    """count actions (a, b): a in C_free within NEAR_M of an obstacle, 1-3 joints turned (up to 0.3 rad), the MA
    moved or put on a joint."""
    arm = env.arm
    lo, hi = np.append(-arm.theta_b, 0.0), np.append(arm.theta_b, arm.total_length)
    A, B = [], []
    while len(A) < count:
        for a in rng.uniform(lo, hi, (4 * count, arm.n + 1)):
            if len(A) == count:
                break
            if not chk.is_valid(a) or chk.clearance(a) > NEAR_M:
                continue
            b = a.copy()
            joints = rng.choice(arm.n, size=rng.integers(1, 4), replace=False)
            b[joints] += rng.uniform(-0.3, 0.3, joints.size)
            b[-1] = arm.r[rng.integers(arm.n)] if rng.random() < 0.2 else rng.uniform(0.0, arm.total_length)
            A.append(a)
            B.append(np.clip(b, lo, hi))
    return np.array(A), np.array(B)


def masr_shapes(chk, qa: np.ndarray, qb: np.ndarray, res: float) -> np.ndarray:
    """The arm's configurations along the convention's rotations, no point moving more than res between two."""
    from armbridge.planning.masr.collision import rotation_order

    order = np.empty(chk.arm.n, dtype=np.int64)
    m = rotation_order(qa, qb, chk.collision.rj, order)
    q = qa.copy()
    out = []
    for j in order[:m]:
        k = max(1, int(math.ceil(abs(qb[j] - qa[j]) * chk.collision.reach[j] / res)))
        for s in range(1, k + 1):
            q[j] = qa[j] + (qb[j] - qa[j]) * s / k
            out.append(q.copy())
        q[j] = qb[j]
    out.append(qb.copy())
    return np.array(out)


@pytest.fixture(scope="module", params=MASR_ENVS)
def masr_edges(request):
    from armbridge.planning.masr.environment import fixed_environment
    from armbridge.planning.masr.space import MasrChecker

    env = fixed_environment(request.param)
    chk = MasrChecker(env.checker())
    A, B = masr_near_edges(env, chk, np.random.default_rng(24), MASR_EDGES)
    free = np.array([chk.motion_valid(a, b) for a, b in zip(A, B)])
    return request.param, env, chk, A, B, free


def test_masr_certified_free_actions_are_free_at_a_ten_times_finer_resolution(masr_edges):
    from armbridge.planning.masr.collision import SWEEP_RES

    name, env, chk, A, B, free = masr_edges
    c = chk.collision
    fine = np.array([not np.any(c.hits(masr_shapes(chk, a, b, SWEEP_RES / 10)) >= 0) for a, b in zip(A, B)])
    missed = np.flatnonzero(free & ~fine)
    assert missed.size == 0, (name, missed[:5])
    assert 0.05 * len(A) < free.sum() < 0.98 * len(A), (name, free.sum())
    assert np.count_nonzero(fine & ~free) <= 0.02 * fine.sum(), (name, np.count_nonzero(fine & ~free))


def test_masr_certified_free_actions_do_not_overlap_in_shapely(masr_edges):
    from armbridge.planning.masr.collision import arm_points

    name, env, chk, A, B, free = masr_edges
    idx = np.flatnonzero(free)
    least = np.array([min(chk.clearance(q) for q in masr_shapes(chk, A[k], B[k], 0.01)) for k in idx])
    pick = idx[np.argsort(least)[:SHAPELY]]
    Q = np.concatenate([masr_shapes(chk, A[k], B[k], DENSE_M) for k in pick])
    assert len(Q) > 10 * SHAPELY
    pts = np.empty((chk.arm.n + 1, 2))
    P = np.empty((len(Q), chk.arm.n + 1, 2))
    for i, q in enumerate(Q):
        arm_points(q, chk.collision.lengths, pts)
        P[i] = pts
    obstacles = shapely.union_all([shapely.Polygon(p) for p in env.obstacles])
    shapely.prepare(obstacles)
    d = shapely.distance(shapely.linestrings(P), obstacles)
    assert np.all(d > chk.margin), (name, d.min() - chk.margin)
