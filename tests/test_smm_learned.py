"""Learned SMMs: networks and losses (eq. 15-17), training, ONNX export, card,
LearnedSmm inference with the eq. (18) correction, and user errors."""
from __future__ import annotations

import json
import shutil
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from require import missing
from typer.testing import CliRunner

try:
    import onnxruntime  # noqa: F401
    import torch
except ImportError as exc:
    missing(f"{exc.name} is not installed (`make setup` installs the [train] extra)")

from armbridge.errors import ArmbridgeError
from armbridge.robots.dh import DHChain
from armbridge.smm import fourier
from armbridge.smm import networks as nets
from armbridge.smm.arms import get_smm_arm
from armbridge.smm.dataset import SmmDataset
from armbridge.smm.correction import correct, damped_pinv_step, error_and_step
from armbridge.smm.learned import CARD_NAME, LearnedSmm
from armbridge.train import smm as tr
from armbridge.train import smm_data, smm_fit

pytestmark = pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::UserWarning")  # torch.onnx internals

ARM = get_smm_arm("planar3r")
N, K = 64, 16
TINY = smm_fit.SmmTrainConfig(cls_hidden=(8, 8), reg_hidden=(32, 32), epochs=40, min_steps=600, batch=32, seed=1)


@pytest.fixture(autouse=True)
def _one_thread():
    saved = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(saved)


def planar3r_branches(r: float, n_points: int = N) -> np.ndarray:
    """The two SMM branches (2, N, 3) of the unit-link planar 3R at (r, 0) for r < 1, in closed form.

    psi is the direction of link 3; links 1-2 reach the wrist w = x - e(psi)
    with elbow +-acos((|w|^2 - 2) / 2), which never hits 0 or pi for r < 1.
    """
    psi = np.linspace(0, 2 * np.pi, n_points, endpoint=False)
    w = np.stack([r - np.cos(psi), -np.sin(psi)], -1)
    c2 = (np.sum(w**2, -1) - 2) / 2
    out = []
    for sign in (1, -1):
        t2 = sign * np.arccos(np.clip(c2, -1, 1))
        t1 = np.arctan2(w[:, 1], w[:, 0]) - np.arctan2(np.sin(t2), 1 + np.cos(t2))
        out.append(np.stack([t1, t2, psi - t1 - t2], -1))
    return np.angle(np.exp(1j * np.stack(out)))


def null_vectors(q: np.ndarray) -> np.ndarray:
    """Eq. (6) for a 2x3 Jacobian: the cross product of its rows."""
    j = ARM.jacobian(q)
    return np.cross(j[..., 0, :], j[..., 1, :])


def synthetic_dataset() -> SmmDataset:
    """Closed-form SMMs: cluster 0 (r < 1, two branches), cluster 1 (r > 3, out of reach)."""
    r_in = np.linspace(0.1, 0.9, 60)
    r_out = np.linspace(3.05, 3.4, 20)
    pts = np.stack([planar3r_branches(r) for r in r_in])  # (60, 2, N, 3)
    coeffs = fourier.lowpass(fourier.encode(fourier.orient(pts, null_vectors(pts))), K)
    all_coeffs = np.full((80, 2, 3, K), np.nan + 0j)
    all_coeffs[:60] = coeffs
    cluster = np.r_[np.zeros(60, np.int64), np.ones(20, np.int64)]
    return SmmDataset(robot="planar3r", canon=np.concatenate([r_in, r_out])[:, None],
                      cluster=cluster, label=cluster, coeffs=all_coeffs, cluster_branches=np.array([2, 0]),
                      boundary_canon=np.zeros((0, 1)), boundary_label=np.zeros(0, np.int64), K=K, N=N)


@pytest.fixture(scope="module")
def ds() -> SmmDataset:
    return synthetic_dataset()


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory, ds) -> Any:
    out = tmp_path_factory.mktemp("smm") / "smm-planar3r"
    work = out.parent / "work"
    cfg = tr.PipelineConfig(robot="planar3r", train=TINY, dataset=work / "none.npz", out=out, work_dir=work,
                            eval_points=N, correct_iters=3)
    torch.set_num_threads(1)
    card = tr.run(cfg, ds, progress=False, device=torch.device("cpu"))
    return SimpleNamespace(path=out, card=card)


# ------------------------------------------------------------------ networks


def test_target_layout_round_trips():
    rng = np.random.default_rng(0)
    c = rng.normal(size=(5, 2, 3, 7)) + 1j * rng.normal(size=(5, 2, 3, 7))
    y = nets.coeffs_to_target(c)
    assert y.shape == (5, 2 * 3 * 7 * 2)
    assert y[1, 1] == c[1, 0, 0, 0].imag  # (branch, joint, k, [re, im])
    np.testing.assert_array_equal(nets.target_to_coeffs(y, 2, 3, 7), c)


def test_paper_sizes_and_scaled_inputs():
    assert nets.default_architecture(4) == nets.Architecture((50, 50, 50), (150,) * 5)
    with pytest.raises(ArmbridgeError, match="5-joint"):
        nets.default_architecture(5)
    lo, hi = nets.input_box(np.array([[0.0, 2.0], [4.0, 2.0]]))
    clf = nets.SmmClassifier(lo, hi, (4,), 3)
    f = clf.features(torch.tensor([[0.0, 2.0], [4.0, 2.0]]))
    np.testing.assert_allclose(f.numpy(), [[-1, 0], [1, 0]])  # a constant coordinate maps to 0
    assert isinstance(clf.body[1], torch.nn.LeakyReLU)


def test_a_periodic_coordinate_is_one_place_at_both_ends():
    """The 7R's azimuth enters as (cos, sin): -pi and pi (and az and az + 2 pi) are the same input,
    which the raw scaled angle would put at the two ends of the box."""
    lo, hi = np.array([0.0, 0.0, 0.0, -np.pi]), np.array([1.0, 1.0, np.pi, np.pi])
    torch.manual_seed(0)
    clf = nets.SmmClassifier(lo, hi, (8,), 3, periodic=(False, False, False, True))
    assert clf.body[0].in_features == 5
    x = torch.tensor([[0.5, 0.5, 1.0, -np.pi], [0.5, 0.5, 1.0, 0.3]])
    y = x.clone()
    y[:, 3] += 2 * np.pi  # pi, and 0.3 + 2 pi
    torch.testing.assert_close(clf(x), clf(y))
    raw = nets.SmmClassifier(lo, hi, (8,), 3)
    assert raw.body[0].in_features == 4 and not torch.allclose(raw.features(x[:1]), raw.features(y[:1]))
    with pytest.raises(ArmbridgeError, match="3 flags for 4"):
        nets.SmmClassifier(lo, hi, (8,), 3, periodic=(False, False, True))


def test_regressor_scaling_keeps_eq17_up_to_a_constant():
    rng = np.random.default_rng(1)
    y = rng.normal(size=(50, 6)) * [10, 10, 1, 1, 0.01, 0.01] + 3
    mean, scale = nets.output_scaling(y)
    reg = nets.SmmRegressor(np.zeros(1), np.ones(1), (4,), mean, scale)
    yt, pt = torch.as_tensor(y, dtype=torch.float32), torch.as_tensor(y[::-1].copy(), dtype=torch.float32)
    ratio = nets.regressor_loss(reg.normalise(pt), reg.normalise(yt)) / nets.regressor_loss(pt, yt)
    assert ratio.item() == pytest.approx(1 / scale**2, rel=1e-4)
    x = torch.rand(3, 1)
    torch.testing.assert_close(reg(x), reg.mean + reg.scale * reg.normalised(x))


# ------------------------------------------------------------------ training


@pytest.fixture(scope="module")
def tiny(ds) -> Any:
    rows, _ = smm_data.split(ds.cluster, 0.1, 0)
    return SimpleNamespace(rows=rows, trained=smm_fit.train(ds, rows, TINY, progress=False, device=torch.device("cpu")))


def same_weights(a: smm_fit.Trained, b: smm_fit.Trained) -> bool:
    nets_a = [a.classifier, *a.regressors.values()]
    nets_b = [b.classifier, *b.regressors.values()]
    return all(torch.equal(pa, pb) for na, nb in zip(nets_a, nets_b) for pa, pb in zip(na.parameters(), nb.parameters()))


def test_tiny_training_lowers_both_losses_and_is_deterministic(ds, tiny):
    for key in ("classifier", "regressor-0"):
        h = tiny.trained.history[key]
        assert h[-1]["loss"] < 0.5 * h[0]["loss"], key
    assert set(tiny.trained.regressors) == {0}  # cluster 1 is out of reach: no regressor
    again = smm_fit.train(ds, tiny.rows, TINY, progress=False, device=torch.device("cpu"))
    assert same_weights(again, tiny.trained)


def test_resume_after_an_interruption_gives_the_same_networks(ds, tiny, tmp_path):
    ck = tmp_path / "ck.pt"

    def stop(msg: str) -> None:
        if msg.startswith("classifier"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        smm_fit.train(ds, tiny.rows, TINY, checkpoint=ck, progress=False, log=stop, device=torch.device("cpu"))
    logs: list[str] = []
    resumed = smm_fit.train(ds, tiny.rows, TINY, checkpoint=ck, resume=True, progress=False, log=logs.append,
                            device=torch.device("cpu"))
    assert logs[0].startswith("resumed") and "1 of 2" in logs[0]
    assert same_weights(resumed, tiny.trained)
    other = smm_fit.SmmTrainConfig(**{**TINY.__dict__, "seed": 2})
    with pytest.raises(ArmbridgeError, match="other settings"):
        smm_fit.train(ds, tiny.rows, other, checkpoint=ck, resume=True, progress=False, device=torch.device("cpu"))


def test_split_holds_out_a_share_of_every_cluster_and_skips_singular():
    cluster = np.array([-1] * 5 + [0] * 20 + [1] * 10 + [2])
    train, test = smm_data.split(cluster, 0.2, 0)
    assert not set(train) & set(test)
    assert np.bincount(cluster[test], minlength=3).tolist() == [4, 2, 0]
    assert set(np.flatnonzero(cluster == 2)) <= set(train)
    assert (cluster[np.r_[train, test]] >= 0).all()


def test_bad_settings_are_user_errors():
    with pytest.raises(ArmbridgeError, match="--epochs"):
        smm_fit.SmmTrainConfig(cls_hidden=(5,), reg_hidden=(5,), epochs=0)
    with pytest.raises(ArmbridgeError, match="--lr-decay"):
        smm_fit.SmmTrainConfig(cls_hidden=(5,), reg_hidden=(5,), lr_decay=0)
    assert smm_fit.parse_sizes("4x150", "--reg-hidden") == (150,) * 4
    with pytest.raises(ArmbridgeError, match="--cls-hidden"):
        smm_fit.parse_sizes("5,a", "--cls-hidden")


# ------------------------------------------------------------ export and card


def test_export_matches_torch_and_card_is_complete(model_dir):
    card = model_dir.card
    assert card["accuracy"]["onnx_vs_torch_max_rel"] < 1e-5
    assert card["robot"] == "planar3r" and card["fourier"]["K"] == K
    assert card["clusters"]["branches"] == [2, 0] and card["clusters"]["out_of_reach"] == [1]
    assert sorted(card["files"]["regressors"]) == ["0"]
    held = card["accuracy"]["held_out"]
    assert held["locations"] == 8
    assert 0 <= held["branch_count_mismatch_pct"] <= 100 - held["classifier_accuracy_pct"] + 1e-9
    assert held["fk_error_pct_after"]["mean"] < held["fk_error_pct_before"]["mean"]
    assert json.loads((model_dir.path / CARD_NAME).read_text()) == json.loads(json.dumps(card))


# ------------------------------------------------------------------ inference


def test_compute_shapes_padding_and_counts(model_dir):
    smm = LearnedSmm.load(model_dir.path, robot="planar3r")
    rng = np.random.default_rng(3)
    r = np.r_[rng.uniform(0.15, 0.85, 6), rng.uniform(3.1, 3.35, 4)]
    phi = rng.uniform(-np.pi, np.pi, r.size)
    x = np.stack([r * np.cos(phi), r * np.sin(phi)], -1)
    s = smm.compute(x, n_points=50)
    assert s.points.shape == (10, 2, 50, 3) and s.count.dtype == np.int64
    np.testing.assert_array_equal(s.count, smm.branches[smm.classify(r[:, None])])
    assert (s.count[:6] == 2).all() and (s.count[6:] == 0).all()  # the tiny classifier gets these clear cases
    assert np.isnan(s.points[6:]).all() and np.isfinite(s.points[:6]).all()
    assert (np.abs(s.points[:6]) <= np.pi).all() and not s.singular.any()


def test_joint1_symmetry_and_correction_lower_the_fk_error(model_dir):
    smm = LearnedSmm.load(model_dir.path)
    r = np.linspace(0.2, 0.8, 5)
    x0 = np.stack([r, np.zeros_like(r)], -1)
    x1 = np.stack([r * np.cos(1.0), r * np.sin(1.0)], -1)
    s0, s1 = smm.compute(x0, n_points=N), smm.compute(x1, n_points=N)
    np.testing.assert_allclose(np.angle(np.exp(1j * (s1.points[..., 0] - s0.points[..., 0]))), 1.0, atol=1e-9)
    before = tr.fk_errors(ARM, s1, x1)
    after = tr.fk_errors(ARM, smm.compute(x1, n_points=N, correct_iters=3), x1)
    assert after.mean() < 1e-3 * before.mean() and after.max() < 1e-9


def test_damped_pinv_step_matches_pinv_for_every_task_size():
    rng = np.random.default_rng(4)
    for m in (2, 3, 6):
        jac = torch.as_tensor(rng.normal(size=(20, m, m + 1)))
        e = torch.as_tensor(rng.normal(size=(20, m)))
        want = (torch.linalg.pinv(jac) @ e.unsqueeze(-1)).squeeze(-1)
        torch.testing.assert_close(damped_pinv_step(jac, e, 0.0), want, rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("name", ["planar3r", "spatial4r", "spatial7r", "arm3r"])
def test_error_and_step_match_the_dh_chain_and_the_pseudoinverse(name):
    arm = get_smm_arm(name)
    rng = np.random.default_rng(7)
    q = torch.as_tensor(rng.uniform(-np.pi, np.pi, (40, arm.n)))
    x = arm.task(q + torch.as_tensor(rng.normal(0, 0.05, q.shape)))
    err = arm.task_error(q, x)
    score, step = error_and_step(arm, q, x, 0.0)
    want = (torch.linalg.pinv(arm.jacobian(q)) @ err.unsqueeze(-1)).squeeze(-1)
    torch.testing.assert_close(step, want, rtol=1e-7, atol=1e-9)
    pos, rot = err[:, : min(arm.m, 3)], err[:, 3:]
    torch.testing.assert_close(score, (pos**2).sum(-1) / arm.reach**2 + (rot**2).sum(-1))
    assert error_and_step(arm, q, x, step=False)[1] is None


def test_correction_never_leaves_a_point_worse():
    q_sing = torch.tensor([[0.3, 1e-7, 1e-7]])  # stretched out: J^+ overshoots
    x = torch.tensor([[2.999, 0.2]])
    q = correct(ARM, q_sing, x, 3)
    assert ARM.fk_error(q, x) <= ARM.fk_error(q_sing, x)


def test_correction_reaches_the_target_from_nearby():
    rng = np.random.default_rng(5)
    q_true = rng.uniform(0.4, 2.7, (100, 3)) * rng.choice([-1, 1], (100, 3))  # away from singular (q2, q3 = 0, pi)
    q_true = torch.as_tensor(q_true)
    x = ARM.task(q_true)
    q = correct(ARM, q_true + 0.05, x, 4)
    assert ARM.fk_error(q, x).max() < 1e-10


# ---------------------------------------------------------------- user errors


def test_missing_corrupt_or_foreign_models_are_user_errors(model_dir, tmp_path):
    with pytest.raises(ArmbridgeError, match="no card.json"):
        LearnedSmm.load(tmp_path / "nowhere")
    with pytest.raises(ArmbridgeError, match="for robot 'planar3r', not 'spatial4r'"):
        LearnedSmm.load(model_dir.path, robot="spatial4r")
    bad = tmp_path / "bad"
    shutil.copytree(model_dir.path, bad)
    (bad / CARD_NAME).write_text("{not json")
    with pytest.raises(ArmbridgeError, match="not a readable model card"):
        LearnedSmm.load(bad)
    shutil.copy(model_dir.path / CARD_NAME, bad / CARD_NAME)
    (bad / "regressor-0.onnx").write_bytes(b"garbage")
    with pytest.raises(ArmbridgeError, match="sha256"):
        LearnedSmm.load(bad)
    with pytest.raises(ArmbridgeError, match="not a loadable ONNX"):
        LearnedSmm.load(bad, verify=False)
    (bad / "regressor-0.onnx").unlink()
    with pytest.raises(ArmbridgeError, match="cannot read the model file"):
        LearnedSmm.load(bad)
    card = json.loads((model_dir.path / CARD_NAME).read_text())
    (bad / CARD_NAME).write_text(json.dumps({**card, "kind": "masr-iknn"}))
    with pytest.raises(ArmbridgeError, match="kind is 'masr-iknn'"):
        LearnedSmm.load(bad)
    (bad / CARD_NAME).write_text(json.dumps({**card, "files": {"classifier": card["files"]["classifier"]}}))
    with pytest.raises(ArmbridgeError, match="files.regressors"):
        LearnedSmm.load(bad)
    smm = LearnedSmm.load(model_dir.path)
    with pytest.raises(ArmbridgeError, match=r"\(L, 2\)"):
        smm.compute(np.zeros((4, 3)))
    with pytest.raises(ArmbridgeError, match="finite"):
        smm.compute(np.array([[np.nan, 0.0]]))


def test_cli_grids_the_7r_region_and_rejects_other_pose_arms():
    s7 = get_smm_arm("spatial7r")
    assert smm_data.grid_for(s7, "").shape == (3, 3, 24, 48) and smm_data.grid_for(s7, "2x2x8x16").shape == (2, 2, 8, 16)
    rolled = DHChain(name="pose7", a=np.r_[s7.a[:-1], 0.1], alpha=s7.alpha, d=s7.d, theta=s7.theta, space="pose")
    with pytest.raises(ArmbridgeError, match="--dataset"):
        smm_data.grid_for(rolled, "")
    with pytest.raises(ArmbridgeError, match="--grid"):
        smm_data.grid_for(ARM, "2x")


# ------------------------------------------------------- end to end, real data


def test_cli_trains_a_tiny_3r_model_from_nullspace_data_and_resumes(tmp_path):
    from armbridge.cli import build_app

    out, work = tmp_path / "smm-planar3r", tmp_path / "work"
    args = ["train", "smm-3r", "--grid", "24", "--epochs", "2", "--min-steps", "60", "--batch", "16",
            "--cls-hidden", "8,8", "--reg-hidden", "2x32", "--no-progress", "--work-dir", str(work), "--out", str(out)]
    res = CliRunner().invoke(build_app(), args)
    assert res.exit_code == 0, res.output
    data = SmmDataset.load(work / "dataset.npz")
    assert data.canon.shape == (24, 1) and set(data.cluster_branches.tolist()) >= {1, 2}
    card = json.loads((out / CARD_NAME).read_text())
    assert card["training"]["command"].startswith("armbridge train smm-3r")
    assert card["dataset"]["locations"] == 24 and card["dataset"]["grid_shape"] == [24]
    smm = LearnedSmm.load(out, robot="planar3r")
    x = fourier_free_locations(smm, 30)
    s = smm.compute(x, correct_iters=2)
    assert s.points.shape == (30, int(max(data.cluster_branches)), 128, 3)
    assert set(s.count.tolist()) <= set(data.cluster_branches.tolist())
    again = CliRunner().invoke(build_app(), [*args, "--resume"])
    assert again.exit_code == 0, again.output
    assert json.loads((out / CARD_NAME).read_text())["files"] == card["files"]  # same networks, same bytes
    bad = CliRunner().invoke(build_app(), ["train", "smm-3r", "--robot", "spatial4r", "--work-dir", str(work)])
    assert bad.exit_code != 0 and "3-joint" in str(bad.exception or bad.output)


def test_cli_trains_a_tiny_7r_region_model_whose_smms_follow_both_symmetries(tmp_path):
    """The 7R's SMM at a location is the canonical one moved by the shift: theta_1 += phi, theta_7 += psi."""
    from armbridge.cli import build_app

    out, work = tmp_path / "smm-spatial7r", tmp_path / "work"
    args = ["train", "smm-7r", "--grid", "1x1x4x8", "--sing-tol", "0.005", "--boundary-points", "0", "--epochs", "2",
            "--min-steps", "20", "--batch", "16", "--cls-hidden", "8", "--reg-hidden", "16", "--no-progress",
            "--work-dir", str(work), "--out", str(out)]
    res = CliRunner().invoke(build_app(), args)
    assert res.exit_code == 0, res.output
    smm = LearnedSmm.load(out, robot="spatial7r")
    arm = smm.arm
    data = SmmDataset.load(work / "dataset.npz")
    c = data.canon[data.cluster >= 0][:6]
    shift = np.zeros((len(c), 7))
    shift[:, 0], shift[:, 6] = np.random.default_rng(1).uniform(-np.pi, np.pi, (2, len(c)))
    base = smm.compute(arm.uncanonical(c), n_points=32)
    moved = smm.compute(arm.uncanonical(c, shift), n_points=32)
    assert np.array_equal(base.count, moved.count) and base.count.min() > 0
    ok = np.isfinite(base.points)
    diff = moved.points[ok] - (base.points + shift[:, None, None, :])[ok]
    assert np.abs(np.angle(np.exp(1j * diff))).max() < 1e-5  # float32 networks, wrapped angles
    turned = c.copy()
    turned[:, 3] += 2 * np.pi  # the exported graphs take the azimuth as (cos, sin): a turn is no change
    label = smm.classify(c)
    assert np.array_equal(smm.classify(turned), label)
    np.testing.assert_allclose(smm.coefficients(int(label[0]), turned[:1]), smm.coefficients(int(label[0]), c[:1]),
                               rtol=1e-5, atol=1e-5)


def fourier_free_locations(smm: LearnedSmm, count: int) -> np.ndarray:
    """Tips of random configurations of the model's arm."""
    q = np.random.default_rng(6).uniform(-np.pi, np.pi, (count, smm.arm.n))
    return np.asarray(smm.arm.task(q))


# ------------------------------------------------------------------ the shipped models

SHIPPED = sorted(p.parent for p in (Path(__file__).parents[1] / "models" / "onnx").glob("smm-*/card.json"))


def test_the_3r_and_4r_models_are_shipped():
    assert {"smm-planar3r", "smm-arm3r", "smm-spatial4r"} <= {p.name for p in SHIPPED}


@pytest.mark.parametrize("folder", SHIPPED, ids=lambda p: p.name)
def test_shipped_model_meets_its_card_on_fresh_locations(folder):
    """A quality gate: fresh random locations (not grid cells), against the nullspace ground truth."""
    from armbridge.smm import nullspace
    from armbridge.smm.grid import random_locations

    model = LearnedSmm.load(folder)  # checks every file's sha256
    held = model.card["accuracy"]["held_out"]
    x = random_locations(model.arm, 150, seed=4321)
    truth = nullspace.compute(model.arm, x)
    before = model.compute(x)
    after = model.compute(x, correct_iters=3)
    mismatch = np.mean(before.count != truth.count) * 100
    # 150 locations: allow the card's held-out mismatch plus 5 points (a binomial SE of ~2 at 5 %)
    assert mismatch <= held["branch_count_mismatch_pct"] + 5
    same = (before.count == truth.count) & (truth.count > 0)
    err_before = tr.fk_errors(model.arm, _subset(before, same), x[same]) * 100
    err_after = tr.fk_errors(model.arm, _subset(after, same), x[same]) * 100
    assert err_before.mean() <= held["fk_error_pct_before"]["mean"] * 1.5 + 0.05
    assert err_after.mean() < err_before.mean() and err_after.mean() <= max(
        held["fk_error_pct_after"]["mean"] * 10, 1e-3)


def _subset(s, rows):
    from armbridge.smm.manifold import SmmSet

    return SmmSet(s.points[rows], s.count[rows], s.singular[rows])
