"""The 3R drawing arm's IK pipeline (Murai, Vairagi, Semwal): ANN (Table 2), FABRIK
(section 3.6), the CBF-QP filter (eq. 6-9), the shipped model against its card and
`armbridge train arm3r-ik`."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from require import missing

try:
    import onnxruntime  # noqa: F401
    import qpsolvers  # noqa: F401
except ImportError as exc:
    missing(f"{exc.name} is not installed (`make setup` installs it)")

from armbridge.errors import ArmbridgeError  # noqa: E402
from armbridge.ik import arm3r_pipeline as pipe  # noqa: E402
from armbridge.ik.analytic3r import ik as closed_form  # noqa: E402
from armbridge.ik.arm3r_ann import Arm3rANN, fk_samples, sha256, tip_errors  # noqa: E402
from armbridge.ik.cbf import (  # noqa: E402
    CbfConfig,
    barrier_values,
    filter_velocity,
    lyapunov,
    track,
)
from armbridge.ik.fabrik import clip_angle, fabrik, fabrik_oriented  # noqa: E402
from armbridge.ik.region import SafeRegion, pen_angle, safe_region  # noqa: E402
from armbridge.robots import get_robot  # noqa: E402

ARM = get_robot("arm3r")
ROOT = Path(__file__).resolve().parents[1]
CARD = ROOT / "models" / "onnx" / "arm3r-ik" / "card.json"
PI = np.pi
REGION = safe_region(ARM)  # the drawing's disc is the CBF's safe set
THETA = pen_angle(ARM)


def disc_points(count: int, seed: int, region: SafeRegion = REGION, frac: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    r = frac * region.radius * np.sqrt(rng.random(count))
    a = rng.random(count) * 2 * PI
    return np.asarray(region.center) + np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)


def safe_starts(xy: np.ndarray) -> np.ndarray:
    """Configurations with the tip on xy (in the disc) at the pen angle: the closed form."""
    q, ok = closed_form(ARM, np.concatenate([xy, np.full((len(xy), 1), THETA)], axis=1))
    assert ok.all()
    return q


# ------------------------------------------------------------------ FABRIK


def test_clip_angle_hand_cases():
    lo, hi = 0.0, PI
    a = np.array([0.5, -0.1, -3.0, 2 * PI + 0.5, PI + 0.1, 1.5 * PI + 0.01])
    # -0.1 is nearer 0; -3.0 (= 3.28) is nearer pi; 2pi + 0.5 is 0.5; 1.5 pi + 0.01 is nearer 2 pi = 0
    np.testing.assert_allclose(clip_angle(a, lo, hi), [0.5, 0.0, PI, 0.5, PI, 0.0], atol=1e-12)


def test_fabrik_hand_worked_target():
    # q = (pi/2, -pi/2, 0): link 1 up to (0, 0.19), links 2 and 3 along +x: the tip at (0.19, 0.19)
    np.testing.assert_allclose(ARM.ee_point([PI / 2, -PI / 2, 0.0]), [0.19, 0.19], atol=1e-15)
    res = fabrik(ARM, [[0.19, 0.19]], [[1.3, -1.2, 0.4]], tol=1e-9)
    assert res.ok[0] and res.error[0] <= 1e-9 and res.iterations[0] < 50
    np.testing.assert_allclose(ARM.ee_point(res.q[0]), [0.19, 0.19], atol=1e-9)
    assert ARM.within_limits(res.q).all()


def test_fabrik_converges_on_reachable_targets():
    poses, q = fk_samples(ARM, 3000, 11)
    margin = np.min(np.minimum(q - ARM.q_min, ARM.q_max - q), axis=1)
    r = np.linalg.norm(poses[:, :2], axis=1)
    keep = (margin > 0.2) & (r > 0.05) & (r < 0.33)  # away from the limits, the base and full stretch
    t, q_true = poses[keep, :2], q[keep]
    init = q_true + np.random.default_rng(12).normal(0, 0.15, q_true.shape)
    res = fabrik(ARM, t, init, tol=1e-6, max_iter=100)
    assert res.reachable.all()
    # a few targets near a limit fold the chain onto its limits from a 0.15 rad-off start (measured 98.1 %)
    assert res.converged.mean() >= 0.97, res.converged.mean()
    assert ARM.within_limits(res.q).all()
    np.testing.assert_allclose(tip_errors(ARM, res.q, t)[res.converged], res.error[res.converged], atol=1e-12)
    assert res.error[res.converged].max() <= 1e-6


def test_fabrik_converges_everywhere_in_the_drawing_disc():
    xy = disc_points(3000, 21)
    q_true = safe_starts(xy)
    init = q_true + np.random.default_rng(22).normal(0, 0.15, q_true.shape)
    res = fabrik(ARM, xy, init, tol=1e-6)
    assert res.ok.all() and res.error.max() <= 1e-6 and ARM.within_limits(res.q).all()


def test_fabrik_reports_unreachable_targets():
    far = np.array([[0.5, 0.1], [0.0, 0.39]])         # beyond the reach 0.38 m
    outside = np.array([[0.0, -0.2]])                 # within reach, not with q1 in [0, pi]
    res = fabrik(ARM, np.concatenate([far, outside]), np.tile([1.0, -1.0, 0.3], (3, 1)))
    assert res.reachable.tolist() == [False, False, True]
    assert not res.converged.any() and not res.ok.any()
    # beyond the reach: stretched at the target, q1 = its bearing (clipped into [0, pi])
    np.testing.assert_allclose(res.q[:2, 1:], 0.0)
    np.testing.assert_allclose(res.q[:2, 0], [np.arctan2(0.1, 0.5), PI / 2])
    assert res.iterations[:2].tolist() == [0, 0]
    assert res.error[2] > 0.05 and ARM.within_limits(res.q).all()


def test_fabrik_oriented_hand_worked_target():
    # tip (0.19, 0.19) at phi = 0: the wrist joint on (0.12, 0.19), links 1-2 solved there, q3 = -(q1 + q2)
    res = fabrik_oriented(ARM, [[0.19, 0.19]], 0.0, [[1.3, -1.2, 0.4]], tol=1e-9)
    assert res.ok[0] and res.oriented[0] and res.error[0] <= 1e-9
    np.testing.assert_allclose(res.q[0], [PI / 2, -PI / 2, 0.0], atol=1e-8)
    assert abs(res.q[0].sum()) < 1e-12
    np.testing.assert_allclose(ARM.joint_points(res.q[0])[2], [0.12, 0.19], atol=1e-9)


def test_fabrik_oriented_holds_the_pen_angle_in_the_drawing_disc():
    """Every point of the disc at the pen angle: the tip within tol, theta = q1 + q2 + q3 exact, the
    joints inside the limits, the same answer as the closed form (arm3r has one elbow branch)."""
    xy = disc_points(3000, 23)
    q_true = safe_starts(xy)
    init = q_true + np.random.default_rng(24).normal(0, 0.15, q_true.shape)
    res = fabrik_oriented(ARM, xy, THETA, init, tol=1e-6, max_iter=200)
    assert res.ok.all() and res.oriented.all() and res.error.max() <= 1e-6 and ARM.within_limits(res.q).all()
    assert np.abs(res.q.sum(axis=1) - THETA).max() < 1e-12
    np.testing.assert_allclose(res.q, q_true, atol=1e-4)
    # FABRIK on position alone reaches the same points but spends the orientation
    free = fabrik(ARM, xy, init, tol=1e-6)
    assert free.ok.all() and np.rad2deg(np.sqrt(np.mean((free.q.sum(axis=1) - THETA) ** 2))) > 1.25


def test_fabrik_oriented_reports_what_it_cannot_hold():
    # (0.30, 0.05) at phi = pi: the wrist point (0.37, 0.05) is beyond l1 + l2 = 0.31 m (step 2 fails);
    # (0.25, 0) at phi = pi/2: the wrist point (0.25, -0.07) is within reach, not with q1 in [0, pi]
    t = np.array([[0.30, 0.05], [0.25, 0.0]])
    phi = np.array([PI, PI / 2])
    res = fabrik_oriented(ARM, t, phi, np.tile([1.0, -1.0, 0.3], (2, 1)))
    assert res.reachable.tolist() == [False, True]
    assert not res.converged.any() and not res.oriented.any() and ARM.within_limits(res.q).all()
    assert (res.error > 0.01).all()
    assert not closed_form(ARM, np.c_[t, phi])[1].any()  # the closed form agrees: no answer at phi
    with pytest.raises(ArmbridgeError, match=r"targets must have shape \(B, 2\)"):
        fabrik_oriented(ARM, [0.1, 0.2], 0.0, [[0.0, 0.0, 0.0]])
    with pytest.raises(ArmbridgeError, match="q_init must have shape"):
        fabrik_oriented(ARM, [[0.1, 0.2]], 0.0, [[0.0, 0.0]])


def test_fabrik_bad_shapes_are_one_clear_error():
    with pytest.raises(ArmbridgeError, match=r"targets must have shape \(B, 2\)"):
        fabrik(ARM, [0.1, 0.2], [[0.0, 0.0, 0.0]])
    with pytest.raises(ArmbridgeError, match="q_init must have shape"):
        fabrik(ARM, [[0.1, 0.2]], [[0.0, 0.0]])


# ------------------------------------------------------------------ CBF


def test_cbf_closed_forms_and_exact_match_osqp():
    """Every branch of the QP (free, box, circle, both) against OSQP on the same rows."""
    rng = np.random.default_rng(5)
    q0 = safe_starts(disc_points(300, 6))
    # states pushed onto the boundary and the joint limits by far references
    q = track(ARM, REGION, q0, rng.uniform(-4, 4, q0.shape), 40).q
    u_nom = 5.0 * (rng.uniform(-4, 4, q.shape) - q)
    u_nom[:50] *= 1e-3                                  # small: the box and circle never bind
    ue, se = filter_velocity(ARM, REGION, q, u_nom, solver="exact")
    uo, so = filter_velocity(ARM, REGION, q, u_nom, solver="osqp")
    assert se["box_or_free"] > 0 and se["circle"] > 0 and se["both_exact"] > 0 and se["osqp"] == 0
    assert so["osqp"] == se["both_exact"]
    np.testing.assert_allclose(ue, uo, atol=1e-7)
    # the constraints (9) hold for the answer
    cfg = CbfConfig()
    h = barrier_values(ARM, REGION, q)
    assert np.all(ue >= -cfg.gamma * h[:, 1:4] - 1e-12) and np.all(ue <= cfg.gamma * h[:, 4:] + 1e-12)
    assert np.all(np.abs(ue) <= ARM.v_max + 1e-12)


def test_cbf_single_circle_constraint_hand_case():
    """Tip on the boundary, pushed straight out: the circle's closed form removes exactly the
    outward part (h = 0, so a u >= 0), and with gamma h > 0 inside leaves u alone."""
    cx, cy = REGION.center
    q = safe_starts(np.array([[cx, cy + REGION.radius - 1e-12], [cx, cy]]))
    tip, jac = ARM.ee_point(q), ARM.jacobian(q)[:, :2, :]
    out = np.linalg.pinv(jac[0]) @ np.array([0.0, 0.01])     # 1 cm/s straight up (out of the disc)
    u, stats = filter_velocity(ARM, REGION, q, np.stack([out, out]))
    a = -2 * (tip[0] - np.array(REGION.center)) @ jac[0]
    assert stats["circle"] == 1 and a @ u[0] >= -1e-9 and abs(a @ u[0]) < 1e-9
    np.testing.assert_allclose(u[1], out)                     # at the centre nothing binds


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), gamma=st.floats(1.0, 100.0), gain=st.floats(0.5, 50.0),
       spread=st.floats(0.1, 6.0), frac=st.floats(0.0, 1.0))
def test_cbf_never_leaves_the_safe_set(seed, gamma, gain, spread, frac):
    """Random safe starts, references anywhere (outside the disc and the limits too): every
    step stays in C (eq. 6) and V never rises."""
    rng = np.random.default_rng(seed)
    q0 = safe_starts(disc_points(64, seed, frac=frac))
    q_ref = rng.uniform(-spread, spread, q0.shape) + q0
    cfg = CbfConfig(gamma=gamma, gain=gain, dt=min(0.01, 1 / gamma, 1.9 / gain))
    res = track(ARM, REGION, q0, q_ref, 40, cfg)
    assert res.h_min.min() >= 0 and res.limit_margin_min.min() >= 0
    assert np.all(np.diff(res.V, axis=0) <= 1e-12 * res.V[:-1] + 1e-15)


def test_cbf_tracks_a_safe_reference_and_lyapunov_decreases():
    q0 = safe_starts(disc_points(200, 8))
    q1 = safe_starts(disc_points(200, 9))
    res = track(ARM, REGION, q0, q1, 300)
    assert np.all(np.diff(res.V, axis=0) <= 0)
    assert res.V[-1].max() < 1e-10 * max(res.V[0].max(), 1e-9) + 1e-12
    np.testing.assert_allclose(res.q, q1, atol=1e-5)
    np.testing.assert_allclose(lyapunov(res.q, q1, (1, 1, 1)), res.V[-1])


def test_cbf_refuses_an_unsafe_start_and_bad_settings():
    with pytest.raises(ArmbridgeError, match="outside the safe set"):
        track(ARM, REGION, [[PI / 2, 0.0, 0.0]], [[PI / 2, 0.0, 0.0]], 5)  # tip at (0, 0.38): outside
    with pytest.raises(ArmbridgeError, match="gamma\\*dt <= 1"):
        CbfConfig(gamma=200.0)
    with pytest.raises(ArmbridgeError, match="radius > 0"):
        SafeRegion((0.0, 0.2), 0.0)


# ------------------------------------------------------------------ the shipped model


@pytest.fixture(scope="module")
def ann():
    return Arm3rANN.load(CARD)  # checks the float model's sha256


def test_shipped_model_meets_its_card(ann):
    card = json.loads(CARD.read_text())
    for entry in card["files"].values():
        assert sha256(CARD.parent / entry["path"]) == entry["sha256"]
    assert card["robot"] == ARM.to_dict()
    acc = card["accuracy"]
    fresh = pipe.drawing_samples(ARM, 4000, seed=424242)  # not the card's seed
    m = pipe.measure(ARM, ann.predict, fresh)
    disc = acc["drawing_disc"]
    assert m["ann"]["tip"]["mean_mm"] <= disc["ann"]["tip"]["mean_mm"] * 1.2 + 0.2
    assert m["ann_fabrik"]["converged_pct"] >= disc["ann_fabrik"]["converged_pct"] - 0.5
    assert m["ann_fabrik"]["tip"]["mean_mm"] < 0.1 and m["ann_fabrik"]["tip"]["max_mm"] <= 1e-3  # tol 1 um
    poses, q = fk_samples(ARM, 4000, 515151)
    whole = pipe.measure(ARM, ann.predict, poses, q)
    assert whole["ann"]["tip"]["mean_mm"] <= acc["test_split"]["ann"]["tip"]["mean_mm"] * 1.2 + 0.2
    assert np.all(np.asarray(whole["ann"]["q_mae_rad"]) <= np.asarray(acc["test_split"]["ann"]["q_mae_rad"]) * 1.2 + 0.005)
    int8 = Arm3rANN.load(CARD, int8=True)
    m8 = pipe.measure(ARM, int8.predict, fresh)
    scheme = acc["int8_onnx"]["scheme"]
    assert m8["ann"]["tip"]["mean_mm"] <= acc["int8_onnx"][scheme]["ann"]["tip"]["mean_mm"] * 1.2 + 0.2
    assert m8["ann_fabrik"]["tip"]["mean_mm"] < 0.1


def test_pipeline_with_cbf_has_no_violations_on_random_targets(ann):
    """Targets anywhere around the disc (four in five outside it): ANN + FABRIK gives the
    reference, the CBF filter drives the arm there from the disc's centre; no step leaves C."""
    rng = np.random.default_rng(77)
    n = 3000
    xy = np.asarray(REGION.center) + rng.uniform(-2 * REGION.radius, 2 * REGION.radius, (n, 2))
    res = pipe.solve(ARM, ann.predict, xy, THETA)
    q0 = np.tile(safe_starts(np.array([REGION.center])), (n, 1))
    out = track(ARM, REGION, q0, res.q, 150)
    assert out.h_min.min() >= 0 and out.limit_margin_min.min() >= 0
    inside = REGION.contains(xy) & res.ok
    assert inside.sum() > n // 8  # the disc is ~20 % of the square
    # targets inside the disc are reached (to the tracking's residual after 1.5 s at K = 5/s)
    assert tip_errors(ARM, out.q[inside], xy[inside]).max() < 2e-3


def test_pipeline_holds_the_pen_angle_and_falls_back_to_position(ann):
    """ANN + FABRIK (`pipe.solve`): in the disc at the pen angle every target is solved with theta
    held; targets no configuration reaches at theta are solved on position alone (oriented False)."""
    xy = np.concatenate([disc_points(500, 31), [[0.30, 0.05], [0.25, 0.0]]])
    theta = np.r_[np.full(500, THETA), PI, PI / 2]
    res = pipe.solve(ARM, ann.predict, xy, theta)
    assert res.ok.all() and res.error.max() <= 1e-6 and ARM.within_limits(res.q).all()
    assert res.oriented[:500].all() and not res.oriented[500:].any()
    assert np.abs(res.q[:500].sum(axis=1) - THETA).max() < 1e-12
    free = pipe.solve(ARM, ann.predict, xy, theta, orient=False)
    assert free.oriented is None and free.ok.all()


def test_ann_bad_input_and_bad_card(tmp_path, ann):
    with pytest.raises(ArmbridgeError, match=r"shape \(\.\.\., 3\)"):
        ann.predict([0.1, 0.2])
    bad = tmp_path / "card.json"
    card = json.loads(CARD.read_text())
    (tmp_path / "float.onnx").write_bytes(b"not a model")
    bad.write_text(json.dumps(card))
    with pytest.raises(ArmbridgeError, match="does not match its card"):
        Arm3rANN.load(bad)


# ------------------------------------------------------------------ armbridge train arm3r-ik


def _armbridge(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("armbridge")
    return subprocess.run([str(exe), *args], cwd=cwd, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"})


def test_train_command_tiny_run_and_force(tmp_path):
    try:
        import torch  # noqa: F401
    except ImportError:
        missing("torch is not installed (`make setup` installs the [train] extra)")
    args = ["train", "arm3r-ik", "--samples", "2000", "--epochs", "1", "--eval-points", "300",
            "--out", "out", "--work-dir", "work", "--no-progress"]
    first = _armbridge(*args, cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    card = json.loads((tmp_path / "out" / "card.json").read_text())
    assert card["training"]["samples"] == 2000 and card["training"]["steps"] == -(-1400 // 128)
    assert card["architecture"] == {"inputs": 3, "hidden": [100, 100], "activation": "relu", "outputs": 3,
                                    "parameters": 3 * 100 + 100 + 100 * 100 + 100 + 100 * 3 + 3}
    for entry in card["files"].values():
        assert sha256(tmp_path / "out" / entry["path"]) == entry["sha256"]
    assert card["accuracy"]["onnx_vs_torch_max_abs_rad"] < 1e-4
    Arm3rANN.load(tmp_path / "out" / "card.json").predict(np.zeros((2, 3)))
    again = _armbridge(*args, cwd=tmp_path)
    assert again.returncode == 2
    lines = [s for s in again.stderr.splitlines() if s.strip()]
    assert len(lines) == 1 and "exists" in lines[0] and "--force" in lines[0]
    import typer
    from typer.testing import CliRunner

    from armbridge.train.command import train_app

    app = typer.Typer()
    app.add_typer(train_app, name="train")
    bad = CliRunner().invoke(app, ["train", "arm3r-ik", "--samples", "0", "--out", str(tmp_path / "o2")])
    assert isinstance(bad.exception, ArmbridgeError) and "--samples must be > 0" in str(bad.exception)
    assert not (tmp_path / "o2").exists()
