"""Fourier representation of SMM branches (Clark and Xie, section IV).

A branch is a closed curve of N joint configurations. Each joint is mapped to
the circle group (eq. 7) so that the sequence stays periodic across 2*pi
wraps, transformed by the DFT (eq. 8), shifted to a unique start by the phase
rule (eq. 4-5), and low-pass filtered to K components; eq. (9)-(10) map back.

Array layout: points (..., N, n) float radians; coefficients (..., n, F)
complex, one row per joint. A full spectrum (F = N) is in numpy's FFT order.
A low-passed spectrum keeps the K integer frequencies of `frequencies(K)`,
-(K // 2) .. (K - 1) // 2 in numpy's FFT order, i.e. the K lowest |f| with
both signs. Both signs are needed: exp(j theta) is complex, and a joint that
swings without wrapping has equal +f and -f content. For even K the extra
frequency is -K/2, as in numpy, so K = N keeps the spectrum whole.

Phase rule: the paper takes joint 1's f = +1 component as the reference and
shifts by whole samples. Two generalisations, off by default here and on in
armbridge.smm.dataset: `exact` (a fractional shift, so two tracings of one
loop encode alike to ~1e-4 instead of up to one sample apart) and a choice of
reference component (joint, f = +-1), because joint 1's f = +1 content
vanishes on branches along which joint 1 turns backwards.

Coefficients are eq. (8) unnormalised (the DC term of a joint is N times its
mean point on the circle); decode's angle (eq. 9) does not depend on scale.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from armbridge.errors import ArmbridgeError
from armbridge.robots import wrap_angle


def to_circle(theta: np.ndarray) -> np.ndarray:
    """Eq. (7): joint angles to unit complex numbers."""
    return np.exp(1j * np.asarray(theta, dtype=np.float64))


def from_circle(z: np.ndarray) -> np.ndarray:
    """Eq. (9): unit complex numbers back to angles in (-pi, pi]."""
    return np.angle(z)


def frequencies(K: int) -> np.ndarray:
    """The K integer frequencies a low-passed spectrum keeps, in FFT order."""
    return np.rint(np.fft.fftfreq(K, 1.0 / K)).astype(np.int64)


def dft(points: np.ndarray) -> np.ndarray:
    """Eq. (8): (..., N, n) angles -> (..., n, N) spectrum of exp(j theta)."""
    pts = _points(points)
    return np.fft.fft(to_circle(np.swapaxes(pts, -1, -2)), axis=-1)


def phase_shift(coeffs: np.ndarray, exact: bool = False, joint: ArrayLike = 0, freq: ArrayLike = 1) -> np.ndarray:
    """Eq. (4): the sample shift Delta k of each branch, in [0, N).

    Delta k = round(angle(Theta_joint^(freq)) * N / (2 pi freq)) from a full
    spectrum (..., n, N); the paper's reference is joint 1's first positive
    frequency (joint=0, freq=1). joint and freq (+1 or -1) may be arrays
    over the batch: a branch along which joint 1 turns backwards has no
    f = +1 content, and its phase there is noise (see
    dataset.reference_components). exact=True leaves out the rounding: a
    fractional shift, applied in the frequency domain, that sets the
    reference phase to exactly 0 (see encode).
    """
    N = coeffs.shape[-1]
    j = np.broadcast_to(np.asarray(joint, dtype=np.int64), coeffs.shape[:-2])[..., None, None]
    f = np.broadcast_to(np.asarray(freq, dtype=np.int64), coeffs.shape[:-2])
    if np.any(np.abs(f) != 1) or np.any((j < 0) | (j >= coeffs.shape[-2])):
        raise ArmbridgeError(f"phase reference must be a joint in 0..{coeffs.shape[-2] - 1} and freq +1 or -1")
    ref = np.take_along_axis(np.take_along_axis(coeffs, j, axis=-2), np.mod(f, N)[..., None, None], axis=-1)
    dk = np.mod(np.angle(ref[..., 0, 0]) * N / (2 * np.pi * f), N)
    return dk if exact else np.mod(np.rint(dk), N).astype(np.int64)


def first_harmonics(points: np.ndarray) -> np.ndarray:
    """|Theta_j^(f)| / N for f = +1, -1 (last axis, in that order): (..., N, n) -> (..., n, 2).

    The candidates for the phase reference; a direct sum, cheaper than the full DFT.
    """
    pts = _points(points)
    N = pts.shape[-2]
    basis = np.exp(-2j * np.pi * np.outer(np.arange(N), [1, -1]) / N)  # (N, 2)
    return np.abs(np.einsum("...ij,ik->...jk", to_circle(pts), basis)) / N


def apply_shift(coeffs: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Shift theorem: Theta^(f) exp(-j 2 pi f dk / N) for every joint.

    For an integer dk this is np.roll(points, dk, axis=-2) in the sample
    domain, the reordering of eq. (5); afterwards joint 1's f = 1 phase lies
    in [-pi/N, pi/N]. Works on full (N) spectra only.
    """
    N = coeffs.shape[-1]
    f = frequencies(N)
    dk = np.asarray(shift)[..., None, None]
    return coeffs * np.exp(-2j * np.pi * f * dk / N)


def encode(points: np.ndarray, exact: bool = False, joint: ArrayLike = 0, freq: ArrayLike = 1) -> np.ndarray:
    """Branches (..., N, n) -> unique full spectra (..., n, N), eq. (4)-(8).

    The direction along the branch must already be the tracer's (+ null
    vector of eq. 6; see `orient` for branches from elsewhere). The start is
    fixed by the phase rule, so cyclic shifts of one branch encode equally;
    joint and freq choose its reference component (see phase_shift).

    exact=False is the paper's integer shift: two samplings of one loop that
    start between each other's samples still differ by up to one sample
    (about half a tracer step in joint space). exact=True shifts by the
    fractional amount, so joint 1's f = 1 phase is exactly 0 and the
    spectrum depends only on the loop (and the resampling error), which is
    a smoother regression target; decode then returns points of the
    band-limited loop between the original samples.
    """
    c = dft(points)
    return apply_shift(c, phase_shift(c, exact, joint, freq))


def lowpass(coeffs: np.ndarray, K: int) -> np.ndarray:
    """Keep the K lowest-|f| components of full spectra: (..., n, N) -> (..., n, K)."""
    N = coeffs.shape[-1]
    if not isinstance(K, (int, np.integer)) or not 1 <= K <= N:
        raise ArmbridgeError(f"K (Fourier components kept) must be an integer in 1..{N}, got {K!r}")
    return coeffs[..., np.mod(frequencies(int(K)), N)]


def decode(coeffs: np.ndarray, n_points: int = 128) -> np.ndarray:
    """Eq. (10): band-limited spectra (..., n, K) -> (..., n_points, n) angles.

    The series is evaluated at t_i = i * N / n_points (i < n_points) in units
    of the original samples, so n_points = N returns the sample positions of
    the encoded (shifted) branch and any other n_points resamples it.
    """
    c = np.asarray(coeffs)
    if c.ndim < 2 or not np.iscomplexobj(c):
        raise ArmbridgeError(f"coeffs must be complex (..., n, K), got {c.dtype} {c.shape}")
    if not isinstance(n_points, (int, np.integer)) or n_points < 1:
        raise ArmbridgeError(f"n_points must be a positive integer, got {n_points!r}")
    f = frequencies(c.shape[-1])
    t = np.arange(n_points) / n_points
    basis = np.exp(2j * np.pi * np.outer(f, t))  # (K, n_points)
    z = c @ basis  # (..., n, n_points); the 1/N of eq. (10) drops out in atan2
    return np.swapaxes(from_circle(z), -1, -2)


def joint_error(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Absolute joint differences on the circle, |T^-1(T(a) / T(b))| (eq. 13 per joint)."""
    return np.abs(wrap_angle(np.asarray(a) - np.asarray(b)))


def lowpass_error(points: np.ndarray, Ks: Sequence[int]) -> np.ndarray:
    """Fig. 3: mean absolute joint error of branches against their K-term reconstruction.

    points (..., N, n) -> one mean over every branch, sample and joint per K.
    The phase shift commutes with the low-pass filter, so it is left out.
    """
    pts = _points(points)
    N = pts.shape[-2]
    c = dft(pts)
    return np.array([joint_error(decode(lowpass(c, K), N), pts).mean() for K in Ks])


def tangent_sign(points: np.ndarray, null: np.ndarray) -> np.ndarray:
    """+1 where a branch runs along the null vectors sampled on it, else -1.

    points (..., N, n) and null (..., N, n), the eq. (6) null vector at each
    point. The branch's forward differences (wrapped) are compared with the
    null vectors by the sum of their dot products.
    """
    pts = _points(points)
    step = wrap_angle(np.roll(pts, -1, axis=-2) - pts)
    dots = np.einsum("...i,...i->...", step, np.asarray(null, dtype=np.float64)).sum(axis=-1)
    return np.where(dots >= 0, 1, -1)


def orient(points: np.ndarray, null: np.ndarray) -> np.ndarray:
    """Reverse the branches (..., N, n) that run against their null vectors.

    For branches from another source than the tracer (which always follows
    + null vector, eq. 6), so that encode sees the unique direction of
    section IV-B. The first sample stays first.
    """
    pts = _points(points)
    rev = np.roll(pts[..., ::-1, :], 1, axis=-2)
    return np.where((tangent_sign(pts, null) < 0)[..., None, None], rev, pts)


# The regressors' output layout (armbridge.smm.networks): (branch, joint, k, [re, im]) flattened.
def coeffs_to_target(coeffs: np.ndarray) -> np.ndarray:
    """(M, B, n, K) complex -> (M, B*n*K*2) float: real and imaginary parts, flattened."""
    c = np.asarray(coeffs)
    return np.stack([c.real, c.imag], axis=-1).reshape(c.shape[0], -1)


def target_to_coeffs(y: np.ndarray, branches: int, n: int, k: int) -> np.ndarray:
    """Inverse of coeffs_to_target: (M, B*n*K*2) -> (M, B, n, K), complex64 for float32 y
    (a view, no copy: the network's output as is), else complex128."""
    y = np.ascontiguousarray(y, dtype=np.float32 if np.asarray(y).dtype == np.float32 else np.float64)
    return y.reshape(-1, branches, n, 2 * k).view(np.complex64 if y.dtype == np.float32 else np.complex128)


def _points(points: np.ndarray) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim < 2 or pts.shape[-2] < 3:
        raise ArmbridgeError(f"points must be (..., N, n) with N >= 3 samples, got shape {pts.shape}")
    if not np.isfinite(pts).all():
        raise ArmbridgeError("points must be finite (drop NaN-padded branch slots before encoding)")
    return pts
