"""Rotations in 3-D, written once against the array API (array_api_compat).

`rot_z`, `rot_y` (rotations about an axis), `rot_from_vec` (Rodrigues:
rotation vector -> matrix) and `vec_from_rot` (its log map, angle in [0, pi],
exact near pi), each batched over leading axes; `xp_of` is the namespace an
array computes in. A numpy array runs in numpy, so the runtime needs no torch;
a torch tensor runs in torch on its device (the SMM tracer, batched on the CPU
or on CUDA).

Apart from robots/dh.py (DH chains) because this is SO(3) itself, not a
robot: a DH chain's 'pose' task space is a position and a rotation vector,
and the SMM code (nullspace, correction) and its bench use the same maps.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, TypeVar

import array_api_compat.numpy as _np_ns
import numpy as np
from array_api_compat import device as _device
from array_api_compat import is_torch_array

if TYPE_CHECKING:
    import torch

A = TypeVar("A", "torch.Tensor", np.ndarray)  # a numpy array or a torch tensor, answered in kind


def rot_z(phi: A) -> A:
    """Rotations about z by phi, shape (..., 3, 3)."""
    xp = xp_of(phi)
    c, s = xp.cos(phi), xp.sin(phi)
    z, o = xp.zeros_like(c), xp.ones_like(c)
    return xp.stack([xp.stack([c, -s, z], axis=-1), xp.stack([s, c, z], axis=-1), xp.stack([z, z, o], axis=-1)],
                    axis=-2)


def rot_y(angle: A) -> A:
    """Rotations about y by angle, shape (..., 3, 3)."""
    xp = xp_of(angle)
    c, s = xp.cos(angle), xp.sin(angle)
    z, o = xp.zeros_like(c), xp.ones_like(c)
    return xp.stack([xp.stack([c, z, s], axis=-1), xp.stack([z, o, z], axis=-1), xp.stack([-s, z, c], axis=-1)],
                    axis=-2)


def rot_from_vec(v: A) -> A:
    """Rodrigues: rotation vector (..., 3) -> rotation matrix (..., 3, 3)."""
    xp = xp_of(v)
    th2 = xp.sum(v * v, axis=-1)
    th = xp.sqrt(th2)
    small = th2 < 1e-12
    # sin(th)/th and (1-cos th)/th^2 with their series near 0.
    a = xp.where(small, 1 - th2 / 6, xp.sin(th) / xp.where(small, 1.0, th))
    b = xp.where(small, 0.5 - th2 / 24, (1 - xp.cos(th)) / xp.where(small, 1.0, th2))
    k = _skew(v)
    eye = xp.eye(3, dtype=v.dtype, device=_device(v))
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def vec_from_rot(r: A) -> A:
    """Log map: rotation matrix (..., 3, 3) -> rotation vector (..., 3), angle in [0, pi].

    Near pi the skew part vanishes, so the axis comes from the symmetric part.
    """
    xp = xp_of(r)
    w = xp.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], axis=-1) / 2
    s = xp.linalg.vector_norm(w, axis=-1)
    c = ((r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2]) - 1) / 2
    th = xp.atan2(s, c)
    small = s < 1e-9
    scale = xp.where(small, 1 + th * th / 6, th / xp.where(small, 1.0, s))
    v = scale[..., None] * w
    # Near pi: u u^T = (sym(R) - cos(th) I) / (1 - cos(th)); u from its largest
    # column, sign taken from w.
    eye = xp.eye(3, dtype=r.dtype, device=_device(r))
    b: Any = (r + r.mT) / 2 - c[..., None, None] * eye
    pick = xp.argmax(xp.linalg.diagonal(b), axis=-1)[..., None, None]
    col = xp.take_along_axis(b, xp.broadcast_to(pick, (*b.shape[:-2], 3, 1)), axis=-1)[..., 0]
    u = col / xp.clip(xp.linalg.vector_norm(col, axis=-1, keepdims=True), min=1e-300)
    sign = xp.where(xp.sum(u * w, axis=-1) < 0, -1.0, 1.0)
    v_pi = (sign * th)[..., None] * u
    return xp.where((c < -0.99)[..., None], v_pi, v)


def _skew(v: A) -> A:
    xp = xp_of(v)
    z = xp.zeros_like(v[..., 0])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return xp.stack([xp.stack([z, -w, y], axis=-1), xp.stack([w, z, -x], axis=-1), xp.stack([-y, x, z], axis=-1)],
                    axis=-2)


def xp_of(x: Any) -> Any:
    """The array-API namespace of x: torch's for a tensor (imported only then), else numpy's."""
    if is_torch_array(x):
        import array_api_compat.torch as torch_ns

        return torch_ns
    return _np_ns
