"""Local grid refinement (smm/refine.py): patches, merge, and the 4R's three-branch sliver learned."""
import numpy as np
import pytest
import torch

from armbridge.errors import ArmbridgeError
from armbridge.smm import dataset, fourier, refine
from armbridge.smm.arms import get_smm_arm
from armbridge.smm.dataset import SmmDataset
from armbridge.smm.grid import GridSpec, region_grid

torch.set_num_threads(1)


def _ds(canon, cluster, label, branches, bcanon=None, blabel=None, bmax=1, n=2, K=2):
    L = len(canon)
    coeffs = np.full((L, bmax, n, K), np.nan, dtype=complex)
    for i, c in enumerate(cluster):
        if c >= 0:
            coeffs[i, : branches[c]] = 1 + i
    return SmmDataset("r", np.asarray(canon, float), np.asarray(cluster), np.asarray(label), coeffs,
                      np.asarray(branches), np.zeros((0, 2)) if bcanon is None else np.asarray(bcanon, float),
                      np.zeros(0, dtype=np.int64) if blabel is None else np.asarray(blabel), K, 4)


def test_patches_box_each_piece_of_seeds_and_join_overlapping_boxes():
    g = GridSpec((0.0, 0.0), (10.0, 20.0), (10, 20))
    seeds = np.zeros(g.shape, bool)
    seeds[1, 1] = True
    seeds[7:9, 15] = True
    boxes = refine.patches(g, seeds, factor=3, pad=1)
    assert [(b.lo, b.hi, b.shape) for b in boxes] == [((0.0, 0.0), (3.0, 3.0), (9, 9)),
                                                       ((6.0, 14.0), (10.0, 17.0), (12, 9))]
    # an L-shaped piece and a cell inside its bounding box (not touching it): one box
    seeds = np.zeros(g.shape, bool)
    seeds[5, 0:9] = True
    seeds[0:6, 8] = True
    seeds[2, 2] = True
    (box,) = refine.patches(g, seeds, factor=2, pad=0)
    assert (box.lo, box.hi, box.shape) == ((0.0, 0.0), (6.0, 9.0), (12, 18))
    assert refine.patches(g, np.zeros(g.shape, bool), 5) == []


@pytest.mark.parametrize("factor,pad,mask,match", [
    (1, 2, (10, 20), "factor must be an integer >= 2"),
    (2.5, 2, (10, 20), "factor must be an integer >= 2"),
    (2, -1, (10, 20), "pad must be an integer >= 0"),
    (2, 1, (20, 10), "does not match the grid"),
])
def test_bad_patch_settings_are_armbridge_errors(factor, pad, mask, match):
    g = GridSpec((0.0, 0.0), (10.0, 20.0), (10, 20))
    with pytest.raises(ArmbridgeError, match=match):
        refine.patches(g, np.ones(mask, bool), factor, pad)


def test_unlabelled_marks_cells_and_cells_of_unlabelled_boundary_points():
    g = GridSpec((0.0, 0.0), (2.0, 2.0), (2, 2))
    ds = _ds(g.centres(), [0, 0, 0, -1], [0, -1, 0, 0], [1], bcanon=[[1.5, 0.5], [0.2, 0.2]], blabel=[-1, 0])
    assert refine.unlabelled(ds, g).tolist() == [[False, True], [True, False]]
    assert refine.cell_of(g, np.array([[1.999, 1.999], [-5.0, 0.1]])).tolist() == [3, 0]


def test_merge_replaces_coarse_rows_inside_patches_and_renumbers_clusters():
    coarse = _ds([[0.5, 0.5], [1.5, 0.5], [0.5, 1.5], [1.5, 1.5]], [0, 1, 1, 2], [0, 1, 1, 2], [1, 2, 0],
                 bcanon=[[1.6, 1.6], [0.1, 0.1]], blabel=[2, 0], bmax=2)
    # the patch covers the cell of coarse row 3 (cluster 2, out of reach): cluster 2 loses its only row,
    # but it has no branches and no label names it any more either, so it goes
    pg = GridSpec((1.0, 1.0), (2.0, 2.0), (2, 2))
    patch = _ds(pg.centres(), [0, 0, 1, -1], [0, 0, 1, 1], [3, 1], bmax=3)
    out = refine.merge(coarse, [refine.Patch(pg, 0.01, patch)])
    assert out.canon.tolist() == [[0.5, 0.5], [1.5, 0.5], [0.5, 1.5]] + pg.centres().tolist()
    assert out.cluster.tolist() == [0, 1, 1, 2, 2, 3, -1]
    assert out.label.tolist() == [0, 1, 1, 2, 2, 3, 3]
    assert out.cluster_branches.tolist() == [1, 2, 3, 1]
    assert out.boundary_canon.tolist() == [[0.1, 0.1]] and out.boundary_label.tolist() == [0]
    assert out.coeffs.shape == (7, 3, 2, 2)
    assert np.isfinite(out.coeffs[3, :3]).all() and np.isnan(out.coeffs[0, 1:]).all()
    assert out.coeffs[3, 0, 0, 0] == 1 and out.coeffs[1, 1, 0, 0] == 2   # rows keep their own coefficients
    # a coarse cluster with branches that loses every row is dropped; a label naming it becomes -1
    coarse = _ds([[0.5, 0.5], [1.5, 1.5]], [0, 1], [0, 1], [1, 2], bcanon=[[0.6, 0.6]], blabel=[1], bmax=2)
    out = refine.merge(coarse, [refine.Patch(pg, 0.01, _ds(pg.centres(), [0] * 4, [0] * 4, [2], bmax=2))])
    assert out.cluster_branches.tolist() == [1, 2] and out.boundary_label.tolist() == [-1]
    assert refine.merge(coarse, []) is coarse


def test_merge_refuses_a_patch_of_another_data_set():
    coarse = _ds([[0.5, 0.5]], [0], [0], [1])
    other = _ds([[0.5, 0.5]], [0], [0], [1], K=3)
    with pytest.raises(ArmbridgeError, match="does not match the coarse one"):
        refine.merge(coarse, [refine.Patch(GridSpec((0.0, 0.0), (1.0, 1.0), (1, 1)), 0.01, other)])


def test_the_4r_three_branch_sliver_is_learnable_only_after_refinement():
    """A coarse 4 x 6 grid over a piece of the spatial 4R's three-branch sliver near rho = 3.6 has no
    cluster of three branches (those cells are singular); refined 4x, it has, and its coefficients
    decode to configurations on the targets (eq. 10, then FK)."""
    arm = get_smm_arm("spatial4r")
    g = GridSpec((3.50, 0.25), (3.70, 0.55), (4, 6))
    opts = dict(K=8, N=32, batch=512, per_cell=1, seeds=16, device="cpu", sing_tol=0.02)
    coarse = dataset.build_dataset(arm, g, **opts)
    assert 3 in coarse.smms.count and 3 not in coarse.dataset.cluster_branches
    merged, parts = refine.refine(arm, coarse, factor=4, pad=0, per_cell=1, batch=512, sing_tol=0.02, seeds=16,
                                  device="cpu")
    assert parts and all(p.sing_tol == pytest.approx(0.01) for p in parts)
    assert merged.canon.shape[0] == g.size - refine.inside([p.grid for p in parts], g.centres()).sum() + sum(
        p.grid.size for p in parts)
    three = np.flatnonzero(merged.cluster_branches == 3)
    assert three.size >= 1
    rows = np.flatnonzero(np.isin(merged.cluster, three))
    q = fourier.decode(merged.coeffs[rows, :3], n_points=32)             # (R, 3, 32, n)
    x = np.asarray(arm.uncanonical(merged.canon[rows]))
    tip = np.asarray(arm.task(q.reshape(-1, arm.n))).reshape(len(rows), 3, 32, -1)
    err = np.linalg.norm(tip - x[:, None, None, :], axis=-1) / arm.reach
    assert np.median(err) < 0.01                                         # K = 8 of 32: a coarse spectrum
    info = refine.summary(parts)
    assert sum(p["clusters_by_branches"].get("3", 0) for p in info) == three.size


def test_disagree_marks_both_sides_of_a_count_change_and_wraps_periodic_axes():
    count = np.array([[1, 1, 1, 2],
                      [1, 1, 1, 1]])
    assert refine.disagree(count).astype(int).tolist() == [[0, 0, 1, 1], [0, 0, 0, 1]]
    # axis 1 periodic: the last column's 2 also meets the first column's 1
    assert refine.disagree(count, (False, True)).astype(int).tolist() == [[1, 0, 1, 1], [0, 0, 0, 1]]
    assert not refine.disagree(np.full((3, 1, 4), 2)).any()
    with pytest.raises(ArmbridgeError, match="one flag per grid axis"):
        refine.disagree(count, (True,))


def test_4d_patches_are_tiles_with_per_axis_factors():
    g = GridSpec((0.0, 0.0, 0.0, -4.0), (1.0, 1.0, 4.0, 4.0), (1, 1, 4, 8))
    seeds = np.zeros(g.shape, bool)
    seeds[0, 0, 0, 0] = seeds[0, 0, 3, 7] = True
    # pad 3 grows them into one box (the whole grid); tiles of 2 keep only the corners' tiles
    tiles = refine.patches(g, seeds, (1, 1, 2, 3), pad=3, tile=2)
    assert [(t.lo, t.hi, t.shape) for t in tiles] == [((0.0, 0.0, 0.0, -4.0), (1.0, 1.0, 2.0, -2.0), (1, 1, 4, 6)),
                                                      ((0.0, 0.0, 2.0, 2.0), (1.0, 1.0, 4.0, 4.0), (1, 1, 4, 6))]
    assert refine.cells_of(g, tiles[1]) == (slice(0, 1), slice(0, 1), slice(2, 4), slice(6, 8))
    assert refine.patch_sing_tol(0.01, (1, 1, 4, 4)) == pytest.approx(0.005)
    for bad in ((1, 1, 1, 1), (2, 2), (1, 1, 2.5, 2)):
        with pytest.raises(ArmbridgeError, match="refinement factor"):
            refine.patches(g, seeds, bad)
    with pytest.raises(ArmbridgeError, match="tile must be"):
        refine.patches(g, seeds, 2, tile=0)


def test_the_7r_grid_is_refined_where_neighbouring_cells_disagree():
    """A tiny 7R grid over tool directions (1 x 1 x 2 x 4): the cells where neighbours disagree on the
    branch count are refined 2x in azimuth, in tiles of 2 cells; each patch is traced (its own SMMs) and
    replaces its coarse rows. A deadline already passed refines nothing."""
    arm = get_smm_arm("spatial7r")
    rg = region_grid(arm)
    g = GridSpec(rg.lo, (rg.lo[0] + 0.05, rg.lo[1] + 0.05, np.pi, np.pi), (1, 1, 2, 4))
    opts = dict(seeds=16, device="cpu", sing_tol=0.005, step=0.04)
    coarse = dataset.build_dataset(arm, g, K=8, N=32, per_cell=0, batch=512, **opts)
    seeds = refine.seeds_for(arm, coarse)
    counts = coarse.smms.count.reshape(g.shape)
    assert seeds.any() and (seeds >= refine.disagree(counts, (False, False, False, True))).all()
    same, none = refine.refine(arm, coarse, (1, 1, 1, 2), pad=0, per_cell=0, tile=2, deadline=0.0, **opts)
    assert none == [] and same is coarse.dataset
    merged, parts = refine.refine(arm, coarse, (1, 1, 1, 2), pad=0, per_cell=0, tile=2, min_cells=1, **opts)
    assert parts
    for p in parts:
        assert p.grid.shape == (1, 1, 2, 4) and p.sing_tol == pytest.approx(0.005 / np.sqrt(2))
        assert seeds[refine.cells_of(g, p.grid)].any()
        assert len(p.dataset.canon) == p.grid.size and set(p.dataset.cluster_branches) <= set(range(1, 9))
    assert merged.canon.shape[0] == g.size - refine.inside([p.grid for p in parts], g.centres()).sum() + sum(
        p.grid.size for p in parts)
    covered = refine.inside([p.grid for p in parts], g.centres())
    assert covered[seeds.ravel()].all()  # every cell where neighbours disagree is refined
