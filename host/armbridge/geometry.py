"""Angle wrapping: the one convention every module uses, [-pi, pi).

`wrap_angle(a)` maps an angle to the copy of it in [-pi, pi): a Python float
gives a float, a numpy array, numpy scalar or list gives numpy, a torch tensor a tensor (with a
gradient of 1 everywhere, so a loss can wrap an angle error). numba kernels
use `wrap_angle_scalar` compiled with `numba.njit` (robots/masr_kernels.py):
the same formula, so numpy, torch and numba agree bit for bit.

Why [-pi, pi) and this formula: a - 2 pi floor((a + pi) / 2 pi) returns every
angle already in [-pi, pi) unchanged, bit for bit (the floor is 0 there), so
wrapping an angle twice, or wrapping a difference that needs no wrap, never
moves it by a rounding error. Near +pi a value within an ulp may round onto
-pi; that is the one place where the half-open end shows.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

PI = math.pi
TWO_PI = 2.0 * math.pi


def wrap_angle_scalar(a: float) -> float:
    """a wrapped to [-pi, pi): the formula, for floats and for numba (`njit(wrap_angle_scalar)`)."""
    return a - TWO_PI * math.floor((a + PI) / TWO_PI)


def wrap_angle(a: Any) -> Any:
    """a wrapped to [-pi, pi): float -> float, array-like -> numpy array, torch tensor -> tensor."""
    if isinstance(a, (int, float)) and not isinstance(a, np.generic):  # numpy scalars take the numpy path
        return wrap_angle_scalar(float(a))
    if not isinstance(a, np.ndarray) and hasattr(a, "floor") and hasattr(a, "requires_grad"):  # a torch tensor
        return a - TWO_PI * ((a + PI) / TWO_PI).floor()
    a = np.asarray(a, dtype=float)
    return a - TWO_PI * np.floor((a + PI) / TWO_PI)
