"""Fourier representation of SMM branches: eq. (4)-(10) and Fig. 3's error."""
import numpy as np
import pytest
import torch

from armbridge.errors import ArmbridgeError
from armbridge.robots import wrap_angle
from armbridge.smm import fourier

torch.set_num_threads(1)
N = 128


def torus_curve(n_points=N, t0=0.0, reverse=False):
    """A smooth closed curve on T^3: joint 1 winds once, joint 3 twice the other way,
    joint 2 swings without wrapping (so it has +f and -f content)."""
    t = t0 + 2 * np.pi * np.arange(n_points) / n_points
    if reverse:
        t = -t
    q = np.stack([t + 0.4 * np.sin(t), 0.3 + 0.7 * np.cos(t), -2 * t + 0.2 * np.sin(3 * t) + 1.0], axis=-1)
    return wrap_angle(q)


def test_frequencies_are_lowest_both_signs():
    assert fourier.frequencies(5).tolist() == [0, 1, 2, -2, -1]
    assert fourier.frequencies(6).tolist() == [0, 1, 2, -3, -2, -1]
    assert sorted(np.abs(fourier.frequencies(40))) == sorted([0] + [k for k in range(1, 20) for _ in (0, 1)] + [20])


def test_full_spectrum_round_trip_is_exact_up_to_the_phase_shift():
    pts = torus_curve()
    c = fourier.dft(pts)
    dk = fourier.phase_shift(c)
    back = fourier.decode(fourier.encode(pts), N)
    assert fourier.joint_error(back, np.roll(pts, int(dk), axis=0)).max() < 1e-12
    # the phase rule: joint 1's first positive frequency has phase ~0 (eq. 4)
    assert abs(np.angle(fourier.encode(pts)[0, 1])) <= np.pi / N + 1e-12


def test_band_limited_round_trip_and_upsampling():
    pts = torus_curve()
    c = fourier.lowpass(fourier.encode(pts), 40)
    assert c.shape == (3, 40)
    dk = int(fourier.phase_shift(fourier.dft(pts)))
    assert fourier.joint_error(fourier.decode(c, N), np.roll(pts, dk, axis=0)).max() < 1e-9
    # decode at 4x the samples: every 4th point is an original sample, the rest lie on the curve
    fine = fourier.decode(c, 4 * N)
    assert fourier.joint_error(fine[::4], np.roll(pts, dk, axis=0)).max() < 1e-9
    t = 2 * np.pi * (np.arange(4 * N) / (4 * N) - dk / N)
    exact = np.stack([t + 0.4 * np.sin(t), 0.3 + 0.7 * np.cos(t), -2 * t + 0.2 * np.sin(3 * t) + 1.0], -1)
    assert fourier.joint_error(fine, exact).max() < 1e-9


def test_lowpass_error_decreases_with_K():
    pts = np.stack([torus_curve(), torus_curve(t0=0.3)])
    pts[1, :, 1] += 1.5 * np.sin(2 * np.pi * 5 * np.arange(N) / N)  # sharper content
    err = fourier.lowpass_error(pts, [4, 10, 20, 40, 90, N])
    assert np.all(np.diff(err) < 0)
    assert err[-1] < 1e-12


@pytest.mark.parametrize("shift", [1, 17, 64, 127])
def test_cyclic_shifts_encode_equally(shift):
    pts = torus_curve()
    a = fourier.encode(pts)
    b = fourier.encode(np.roll(pts, shift, axis=0))
    assert np.abs(a - b).max() < 1e-9 * N


def test_different_starts_encode_within_a_sample():
    """Two samplings of one curve from starts off the sample grid (as from two tracer
    seeds) agree to the sample the integer phase rule leaves (1/2 each)."""
    a = fourier.decode(fourier.lowpass(fourier.encode(torus_curve()), 40), N)
    b = fourier.decode(fourier.lowpass(fourier.encode(torus_curve(t0=1.2345)), 40), N)
    speed = np.linalg.norm(wrap_angle(np.diff(a, axis=0)), axis=-1).max()
    assert np.linalg.norm(wrap_angle(a - b), axis=-1).max() <= speed + 1e-9


def test_exact_phase_makes_off_grid_starts_encode_equally():
    a = fourier.encode(torus_curve(), exact=True)
    b = fourier.encode(torus_curve(t0=1.2345), exact=True)
    assert np.angle(a[0, 1]) == pytest.approx(0.0, abs=1e-12)
    assert np.abs(fourier.lowpass(a, 40) - fourier.lowpass(b, 40)).max() < 1e-9 * N
    # shifting back by the fractional amount recovers the samples
    dk = fourier.phase_shift(fourier.dft(torus_curve()), exact=True)
    back = fourier.decode(fourier.apply_shift(a, -dk), N)
    assert fourier.joint_error(back, torus_curve()).max() < 1e-12


def test_reference_component_for_a_joint_turning_backwards():
    pts = torus_curve(reverse=True)  # joint 1 winds -1: no f = +1 content
    h = fourier.first_harmonics(pts)
    assert h.shape == (3, 2) and h[0, 0] < 0.05 and h[0, 1] > 0.9
    a = fourier.encode(pts, exact=True, joint=0, freq=-1)
    b = fourier.encode(np.roll(pts, 37, axis=0), exact=True, joint=0, freq=-1)
    assert np.angle(a[0, -1]) == pytest.approx(0.0, abs=1e-12)
    assert np.abs(a - b).max() < 1e-9 * N
    batch = fourier.phase_shift(fourier.dft(np.stack([pts, torus_curve()])), False, [0, 0], [-1, 1])
    assert batch.shape == (2,)
    with pytest.raises(ArmbridgeError, match="freq"):
        fourier.phase_shift(fourier.dft(pts), freq=2)


@pytest.mark.parametrize("robot", ["planar3r", "spatial4r"])
def test_two_tracings_of_one_smm_encode_equally(robot):
    """The phase and direction rules make the representation unique: tracer seeds 0 and 1
    start each loop at different configurations."""
    from armbridge.smm import automaton, nullspace
    from armbridge.smm.arms import get_smm_arm
    from armbridge.smm.grid import random_locations

    arm = get_smm_arm(robot)
    x = random_locations(arm, 4, seed=3)
    a = nullspace.compute(arm, x, seeds=12, seed=0, device="cpu")
    b = nullspace.compute(arm, x, seeds=12, seed=1, device="cpu")
    assert np.array_equal(a.count, b.count) and a.count.min() >= 1
    # the tracer's direction is the unique one: orient leaves its branches alone
    pts = a.points[np.arange(a.points.shape[1]) < a.count[:, None]]
    null = nullspace.null_vector(torch.as_tensor(arm.jacobian(pts))).numpy()
    assert (fourier.tangent_sign(pts, null) == 1).all()
    assert np.array_equal(fourier.orient(pts[:, ::-1], null[:, ::-1]), np.roll(pts, 1, axis=1))  # reversed back
    for l in range(len(x)):
        B = int(a.count[l])
        perm, _ = automaton.pair(automaton.deformation(a.points[l, :B], b.points[l, :B]))
        pa, pb = a.points[l, :B], b.points[l, :B][perm]
        ca, cb = (fourier.lowpass(fourier.encode(p, exact=True), 40) for p in (pa, pb))
        assert np.abs(ca - cb).max() < 1e-3 * np.abs(ca).max()
        qa, qb = (fourier.decode(fourier.lowpass(fourier.encode(p), 40), N) for p in (pa, pb))
        step = np.linalg.norm(wrap_angle(np.diff(qa, axis=-2)), axis=-1).max()
        assert np.linalg.norm(wrap_angle(qa - qb), axis=-1).max() <= step + 1e-3  # integer rule: 1/2 sample each


def test_batched_encode_matches_single():
    pts = np.stack([[torus_curve(t0=0.1 * i) for i in range(3)] for _ in range(2)])
    c = fourier.encode(pts)
    assert c.shape == (2, 3, 3, N)
    assert np.allclose(c[1, 2], fourier.encode(pts[1, 2]))
    assert fourier.decode(fourier.lowpass(c, 20), 50).shape == (2, 3, 50, 3)


def test_orient_reverses_branches_running_against_the_null_vector():
    def tangent(t):  # d/dt of torus_curve, a stand-in for the eq. (6) null vector
        return np.stack([1 + 0.4 * np.cos(t), -0.7 * np.sin(t), -2 + 0.6 * np.cos(3 * t)], -1)

    t = 2 * np.pi * np.arange(N) / N
    fwd = torus_curve()
    rev = fourier.orient(torus_curve(reverse=True), tangent(-t))
    assert fourier.joint_error(rev, fwd).max() < 1e-12
    assert np.array_equal(fourier.orient(fwd, tangent(t)), fwd)
    signs = fourier.tangent_sign(np.stack([fwd, torus_curve(reverse=True)]), np.stack([tangent(t), tangent(-t)]))
    assert signs.tolist() == [1, -1]


def test_bad_input_is_an_armbridge_error():
    c = fourier.encode(torus_curve())
    with pytest.raises(ArmbridgeError, match="K"):
        fourier.lowpass(c, 0)
    with pytest.raises(ArmbridgeError, match="K"):
        fourier.lowpass(c, N + 1)
    with pytest.raises(ArmbridgeError, match="finite"):
        fourier.encode(np.full((N, 3), np.nan))
    with pytest.raises(ArmbridgeError, match="complex"):
        fourier.decode(np.ones((3, 10)))
    with pytest.raises(ArmbridgeError, match="n_points"):
        fourier.decode(c, 0)
