"""SMM data set of section V on a tiny planar 3R grid: clusters, classes, Fourier, .npz."""
import numpy as np
import pytest
import torch

from armbridge.errors import ArmbridgeError
from armbridge.smm import dataset, fourier
from armbridge.robots.dh import DHChain
from armbridge.smm.arms import get_smm_arm
from armbridge.smm.grid import REGION_SHAPE, GridSpec, default_grid, region_locations

torch.set_num_threads(1)
K = 40
N = 128


@pytest.fixture(scope="module")
def build():
    arm = get_smm_arm("planar3r")
    grid = GridSpec((0.0,), (3.3,), (40,))  # links of 1 m: singular radii 1 and 3, reach 3
    calls = []
    b = dataset.build_dataset(arm, grid, K=K, N=N, batch=16, progress=lambda d, t: calls.append((d, t)),
                              seeds=12, device="cpu")
    return b, calls


def test_progress_is_reported_per_batch(build):
    b, calls = build
    assert calls[:3] == [(16, 40), (32, 40), (40, 40)]  # the grid, then the boundary points
    points = b.dataset.boundary_canon.shape[0]
    assert points and calls[3:] == [(min(s + 16, points), points) for s in range(0, points, 16)]


def planar3r_branch_count(r: np.ndarray) -> np.ndarray:
    """Links of 1 m: two SMM branches inside r = 1, one out to r = 3, none beyond."""
    return np.select([r < 1, r < 3], [2, 1], 0)


def test_labels_follow_the_nullspace_branch_count(build):
    """Every labelled cell and boundary point gets a cluster with its own branch count;
    clustered cells keep their cluster (cells outside: test_smm_automaton)."""
    b, _ = build
    ds = b.dataset
    assert np.array_equal(ds.label[ds.cluster >= 0], ds.cluster[ds.cluster >= 0])
    ok = ds.label >= 0
    assert np.array_equal(ds.cluster_branches[ds.label[ok]], b.smms.count[ok])
    # boundary points: 4 per boundary cell, inside it, labelled by the analytic count
    cells = dataset.boundary_cells(b.clusters, b.smms.count)
    assert ds.boundary_canon.shape == (4 * cells.size, 1)
    width = 3.3 / 40
    home = np.floor(ds.boundary_canon[:, 0] / width).astype(int)
    assert np.array_equal(home, np.repeat(cells, 4))
    r = ds.boundary_canon[:, 0]
    near_fold = np.min(np.abs(r[:, None] - np.array([1.0, 3.0])), axis=1) < 2e-3  # traced count unsure there
    lab = (ds.boundary_label >= 0) & ~near_fold
    assert lab.sum() > 0.8 * r.size
    assert np.array_equal(ds.cluster_branches[ds.boundary_label[lab]], planar3r_branch_count(r[lab]))
    canon, label = ds.classifier_data(np.flatnonzero(ok))
    assert canon.shape[0] == ok.sum() + (ds.boundary_label >= 0).sum() and (label >= 0).all()


def test_clusters_are_contiguous_radial_bands(build):
    b, _ = build
    ds = b.dataset
    r = ds.canon[:, 0]
    assert np.all(np.diff(r) > 0)
    for c in range(ds.cluster_branches.size):
        cells = np.flatnonzero(ds.cluster == c)
        assert cells.size and np.array_equal(cells, np.arange(cells[0], cells[-1] + 1))
    # inside r = 1: elbow up and down apart (2); between 1 and 3: one loop; past 3: out of reach
    order = [int(ds.cluster_branches[c]) for c in dict.fromkeys(ds.cluster[ds.cluster >= 0])]
    assert order == [2, 1, 0]
    assert ds.cluster_branches[ds.cluster[r < 0.9]].tolist() == [2] * int(np.sum(r < 0.9))
    assert (ds.cluster_branches[ds.cluster[r > 3.05]] == 0).all()


def test_every_clustered_cell_has_its_clusters_branch_count(build):
    b, _ = build
    ds, smms = b.dataset, b.smms
    ok = ds.cluster >= 0
    assert np.array_equal(smms.count[ok], ds.cluster_branches[ds.cluster[ok]])
    slots = np.arange(ds.coeffs.shape[1])
    filled = np.isfinite(ds.coeffs).all(axis=(2, 3))
    assert np.array_equal(filled, ok[:, None] & (slots < smms.count[:, None]))


def test_decoded_coefficients_reproduce_the_nullspace_branches(build):
    b, _ = build
    ds, smms, order = b.dataset, b.smms, b.homotopy.order
    errs = []
    for l, s in zip(*np.nonzero(np.isfinite(ds.coeffs).all(axis=(2, 3)))):
        pts = smms.points[l, order[l, s]]
        joint, freq = b.reference[:, ds.cluster[l], s]
        dk = fourier.phase_shift(fourier.dft(pts), True, joint, freq)  # undo the fractional start shift
        back = ds.coeffs[l, s] * np.exp(2j * np.pi * fourier.frequencies(K) * dk / N)
        errs.append(fourier.joint_error(fourier.decode(back, N), pts).mean())
    assert len(errs) > 30
    assert np.mean(errs) < 6e-4  # Fig. 3 for the 3R at K = 40: below 6e-4 rad on average
    assert max(errs) < 5e-3  # the worst is the cell next to the singular radius r = 1


def test_phase_reference_avoids_vanishing_harmonics(build):
    """Inside r = 1 one of the two 3R branches turns joint 1 backwards: its f = +1
    content is ~0, so the reference there is f = -1 (or another joint)."""
    b, _ = build
    ds = b.dataset
    inner = ds.cluster[0]
    assert ds.cluster_branches[inner] == 2
    assert np.all(b.margin[inner, :2] > 0.2)
    mags = dataset.harmonics(b.smms, ds.cluster, b.homotopy.order)[ds.cluster == inner]
    assert np.nanmin(mags[:, :, 0, 0]) < 0.05  # the paper's reference vanishes on one branch
    co = ds.coeffs[ds.cluster == inner, :2]
    assert np.abs(np.diff(co, axis=0)).max() / N < 0.2  # neighbouring cells: close spectra


def test_homotopy_slots_deform_continuously(build):
    b, _ = build
    ds = b.dataset
    two = np.flatnonzero((ds.cluster >= 0) & (ds.cluster_branches[np.maximum(ds.cluster, 0)] == 2))
    q = fourier.decode(ds.coeffs[two, :2], N)  # (cells, 2, N, 3)
    same = fourier.joint_error(q[1:], q[:-1]).mean(axis=(-1, -2))
    swapped = fourier.joint_error(q[1:, ::-1], q[:-1]).mean(axis=(-1, -2))
    assert (same < swapped).all()
    assert b.homotopy.cost[two].max() < 0.2


def test_save_load_round_trip(build, tmp_path):
    ds = build[0].dataset
    ds.save(tmp_path / "smm.npz")
    back = dataset.SmmDataset.load(tmp_path / "smm.npz")
    assert back.robot == "planar3r" and back.K == K and back.N == N
    for f in ("canon", "cluster", "label", "coeffs", "cluster_branches", "boundary_canon", "boundary_label"):
        assert np.array_equal(getattr(back, f), getattr(ds, f), equal_nan=True)
        assert getattr(back, f).dtype == getattr(ds, f).dtype
    with np.load(tmp_path / "smm.npz") as z:
        assert sorted(z.files) == sorted(dataset.FIELDS)


def test_bad_input_is_an_armbridge_error(tmp_path):
    arm = get_smm_arm("planar3r")
    with pytest.raises(ArmbridgeError, match="lo < hi"):
        GridSpec((1.0,), (0.0,), (10,))
    with pytest.raises(ArmbridgeError, match="dimensions"):
        dataset.build_dataset(arm, GridSpec((0.0, 0.0), (1.0, 1.0), (2, 2)))
    with pytest.raises(ArmbridgeError, match="K"):
        dataset.build_dataset(arm, GridSpec((0.0,), (1.0,), (2,)), K=0)
    s7 = get_smm_arm("spatial7r")
    rolled = DHChain(name="pose7", a=np.r_[s7.a[:-1], 0.1], alpha=s7.alpha, d=s7.d, theta=s7.theta, space="pose")
    with pytest.raises(ArmbridgeError, match="explicit GridSpec"):
        default_grid(rolled)  # its last joint moves the tip: 5 canonical numbers
    with pytest.raises(ArmbridgeError, match="4 cell counts"):
        default_grid(s7, shape=(3, 3))
    (tmp_path / "x.npz").write_bytes(b"not a zip")
    with pytest.raises(ArmbridgeError, match="cannot read"):
        dataset.SmmDataset.load(tmp_path / "x.npz")
    np.savez(tmp_path / "y.npz", robot="planar3r")
    with pytest.raises(ArmbridgeError, match="missing"):
        dataset.SmmDataset.load(tmp_path / "y.npz")


def test_the_7r_grid_is_one_region_times_every_tool_direction():
    arm = get_smm_arm("spatial7r")
    g = default_grid(arm)
    assert g.shape == REGION_SHAPE
    assert g.lo[2:] == (0.0, -np.pi) and g.hi[2:] == (np.pi, np.pi)
    assert g.hi[0] - g.lo[0] == pytest.approx(0.2) and g.hi[1] - g.lo[1] == pytest.approx(0.2)
    c = region_locations(g, 1000, seed=3)
    assert (c >= np.array(g.lo)).all() and (c <= np.array(g.hi)).all()


def test_default_grids_cover_the_workspace_with_a_margin():
    g3 = default_grid(get_smm_arm("planar3r"))
    assert g3.shape == (200,) and g3.lo == (0.0,) and 3.0 < g3.hi[0] < 3.3
    g4 = default_grid(get_smm_arm("spatial4r"), shape=(25, 40))
    assert g4.shape == (25, 40) and g4.lo[0] == 0.0 and g4.lo[1] < 0 < g4.hi[1]
    assert g4.centres().shape == (1000, 2)


def test_fig3_error_falls_with_K():
    err = dataset.fig3(get_smm_arm("planar3r"), Ks=(10, 20, 40), locations=6, seeds=12, device="cpu")
    assert np.all(np.diff(err) < 0) and err[-1] < 1e-3
