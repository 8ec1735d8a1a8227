"""Serial chains of revolute joints given by standard Denavit-Hartenberg tables.

Kinematics in float64, written once against the array API (array_api_compat):
a numpy q runs in numpy, so the runtime (learned SMMs, the fault-tolerant demo)
needs no torch, and a torch q runs in torch on q's device, so the SMM tracer
(armbridge.smm.nullspace) runs batched on the CPU or on CUDA. Every method
takes q of shape (..., n) and answers in q's kind of array; the rotations it
needs (about z and y, rotation vectors and back) are robots/rotations.py's.

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

A DHChain is a `robots.base.Robot` (kind "dh"): q_min, q_max, v_max and
joint_names are data too, optional in a description: a joint without stops
turns in [-pi, pi] (the range SMM configurations are wrapped to), at
DEFAULT_V_MAX rad/s, named j1..jn. SMMs ignore the limits. `joint_points` is
plain numpy, so drawing a DH chain costs no torch call.
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from array_api_compat import device as _device
from array_api_compat import is_torch_array

from armbridge.errors import ArmbridgeError
from armbridge.robots.base import limits_check
from armbridge.robots.planar import PlanarChain, description_fields
from armbridge.robots.rotations import A, rot_from_vec, rot_y, rot_z, vec_from_rot, xp_of

SPACES = {"xy": 2, "xyz": 3, "pose": 6}
_DH_FIELDS = ("a", "alpha", "d", "theta")
_FIELDS = ("name", *_DH_FIELDS, "space")
_LIMIT_FIELDS = ("q_min", "q_max", "v_max", "joint_names")  # optional in a description
DEFAULT_V_MAX = 1.0  # rad/s for a joint whose description gives no speed limit (our choice)
_CANON_DIM = {"xy": 1, "xyz": 2, "pose": 5}  # a tool-roll 'pose' chain: 4
_SMALL_BATCH = 128  # configurations up to which batched 4x4 products beat the batch-last chain


@dataclass(frozen=True, eq=False)
class DHChain:
    """A revolute chain: per joint a (m), alpha (rad), d (m), theta offset (rad);
    limits in rad and rad/s (None: the defaults of the module docstring)."""

    kind: ClassVar[str] = "dh"
    name: str
    a: np.ndarray
    alpha: np.ndarray
    d: np.ndarray
    theta: np.ndarray
    space: str
    q_min: Any = None
    q_max: Any = None
    v_max: Any = None
    joint_names: Any = None
    _cache: dict[tuple[str, str], tuple[Any, ...]] = field(init=False, repr=False, compare=False)
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
        limits = PlanarChain(
            name=self.name, link_lengths=np.ones(n),
            q_min=np.full(n, -math.pi) if self.q_min is None else self.q_min,
            q_max=np.full(n, math.pi) if self.q_max is None else self.q_max,
            v_max=np.full(n, DEFAULT_V_MAX) if self.v_max is None else self.v_max,
            joint_names=tuple(f"j{i + 1}" for i in range(n)) if self.joint_names is None else self.joint_names,
        )  # checks the limits and names as a planar chain's (one set of rules)
        for key, v in arrays.items():
            v.setflags(write=False)
            object.__setattr__(self, key, v)
        for key in _LIMIT_FIELDS:
            object.__setattr__(self, key, getattr(limits, key))
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

    # -- the robot interface (base.Robot) ------------------------------------
    @property
    def dof(self) -> int:
        """Coordinates of q: the n joints."""
        return self.n

    @property
    def joint_units(self) -> tuple[str, ...]:
        """Every joint is in rad."""
        return ("rad",) * self.n

    @property
    def draw_dim(self) -> int:
        """2 for an 'xy' chain (drawn in its plane), else 3."""
        return 2 if self.space == "xy" else 3

    def within_limits(self, q: Any) -> np.ndarray:
        """True where every joint is inside [q_min, q_max] (bounds included), shape (...)."""
        return limits_check(self, self._q_np(q))

    def joint_points(self, q: Any) -> np.ndarray:
        """Base and every frame origin (the last is the tip), (..., n+1, draw_dim); numpy.

        The chain of frames() as plain 4x4 products; 'xy' chains keep x, y.
        """
        q = self._q_np(q)
        th = q + self.theta
        ct, st = np.cos(th), np.sin(th)
        ca, sa = np.cos(self.alpha), np.sin(self.alpha)
        frame = np.broadcast_to(np.eye(4), (*q.shape[:-1], 4, 4))
        points = [frame[..., :3, 3]]
        for i in range(self.n):
            link = np.zeros((*q.shape[:-1], 4, 4))
            c, s = ct[..., i], st[..., i]
            link[..., 0, :] = np.stack([c, -s * ca[i], s * sa[i], self.a[i] * c], -1)
            link[..., 1, :] = np.stack([s, c * ca[i], -c * sa[i], self.a[i] * s], -1)
            link[..., 2, :] = [0.0, sa[i], ca[i], self.d[i]]
            link[..., 3, 3] = 1.0
            frame = frame @ link
            points.append(frame[..., :3, 3])
        p = np.stack(points, -2)
        return p[..., :2] if self.space == "xy" else p

    def ee_point(self, q: Any) -> np.ndarray:
        """The tip, (..., draw_dim)."""
        return self.joint_points(q)[..., -1, :]

    def _q_np(self, q: Any) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.ndim == 0 or q.shape[-1] != self.n:
            raise ArmbridgeError(f"robot {self.name!r}: q must have shape (..., {self.n}), got {q.shape}")
        return q

    # -- kinematics --------------------------------------------------------
    def fk(self, q: A) -> A:
        """Pose of the last frame, shape (..., 4, 4)."""
        return _io(lambda t: self.frames(t)[..., -1, :, :], q)

    def frames(self, q: A) -> A:
        """Base frame and every joint frame, shape (..., n+1, 4, 4)."""
        q = self._q(q)
        xp = xp_of(q)
        k0, kc, ks, off = self._params(q)
        th = q + off
        # Link i: Rz(theta_i) C_i with C_i = Tz(d_i) Tx(a_i) Rx(alpha_i), and
        # Rz(theta) = E + cos(theta) P_c + sin(theta) P_s (see _params).
        links = k0 + xp.cos(th)[..., None, None] * kc + xp.sin(th)[..., None, None] * ks
        out = [xp.broadcast_to(xp.eye(4, dtype=q.dtype, device=_device(q)), (*q.shape[:-1], 4, 4))]
        for i in range(self.n):
            out.append(out[-1] @ links[..., i, :, :])
        return xp.stack(out, axis=-3)

    def kinematics(self, q: A) -> tuple[A, A, A]:
        """Tip rotation (..., 3, 3), tip position (..., 3) and geometric Jacobian (..., m, n)."""
        rot, pos, jac = self._chain(q, jacobian=True)
        assert jac is not None
        return rot, pos, jac

    def tip(self, q: A) -> tuple[A, A]:
        """Tip rotation (..., 3, 3) and position (..., 3)."""
        rot, pos, _ = self._chain(q, jacobian=False)
        return rot, pos

    def _chain(self, q: A, jacobian: bool) -> tuple[A, A, A | None]:
        """kinematics(), the Jacobian only when asked for.

        The same chain as frames(), computed with the batch as the last axis
        ((3, 3, P) rotations, one joint at a time) so that every op runs over
        the whole batch: several times faster than batched 4x4 products for
        the thousands of configurations the SMM tracer steps at once.
        Jacobian column i: joint i turns about z_{i-1} through o_{i-1}.
        """
        q = self._q(q)
        xp, dev = xp_of(q), _device(q)
        lead: tuple[int, ...] = tuple(q.shape[:-1])
        if math.prod(q.shape) <= _SMALL_BATCH * self.n:
            return self._chain_small(q, jacobian)
        th = (xp.reshape(q, (-1, self.n)) + self._params(q)[3]).T  # (n, P)
        ct, st = xp.cos(th), xp.sin(th)
        rot = xp.broadcast_to(xp.eye(3, dtype=q.dtype, device=dev)[:, :, None], (3, 3, th.shape[1]))
        pos = xp.zeros((3, th.shape[1]), dtype=q.dtype, device=dev)
        axes, origins = [], []
        for i, (a, d, ca, sa) in enumerate(self._scalars):
            axes.append(rot[:, 2])
            origins.append(pos)
            # R Rz(theta) Rx(alpha) column by column; p += R (a Rz(theta) x + d z).
            u = rot[:, 0] * ct[i] + rot[:, 1] * st[i]
            v = rot[:, 1] * ct[i] - rot[:, 0] * st[i]
            pos = pos + a * u + d * rot[:, 2]
            rot = xp.stack([u, ca * v + sa * rot[:, 2], ca * rot[:, 2] - sa * v], axis=1)
        r_out = xp.reshape(xp.permute_dims(rot, (2, 0, 1)), (*lead, 3, 3))
        p_out = xp.reshape(pos.T, (*lead, 3))
        if not jacobian:
            return r_out, p_out, None
        z, r = xp.stack(axes), pos - xp.stack(origins)  # (n, 3, P)
        jv = xp.stack([z[:, 1] * r[:, 2] - z[:, 2] * r[:, 1], z[:, 2] * r[:, 0] - z[:, 0] * r[:, 2],
                       z[:, 0] * r[:, 1] - z[:, 1] * r[:, 0]])  # (3, n, P)
        jac = xp.concat([jv, xp.permute_dims(z, (1, 0, 2))]) if self.space == "pose" else jv[: self.m]
        return r_out, p_out, xp.reshape(xp.permute_dims(jac, (2, 0, 1)), (*lead, self.m, self.n))

    def _chain_small(self, q: A, jacobian: bool) -> tuple[A, A, A | None]:
        """_chain() from frames(): fewer, larger ops, faster for a few configurations."""
        f = self.frames(q)
        xp = xp_of(f)
        rot, tip = f[..., -1, :3, :3], f[..., -1, :3, 3]
        if not jacobian:
            return rot, tip, None
        z, o = f[..., :-1, :3, 2], f[..., :-1, :3, 3]
        jv = xp.linalg.cross(z, tip[..., None, :] - o, axis=-1)  # (..., n, 3)
        jac = xp.concat([jv, z], axis=-1) if self.space == "pose" else jv[..., : self.m]
        return rot, tip, jac.mT

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

        def err(t: Any, xt: Any) -> Any:
            e = self.tip_error(*self.tip(t), xt)
            norm = xp_of(e).linalg.vector_norm
            ep = norm(e[..., :3] if self.space == "pose" else e, axis=-1) / self.reach
            if self.space != "pose":
                return ep
            return 0.5 * ep + 0.5 * norm(e[..., 3:], axis=-1) / math.pi

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

        def canon(xt: Any) -> tuple[Any, Any]:
            xt = self._x(xt)
            xp = xp_of(xt)
            phi = xp.atan2(xt[..., 1], xt[..., 0])
            rho = xp.hypot(xt[..., 0], xt[..., 1])
            shift = xp.zeros((*xt.shape[:-1], self.n), dtype=xt.dtype, device=_device(xt))
            shift[..., 0] = phi
            if self.space == "xy":
                return rho[..., None], shift
            if self.space == "xyz":
                return xp.stack([rho, xt[..., 2]], axis=-1), shift
            rc = rot_z(-phi) @ rot_from_vec(xt[..., 3:])
            if not self.tool_roll:
                return xp.concat([xp.stack([rho, xt[..., 2]], axis=-1), vec_from_rot(rc)], axis=-1), shift
            axis = rc[..., :, 2]
            polar = xp.acos(xp.clip(axis[..., 2], -1.0, 1.0))
            azimuth = xp.atan2(axis[..., 1], axis[..., 0])
            roll = (rot_z(azimuth) @ rot_y(polar)).mT @ rc  # Rz(psi)
            shift[..., -1] = xp.atan2(roll[..., 1, 0], roll[..., 0, 0])
            return xp.stack([rho, xt[..., 2], polar, azimuth], axis=-1), shift

        return _io(canon, x)

    def uncanonical(self, c: A, shift: A | None = None) -> A:
        """The location whose canonical form is (c, shift); shift None: all zeros."""

        def unc(ct: Any, *sh: Any) -> Any:
            if ct.shape[-1] != self.c_dim:
                raise ArmbridgeError(
                    f"robot {self.name!r}: canonical locations have {self.c_dim} numbers, got shape {tuple(ct.shape)}"
                )
            xp = xp_of(ct)
            st = sh[0] if sh else xp.zeros((*ct.shape[:-1], self.n), dtype=ct.dtype, device=_device(ct))
            if st.shape[-1] != self.n:
                raise ArmbridgeError(f"robot {self.name!r}: shift needs one offset per joint ({self.n}), "
                                     f"got shape {tuple(st.shape)}")
            rho, pt = ct[..., 0], st[..., 0]
            xy = xp.stack([rho * xp.cos(pt), rho * xp.sin(pt)], axis=-1)
            if self.space == "xy":
                return xy
            if self.space == "xyz":
                return xp.concat([xy, ct[..., 1:2]], axis=-1)
            if self.tool_roll:
                r = rot_z(ct[..., 3]) @ rot_y(ct[..., 2]) @ rot_z(st[..., -1])
            else:
                r = rot_from_vec(ct[..., 2:])
            return xp.concat([xy, ct[..., 1:2], vec_from_rot(rot_z(pt) @ r)], axis=-1)

        return _io(unc, c) if shift is None else _io(unc, c, shift)

    # -- description -------------------------------------------------------
    @classmethod
    def from_planar(cls, chain: PlanarChain) -> DHChain:
        """The 'xy' DH chain of a planar chain (a = link lengths, the rest 0), with
        its limits and joint names (SMMs ignore the limits)."""
        zeros = np.zeros(chain.n)
        return cls(name=chain.name, a=chain.link_lengths.copy(), alpha=zeros, d=zeros, theta=zeros, space="xy",
                   q_min=chain.q_min, q_max=chain.q_max, v_max=chain.v_max, joint_names=chain.joint_names)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description; from_dict(to_dict()) gives an equal chain."""
        d = {"name": self.name, **{f: getattr(self, f).tolist() for f in _DH_FIELDS}, "space": self.space}
        d.update({f: getattr(self, f).tolist() for f in _LIMIT_FIELDS[:3]})
        d["joint_names"] = list(self.joint_names)
        return d

    @classmethod
    def from_dict(cls, d: Any) -> DHChain:
        """Build from a JSON description with the keys of to_dict() (the limit keys may be left out)."""
        return cls(**description_fields(d, _FIELDS, "DH chain description", optional=_LIMIT_FIELDS))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, DHChain) and self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(json.dumps(self.to_dict()))

    # -- internals (array in, array of the same kind out) ---------------------
    def _params(self, like: Any) -> tuple[Any, ...]:
        """(E C, P_c C, P_s C, theta offsets) per joint, arrays of like's kind on its device, cached."""
        cache = self._cache
        xp, dev = xp_of(like), _device(like)
        key = (xp.__name__, str(dev))
        if key not in cache:
            c = np.zeros((self.n, 4, 4))
            ca, sa = np.cos(self.alpha), np.sin(self.alpha)
            c[:, 0, 0], c[:, 0, 3] = 1.0, self.a
            c[:, 1, 1], c[:, 1, 2] = ca, -sa
            c[:, 2, 1], c[:, 2, 2], c[:, 2, 3] = sa, ca, self.d
            c[:, 3, 3] = 1.0
            e, pc, ps = np.diag([0.0, 0, 1, 1]), np.diag([1.0, 1, 0, 0]), np.zeros((4, 4))
            ps[0, 1], ps[1, 0] = -1.0, 1.0
            mats = [e @ c, pc @ c, ps @ c, self.theta]
            cache[key] = tuple(xp.asarray(np.array(v), dtype=xp.float64, device=dev) for v in mats)  # writable copies
        return cache[key]

    def _q(self, q: A) -> A:
        if q.ndim == 0 or q.shape[-1] != self.n:
            raise ArmbridgeError(f"robot {self.name!r}: q must have shape (..., {self.n}), got {tuple(q.shape)}")
        xp = xp_of(q)
        return xp.astype(q, xp.float64, copy=False)

    def _x(self, x: A) -> A:
        if x.ndim == 0 or x.shape[-1] != self.m:
            raise ArmbridgeError(
                f"robot {self.name!r}: a location has {self.m} numbers ({self.space}), got shape {tuple(x.shape)}"
            )
        xp = xp_of(x)
        return xp.astype(x, xp.float64, copy=False)

    def _task_of(self, rot: A, tip: A) -> A:
        if self.space == "pose":
            return xp_of(tip).concat([tip, vec_from_rot(rot)], axis=-1)
        return tip[..., : self.m]

    def tip_error(self, rot: A, tip: A, x: A) -> A:
        """Delta x_e from a tip (rotation, position) to x: position difference, then ('pose') the
        rotation vector of R_x R^T (world frame)."""
        x = self._x(x)
        if self.space != "pose":
            return x - tip[..., : self.m]
        r_err = rot_from_vec(x[..., 3:]) @ rot.mT
        return xp_of(x).concat([x[..., :3] - tip, vec_from_rot(r_err)], axis=-1)


def _io(f: Callable[..., Any], *args: Any) -> Any:
    """Call f on float64 arrays of the first argument's kind: a tensor gives tensors on its device,
    anything else numpy arrays."""
    first = args[0]
    if is_torch_array(first):
        import torch

        return f(*(torch.as_tensor(a, dtype=torch.float64, device=first.device) for a in args))
    return f(*(np.asarray(a, dtype=np.float64) for a in args))


def _finite_vector(where: str, field: str, value: Any) -> np.ndarray:
    """A finite 1-D float copy of value, or an ArmbridgeError naming the field."""
    try:
        v = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ArmbridgeError(f"{where}: {field} must be a list of numbers, got {value!r}") from None
    if v.ndim != 1 or not np.all(np.isfinite(v)):
        raise ArmbridgeError(f"{where}: {field} must be a flat list of finite numbers, got {value!r}")
    return v
