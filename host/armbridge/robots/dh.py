"""Serial chains of revolute joints given by standard Denavit-Hartenberg tables.

Kinematics in torch float64 so that the SMM tracer (armbridge.smm.nullspace)
runs batched on the CPU or on CUDA. Every method takes q of shape (..., n);
a numpy q gives a numpy result, a tensor q a tensor on q's device.

Standard DH: frame i follows frame i-1 by Rz(theta_i + offset_i) Tz(d_i)
Tx(a_i) Rx(alpha_i); joint i turns about z_{i-1}, so joint 1 turns about the
base z axis. That is what makes the joint-1 symmetry of section V-B hold for
every chain: T(theta_1 + phi) = Rz(phi) T(theta_1), i.e. the SMM of a
location rotated by phi about base z is the SMM of the location with
theta_1 += phi (canonical / uncanonical). A 'pose' chain whose last joint
only rolls the tool about its own axis (a_n = 0, alpha_n = 0: `tool_roll`)
has a second symmetry: the SMM at (p, R Rz(psi)) is the SMM at (p, R) with
theta_n += psi, so only the tool axis matters (section V-B's reduction of
the orienting grid).

Task spaces: 'xy' (planar arms: position in the base x-y plane), 'xyz'
(position) and 'pose' (position and rotation vector, 6 numbers).
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
import torch

from armbridge.errors import ArmbridgeError
from armbridge.robots.planar import PlanarChain, description_fields

A = TypeVar("A", torch.Tensor, np.ndarray)

SPACES = {"xy": 2, "xyz": 3, "pose": 6}
_DH_FIELDS = ("a", "alpha", "d", "theta")
_FIELDS = ("name", *_DH_FIELDS, "space")
_CANON_DIM = {"xy": 1, "xyz": 2, "pose": 5}  # a tool-roll 'pose' chain: 4
_SMALL_BATCH = 128  # configurations up to which batched 4x4 products beat the batch-last chain


@dataclass(frozen=True, eq=False)
class DHChain:
    """A revolute chain: per joint a (m), alpha (rad), d (m), theta offset (rad)."""

    name: str
    a: np.ndarray
    alpha: np.ndarray
    d: np.ndarray
    theta: np.ndarray
    space: str
    _cache: dict[torch.device, tuple[torch.Tensor, ...]] = field(init=False, repr=False, compare=False)
    _scalars: tuple[tuple[float, float, float, float], ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ArmbridgeError("DH chain name must be a non-empty string")
        where = f"DH chain {self.name!r}"
        arrays = {f: _finite_vector(where, f, getattr(self, f)) for f in _DH_FIELDS}
        n = arrays["a"].size
        if n == 0:
            raise ArmbridgeError(f"{where}: a is empty (need one row per joint)")
        for key, v in arrays.items():
            if v.size != n:
                raise ArmbridgeError(f"{where}: {key} has {v.size} values, a has {n} (one per joint)")
        if self.space not in SPACES:
            raise ArmbridgeError(f"{where}: space must be one of {sorted(SPACES)}, got {self.space!r}")
        if self.space == "xy" and np.any(np.abs(np.sin(arrays["alpha"])) > 1e-12):
            raise ArmbridgeError(
                f"{where}: space 'xy' needs a planar chain, alpha must all be 0 or pi, got {arrays['alpha'].tolist()}"
            )
        if not np.any(np.hypot(arrays["a"], arrays["d"]) > 0):
            raise ArmbridgeError(f"{where}: every a and d is 0, the chain has no length")
        for key, v in arrays.items():
            v.setflags(write=False)
            object.__setattr__(self, key, v)
        object.__setattr__(self, "_cache", {})
        scalars = zip(self.a, self.d, np.cos(self.alpha), np.sin(self.alpha))
        object.__setattr__(self, "_scalars", tuple((float(a), float(d), float(c), float(s)) for a, d, c, s in scalars))

    # -- sizes -------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of joints."""
        return int(self.a.size)

    @property
    def m(self) -> int:
        """Task dimensions: 2 ('xy'), 3 ('xyz') or 6 ('pose')."""
        return SPACES[self.space]

    @property
    def tool_roll(self) -> bool:
        """A 'pose' chain whose last joint turns the tool about its own z without moving the tip."""
        return self.space == "pose" and self.a[-1] == 0 and self.alpha[-1] == 0

    @property
    def c_dim(self) -> int:
        """Size of a canonical location (see canonical)."""
        return 4 if self.tool_roll else _CANON_DIM[self.space]

    @property
    def reach(self) -> float:
        """L of eq. (19): total link length, sum of |(a_i, d_i)|.

        Each joint moves the tip by d_i along z_{i-1} and a_i along x_i, two
        perpendicular offsets, so this also bounds the distance of any
        reachable position from the base origin.
        """
        return float(np.hypot(self.a, self.d).sum())

    # -- kinematics --------------------------------------------------------
    def fk(self, q: A) -> A:
        """Pose of the last frame, shape (..., 4, 4)."""
        return _io(lambda t: self.frames(t)[..., -1, :, :], q)

    def frames(self, q: torch.Tensor) -> torch.Tensor:
        """Base frame and every joint frame, shape (..., n+1, 4, 4)."""
        q = self._q(q)
        k0, kc, ks, off = self._params(q.device)
        th = q + off
        # Link i: Rz(theta_i) C_i with C_i = Tz(d_i) Tx(a_i) Rx(alpha_i), and
        # Rz(theta) = E + cos(theta) P_c + sin(theta) P_s (see _params).
        links = k0 + torch.cos(th)[..., None, None] * kc + torch.sin(th)[..., None, None] * ks
        out = [torch.eye(4, dtype=q.dtype, device=q.device).expand(*q.shape[:-1], 4, 4)]
        for i in range(self.n):
            out.append(out[-1] @ links[..., i, :, :])
        return torch.stack(out, -3)

    def kinematics(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Tip rotation (..., 3, 3), tip position (..., 3) and geometric Jacobian (..., m, n)."""
        rot, pos, jac = self._chain(q, jacobian=True)
        assert jac is not None
        return rot, pos, jac

    def tip(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Tip rotation (..., 3, 3) and position (..., 3)."""
        rot, pos, _ = self._chain(q, jacobian=False)
        return rot, pos

    def _chain(self, q: torch.Tensor, jacobian: bool) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """kinematics(), the Jacobian only when asked for.

        The same chain as frames(), computed with the batch as the last axis
        ((3, 3, P) rotations, one joint at a time) so that every op runs over
        the whole batch: several times faster than batched 4x4 products for
        the thousands of configurations the SMM tracer steps at once.
        Jacobian column i: joint i turns about z_{i-1} through o_{i-1}.
        """
        q = self._q(q)
        lead = q.shape[:-1]
        if q.numel() <= _SMALL_BATCH * self.n:
            return self._chain_small(q, jacobian)
        th = (q.reshape(-1, self.n) + self._params(q.device)[3]).T  # (n, P)
        ct, st = torch.cos(th), torch.sin(th)
        rot = torch.eye(3, dtype=q.dtype, device=q.device)[:, :, None].expand(3, 3, th.shape[1])
        pos = torch.zeros(3, th.shape[1], dtype=q.dtype, device=q.device)
        axes, origins = [], []
        for i, (a, d, ca, sa) in enumerate(self._scalars):
            axes.append(rot[:, 2])
            origins.append(pos)
            # R Rz(theta) Rx(alpha) column by column; p += R (a Rz(theta) x + d z).
            u = rot[:, 0] * ct[i] + rot[:, 1] * st[i]
            v = rot[:, 1] * ct[i] - rot[:, 0] * st[i]
            pos = pos + a * u + d * rot[:, 2]
            rot = torch.stack([u, ca * v + sa * rot[:, 2], ca * rot[:, 2] - sa * v], 1)
        r_out = rot.permute(2, 0, 1).reshape(*lead, 3, 3)
        p_out = pos.T.reshape(*lead, 3)
        if not jacobian:
            return r_out, p_out, None
        z, r = torch.stack(axes), pos - torch.stack(origins)  # (n, 3, P)
        jv = torch.stack([z[:, 1] * r[:, 2] - z[:, 2] * r[:, 1], z[:, 2] * r[:, 0] - z[:, 0] * r[:, 2],
                          z[:, 0] * r[:, 1] - z[:, 1] * r[:, 0]])  # (3, n, P)
        jac = torch.cat([jv, z.transpose(0, 1)]) if self.space == "pose" else jv[: self.m]
        return r_out, p_out, jac.permute(2, 0, 1).reshape(*lead, self.m, self.n)

    def _chain_small(self, q: torch.Tensor, jacobian: bool) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """_chain() from frames(): fewer, larger ops, faster for a few configurations."""
        f = self.frames(q)
        rot, tip = f[..., -1, :3, :3], f[..., -1, :3, 3]
        if not jacobian:
            return rot, tip, None
        z, o = f[..., :-1, :3, 2], f[..., :-1, :3, 3]
        jv = torch.linalg.cross(z, tip[..., None, :] - o, dim=-1)  # (..., n, 3)
        jac = torch.cat([jv, z], -1) if self.space == "pose" else jv[..., : self.m]
        return rot, tip, jac.transpose(-1, -2)

    def task(self, q: A) -> A:
        """Location of q: (x, y), (x, y, z) or (x, y, z, rotation vector)."""
        return _io(lambda t: self._task_of(*self.tip(t)), q)

    def task_error(self, q: A, x: A) -> A:
        """Delta x_e of eq. (1)/(18): from q's location to target x, shape (..., m).

        'pose': position error and the rotation vector of R_target R^T, the
        world-frame rotation that the geometric Jacobian's angular rows move.
        """
        return _io(lambda t, xt: self.tip_error(*self.tip(t), xt), q, x)

    def jacobian(self, q: A) -> A:
        """Geometric Jacobian d(location)/dq, shape (..., m, n)."""
        return _io(lambda t: self.kinematics(t)[2], q)

    def fk_error(self, q: A, x: A) -> A:
        """Eq. (19) as a fraction (x100 for %): |p - p_target| / L, and for 'pose'
        the mean of that and the orientation angle / pi."""

        def err(t: torch.Tensor, xt: torch.Tensor) -> torch.Tensor:
            e = self.tip_error(*self.tip(t), xt)
            ep = torch.linalg.vector_norm(e[..., :3] if self.space == "pose" else e, dim=-1) / self.reach
            if self.space != "pose":
                return ep
            return 0.5 * ep + 0.5 * torch.linalg.vector_norm(e[..., 3:], dim=-1) / math.pi

        return _io(err, q, x)

    # -- symmetries (section V-B) -------------------------------------------
    def canonical(self, x: A) -> tuple[A, A]:
        """(c, shift): the canonical location c of x and joint offsets shift (..., n) such that
        the SMM at x is the SMM at uncanonical(c) with every configuration moved by shift.

        x is rotated by -phi about base z into the x-z half-plane (x >= 0),
        shift[..., 0] = phi. 'xy': c = (r,); 'xyz': c = (rho, z); 'pose':
        c = (rho, z, rotation vector of Rz(-phi) R), 5 numbers, or for a
        tool_roll chain c = (rho, z, polar, azimuth) of the tool axis of
        R' = Rz(-phi) R, with R' = Rz(azimuth) Ry(polar) Rz(psi) and
        shift[..., n-1] = psi.
        """

        def canon(xt: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            xt = self._x(xt)
            phi = torch.atan2(xt[..., 1], xt[..., 0])
            rho = torch.hypot(xt[..., 0], xt[..., 1])
            shift = torch.zeros(*xt.shape[:-1], self.n, dtype=xt.dtype, device=xt.device)
            shift[..., 0] = phi
            if self.space == "xy":
                return rho[..., None], shift
            if self.space == "xyz":
                return torch.stack([rho, xt[..., 2]], -1), shift
            rc = rot_z(-phi) @ rot_from_vec(xt[..., 3:])
            if not self.tool_roll:
                return torch.cat([torch.stack([rho, xt[..., 2]], -1), vec_from_rot(rc)], -1), shift
            axis = rc[..., :, 2]
            polar = torch.acos(axis[..., 2].clamp(-1.0, 1.0))
            azimuth = torch.atan2(axis[..., 1], axis[..., 0])
            roll = (rot_z(azimuth) @ rot_y(polar)).transpose(-1, -2) @ rc  # Rz(psi)
            shift[..., -1] = torch.atan2(roll[..., 1, 0], roll[..., 0, 0])
            return torch.stack([rho, xt[..., 2], polar, azimuth], -1), shift

        if isinstance(x, np.ndarray):
            c, p = canon(torch.as_tensor(x, dtype=torch.float64))
            return c.numpy(), p.numpy()
        return canon(x)

    def uncanonical(self, c: A, shift: A | None = None) -> A:
        """The location whose canonical form is (c, shift); shift None: all zeros."""

        def unc(ct: torch.Tensor, *sh: torch.Tensor) -> torch.Tensor:
            if ct.shape[-1] != self.c_dim:
                raise ArmbridgeError(
                    f"robot {self.name!r}: canonical locations have {self.c_dim} numbers, got shape {tuple(ct.shape)}"
                )
            st = sh[0] if sh else torch.zeros(*ct.shape[:-1], self.n, dtype=ct.dtype, device=ct.device)
            if st.shape[-1] != self.n:
                raise ArmbridgeError(f"robot {self.name!r}: shift needs one offset per joint ({self.n}), "
                                     f"got shape {tuple(st.shape)}")
            rho, pt = ct[..., 0], st[..., 0]
            xy = torch.stack([rho * torch.cos(pt), rho * torch.sin(pt)], -1)
            if self.space == "xy":
                return xy
            if self.space == "xyz":
                return torch.cat([xy, ct[..., 1:2]], -1)
            if self.tool_roll:
                r = rot_z(ct[..., 3]) @ rot_y(ct[..., 2]) @ rot_z(st[..., -1])
            else:
                r = rot_from_vec(ct[..., 2:])
            return torch.cat([xy, ct[..., 1:2], vec_from_rot(rot_z(pt) @ r)], -1)

        return _io(unc, c) if shift is None else _io(unc, c, shift)

    # -- description -------------------------------------------------------
    @classmethod
    def from_planar(cls, chain: PlanarChain) -> DHChain:
        """The 'xy' DH chain of a planar chain (a = link lengths, the rest 0);
        its joint limits are dropped (SMMs ignore them)."""
        zeros = np.zeros(chain.n)
        return cls(name=chain.name, a=chain.link_lengths.copy(), alpha=zeros, d=zeros, theta=zeros, space="xy")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description; from_dict(to_dict()) gives an equal chain."""
        return {"name": self.name, **{f: getattr(self, f).tolist() for f in _DH_FIELDS}, "space": self.space}

    @classmethod
    def from_dict(cls, d: Any) -> DHChain:
        """Build from a JSON description with exactly the keys of to_dict()."""
        return cls(**description_fields(d, _FIELDS, "DH chain description"))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, DHChain) and self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(json.dumps(self.to_dict()))

    # -- internals (tensor in, tensor out) ---------------------------------
    def _params(self, device: torch.device) -> tuple[torch.Tensor, ...]:
        """(E C, P_c C, P_s C, theta offsets) per joint on device, cached."""
        cache = self._cache
        if device not in cache:
            c = np.zeros((self.n, 4, 4))
            ca, sa = np.cos(self.alpha), np.sin(self.alpha)
            c[:, 0, 0], c[:, 0, 3] = 1.0, self.a
            c[:, 1, 1], c[:, 1, 2] = ca, -sa
            c[:, 2, 1], c[:, 2, 2], c[:, 2, 3] = sa, ca, self.d
            c[:, 3, 3] = 1.0
            e, pc, ps = np.diag([0.0, 0, 1, 1]), np.diag([1.0, 1, 0, 0]), np.zeros((4, 4))
            ps[0, 1], ps[1, 0] = -1.0, 1.0
            mats = [e @ c, pc @ c, ps @ c, self.theta]
            cache[device] = tuple(torch.tensor(v, dtype=torch.float64, device=device) for v in mats)
        return cache[device]

    def _q(self, q: torch.Tensor) -> torch.Tensor:
        if q.ndim == 0 or q.shape[-1] != self.n:
            raise ArmbridgeError(f"robot {self.name!r}: q must have shape (..., {self.n}), got {tuple(q.shape)}")
        return q.to(torch.float64)

    def _x(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim == 0 or x.shape[-1] != self.m:
            raise ArmbridgeError(
                f"robot {self.name!r}: a location has {self.m} numbers ({self.space}), got shape {tuple(x.shape)}"
            )
        return x.to(torch.float64)

    def _task_of(self, rot: torch.Tensor, tip: torch.Tensor) -> torch.Tensor:
        if self.space == "pose":
            return torch.cat([tip, vec_from_rot(rot)], -1)
        return tip[..., : self.m]

    def tip_error(self, rot: torch.Tensor, tip: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Delta x_e from a tip (rotation, position) to x: position difference, then ('pose') the
        rotation vector of R_x R^T (world frame)."""
        x = self._x(x)
        if self.space != "pose":
            return x - tip[..., : self.m]
        r_err = rot_from_vec(x[..., 3:]) @ rot.transpose(-1, -2)
        return torch.cat([x[..., :3] - tip, vec_from_rot(r_err)], -1)


def rot_z(phi: torch.Tensor) -> torch.Tensor:
    """Rotations about z by phi, shape (..., 3, 3)."""
    c, s = torch.cos(phi), torch.sin(phi)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack([torch.stack([c, -s, z], -1), torch.stack([s, c, z], -1), torch.stack([z, z, o], -1)], -2)


def rot_y(angle: torch.Tensor) -> torch.Tensor:
    """Rotations about y by angle, shape (..., 3, 3)."""
    c, s = torch.cos(angle), torch.sin(angle)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack([torch.stack([c, z, s], -1), torch.stack([z, o, z], -1), torch.stack([-s, z, c], -1)], -2)


def rot_from_vec(v: torch.Tensor) -> torch.Tensor:
    """Rodrigues: rotation vector (..., 3) -> rotation matrix (..., 3, 3)."""
    th2 = (v * v).sum(-1)
    th = torch.sqrt(th2)
    small = th2 < 1e-12
    # sin(th)/th and (1-cos th)/th^2 with their series near 0.
    a = torch.where(small, 1 - th2 / 6, torch.sin(th) / torch.where(small, 1.0, th))
    b = torch.where(small, 0.5 - th2 / 24, (1 - torch.cos(th)) / torch.where(small, 1.0, th2))
    k = _skew(v)
    eye = torch.eye(3, dtype=v.dtype, device=v.device)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def vec_from_rot(r: torch.Tensor) -> torch.Tensor:
    """Log map: rotation matrix (..., 3, 3) -> rotation vector (..., 3), angle in [0, pi].

    Near pi the skew part vanishes, so the axis comes from the symmetric part.
    """
    w = torch.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1) / 2
    s = torch.linalg.vector_norm(w, dim=-1)
    c = ((r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2]) - 1) / 2
    th = torch.atan2(s, c)
    small = s < 1e-9
    scale = torch.where(small, 1 + th * th / 6, th / torch.where(small, 1.0, s))
    v = scale[..., None] * w
    # Near pi: u u^T = (sym(R) - cos(th) I) / (1 - cos(th)); u from its largest
    # column, sign taken from w.
    eye = torch.eye(3, dtype=r.dtype, device=r.device)
    b = (r + r.transpose(-1, -2)) / 2 - c[..., None, None] * eye
    diag = torch.diagonal(b, dim1=-2, dim2=-1)
    col = torch.take_along_dim(b, diag.argmax(-1)[..., None, None].expand(*b.shape[:-2], 3, 1), -1)[..., 0]
    u = col / torch.linalg.vector_norm(col, dim=-1, keepdim=True).clamp_min(1e-300)
    sign = torch.where((u * w).sum(-1) < 0, -1.0, 1.0)
    v_pi = (sign * th)[..., None] * u
    return torch.where((c < -0.99)[..., None], v_pi, v)


def _skew(v: torch.Tensor) -> torch.Tensor:
    z = torch.zeros_like(v[..., 0])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return torch.stack([torch.stack([z, -w, y], -1), torch.stack([w, z, -x], -1), torch.stack([-y, x, z], -1)], -2)


def _io(f: Callable[..., Any], *args: Any) -> Any:
    """Call f on tensors; numpy arguments give a numpy result (on the CPU)."""
    if isinstance(args[0], np.ndarray):
        out = f(*(torch.as_tensor(np.asarray(a), dtype=torch.float64) for a in args))
        return out.numpy()
    return f(*(torch.as_tensor(a, dtype=torch.float64, device=args[0].device) for a in args))


def _finite_vector(where: str, field: str, value: Any) -> np.ndarray:
    """A finite 1-D float copy of value, or an ArmbridgeError naming the field."""
    try:
        v = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ArmbridgeError(f"{where}: {field} must be a list of numbers, got {value!r}") from None
    if v.ndim != 1 or not np.all(np.isfinite(v)):
        raise ArmbridgeError(f"{where}: {field} must be a flat list of finite numbers, got {value!r}")
    return v
