"""Cellular automata of section V-B/V-C: clusters, deformation matrix, homotopy order."""
import numpy as np
import pytest
import torch

from armbridge.errors import ArmbridgeError
from armbridge.robots import wrap_angle
from armbridge.smm import automaton

torch.set_num_threads(1)


def test_fig7_grid_clusters_in_two_steps():
    count = np.array([[1, 1, 2], [1, 2, 2], [3, 3, 2]])
    cl = automaton.cluster(count, np.zeros((3, 3), bool))
    assert cl.label.reshape(3, 3).tolist() == [[0, 0, 1], [0, 1, 1], [2, 2, 1]]
    assert cl.seed.tolist() == [0, 2, 6]  # the cells whose initial state was the minimum
    assert cl.branches.tolist() == [1, 2, 3]
    assert cl.steps == 2


def test_a_singular_line_splits_equal_counts():
    count = np.full((5, 6), 2)
    singular = np.zeros((5, 6), bool)
    singular[:, 2] = True
    cl = automaton.cluster(count, singular)
    label = cl.label.reshape(5, 6)
    assert (label[:, 2] == -1).all()
    assert (label[:, :2] == 0).all() and (label[:, 3:] == 1).all()
    # a diagonal singular line is no gap for the 4-neighbourhood
    diag = np.eye(6, dtype=bool)[:5]
    assert len(automaton.cluster(np.full((5, 6), 1), diag).seed) == 2


def test_1d_radial_grid_with_out_of_reach_cells():
    count = np.array([2, 2, 2, 2, 1, 1, 1, 1, 1, 0, 0, 0])
    singular = np.zeros(12, bool)
    singular[[4, 8]] = True
    cl = automaton.cluster(count, singular)
    assert cl.label.tolist() == [0, 0, 0, 0, -1, 1, 1, 1, -1, 2, 2, 2]
    assert cl.branches.tolist() == [2, 1, 0]


def test_cells_outside_the_clusters_take_the_nearest_cluster_of_their_count():
    # 1-D: clusters [2 2 2] [1 1] [0 0]; cells 3 and 6 singular, traced with counts 1 and 0
    count = np.array([2, 2, 2, 1, 1, 1, 0, 0, 0])
    singular = np.zeros(9, bool)
    singular[[3, 6]] = True
    cl = automaton.cluster(count, singular)
    cells = np.arange(9.0)[:, None]
    label = automaton.nearest_cluster(cl, cells, count, reach=3)
    assert label.tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2]  # clustered cells keep theirs
    # points between cells, and a count no cluster within reach has (3), or one beyond reach
    pts = np.array([[2.6], [2.4], [5.5], [0.0], [8.0]])
    assert automaton.nearest_cluster(cl, pts, np.array([1, 2, 0, 3, 2]), reach=3).tolist() == [1, 0, 2, -1, -1]
    with pytest.raises(ArmbridgeError, match="reach"):
        automaton.nearest_cluster(cl, cells, count, reach=-1)
    with pytest.raises(ArmbridgeError, match=r"\(P, 1\)"):
        automaton.nearest_cluster(cl, np.zeros((2, 2)), np.zeros(2), reach=1)


def test_large_grid_converges_vectorised():
    count = np.ones((250, 400), dtype=np.int64)
    count[:, 200:] = 2
    cl = automaton.cluster(count, np.zeros_like(count, bool))
    assert len(cl.seed) == 2 and cl.steps == 249 + 199  # the Manhattan radius from each seed


def test_small_clusters_are_dropped_to_the_boundary():
    count = np.array([2, 2, 2, 1, 2, 2, 0, 0, 0, 0])
    singular = np.array([0, 0, 0, 0, 1, 0, 0, 0, 0, 0], bool)
    cl = automaton.drop_small(automaton.cluster(count, singular), 2)
    assert cl.label.tolist() == [0, 0, 0, -1, -1, -1, 1, 1, 1, 1]
    assert cl.branches.tolist() == [2, 0] and cl.seed.tolist() == [0, 6]
    with pytest.raises(ArmbridgeError, match="min_cells"):
        automaton.drop_small(cl, 0)


def test_bad_grid_is_an_armbridge_error():
    with pytest.raises(ArmbridgeError, match="shape"):
        automaton.cluster(np.ones(3, int), np.zeros(4, bool))
    with pytest.raises(ArmbridgeError, match="non-negative integer"):
        automaton.cluster(np.array([1.5, 2.0]), np.zeros(2, bool))
    with pytest.raises(ArmbridgeError, match="max_steps=1"):
        automaton.cluster(np.array([[1, 1, 2], [1, 2, 2], [3, 3, 2]]), np.zeros((3, 3), bool), max_steps=1)


def test_hungarian_recovers_a_known_permutation():
    rng = np.random.default_rng(0)
    perm = rng.permutation(6)
    D = rng.uniform(1.0, 2.0, (6, 6))
    D[np.arange(6), perm] = rng.uniform(0.0, 0.1, 6)
    got, total = automaton.pair(D)
    assert got.tolist() == perm.tolist()
    assert total == pytest.approx(D[np.arange(6), perm].sum())
    # the greedy row minimum is wrong here; the assignment is not
    D = np.array([[1.0, 2.0], [1.1, 5.0]])
    assert automaton.pair(D)[0].tolist() == [1, 0]
    with pytest.raises(ArmbridgeError, match="square"):
        automaton.pair(np.ones((2, 3)))


def branch(k, dx=0.0, dy=0.0, start=0, n=64):
    """Homotopy class k (k = 0, 1, 2) of a synthetic 3-joint SMM, deformed by (dx, dy)."""
    c = (0.0, 2.0, -2.0)[k]
    t = 2 * np.pi * (np.arange(n) + start) / n
    q = np.stack([t, c + 0.3 * np.sin(t) + 0.05 * dx, -c + 0.2 * np.cos(t) + 0.05 * dy], -1)
    return wrap_angle(q)


def test_circle_distance_wraps():
    a = np.array([np.pi - 0.1, 0.0])
    b = np.array([-np.pi + 0.1, 0.0])
    assert automaton.circle_distance(a, b) == pytest.approx(0.2)


def test_deformation_matrix_pairs_constructed_branches():
    a = np.stack([branch(k) for k in range(3)])
    b = np.stack([branch(k, 1.0, -1.0, start=5 * k + 3) for k in (2, 0, 1)])
    D = automaton.deformation(a, b)
    assert D.shape == (3, 3)
    assert automaton.pair(D)[0].tolist() == [1, 2, 0]
    assert np.diag(D[:, [1, 2, 0]]).max() < 0.1 < D[0, 0]
    assert automaton.deformation(a, a).diagonal().max() == 0.0


def test_propagation_gives_consistent_slots_across_a_cluster():
    rng = np.random.default_rng(1)
    shape = (6, 7)
    count = np.full(shape, 3)
    count[:, 5:] = 1  # a second cluster of single branches
    singular = np.zeros(shape, bool)
    singular[:, 3] = True  # splits the 3-branch cells in two clusters
    L, n = count.size, 64
    points = np.full((L, 3, n, 3), np.nan)
    truth = np.full((L, 3), -1)  # homotopy class in each stored slot
    for l, (i, j) in enumerate(np.ndindex(shape)):
        b = int(count[i, j])
        classes = rng.permutation(b)
        truth[l, :b] = classes
        for s, k in enumerate(classes):
            points[l, s] = branch(k, i, j, start=int(rng.integers(n)), n=n)
    cl = automaton.cluster(count, singular)
    hom = automaton.homotopy(cl, points, count.ravel())
    for c, seed in enumerate(cl.seed):
        cells = np.flatnonzero(cl.label == c)
        B = cl.branches[c]
        slot_class = np.take_along_axis(truth[cells, :B], hom.order[cells, :B], axis=1)
        assert (slot_class == slot_class[cells == seed]).all()  # slot b: one class in the whole cluster
        assert (hom.parent[cells] >= 0).all() and (cl.label[hom.parent[cells]] == c).all()
    assert (hom.order[cl.label == -1] == -1).all()
    assert hom.cost.max() < 0.1
    assert hom.steps > 1


def test_homotopy_rejects_counts_that_disagree_with_clusters():
    count = np.array([2, 2, 2])
    cl = automaton.cluster(count, np.zeros(3, bool))
    pts = np.stack([np.stack([branch(0), branch(1)])] * 3)
    with pytest.raises(ArmbridgeError, match="cluster"):
        automaton.homotopy(cl, pts, np.array([2, 1, 2]))
