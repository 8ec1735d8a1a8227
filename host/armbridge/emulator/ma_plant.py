"""Plant of the MASR mobile actuator (MA) on its arm (masr paper, section II-A).

The MA drives along the arm on a wheel, counts the joints' magnets with a hall
sensor, and turns the joint it stands on through a worm gear. The numbers that
the firmware also knows come from its config (firmware/masr_ma/config.py:
LINK_LENGTHS_MM, the joint limits, WHEEL_MM_PER_COUNT, GEAR_MRAD_PER_COUNT,
HALL_WINDOW_MM, BACKLASH_MRAD); the rest are ours, in `MaParams` and
docs/emulator.md ("MASR actuator").

Locomotion, with effort u in [-1, 1] (+ away from the base):

    v_cmd = u * v_full                       wheel speed at full effort
    dv/dt = (v_cmd - v) / tau, |dv/dt| <= a_max  (plant.step: lag, then the limit)
    ds = v dt                                the wheel's own travel (the encoder's)
    dd = ds * (1 + slip)                     ground truth d (the paper's d-dot)
    slip: AR(1) noise, correlation slip_tau, clipped to +-slip_bound;
          a burst fault sets slip = -F (the wheel spins, the MA advances less)
    d stops at the hard ends 0 and l, and the wheel with it
    with no effort, v snaps to 0 below rest_frac * v_full (static friction)
    wheel_count = floor(s / WHEEL_MM_PER_COUNT)

Hall sensor: high once |d - r_j| <= HALL_WINDOW_MM for some joint j (its magnet
sits at r_j, eq. (1)), low again only when |d - r_j| > HALL_WINDOW_MM +
hall_hysteresis; the wheel count is latched at every rising edge (the
firmware's IRQ). A missed-magnet fault removes magnet j.

Joint rotation, with effort u: the worm turns like the wheel (plant.step, at
w_full joint-rad/s); gear_count = floor(w / GEAR_MRAD_PER_COUNT). The worm
meshes with joint j's gear only while |d - r_j| <= engage_mm; then the gear
follows the worm through BACKLASH_MRAD of play (`backlash`). A worm that is
not driven holds its joint (self-locking); a seized joint (stall fault) or a
joint at its hard stop stops the worm once the play is taken up.

The pure step functions (numpy in, numpy out, the random draws passed in) are
`loco_step`, `slip_step`, `hall_step`, `engaged`, `backlash`, `rot_step`,
`counts`; `MaPlant` holds the state, the faults and the seeded noise. The arm's
pose is `robots.masr.MasrArm`'s (`MaPlant.points()`, `MaPlant.ma_point()`).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.robots.masr import MasrArm


@dataclass(frozen=True)
class MaParams:
    """The MA's physical numbers that the firmware config does not hold (ours).

    v_full        0.12 m/s    MA speed at full locomotion effort (the firmware's 100 mm/s is 83 %)
    tau           0.040 s     speed lag of the drive (motor + gearbox + the MA's mass)
    a_max         1.0 m/s^2   acceleration limit (wheel traction)
    slip_bound    0.010       |slip| <= 1 % of the wheel's travel (rubber wheel on the link)
    slip_sigma    0.004       stationary std of the slip process before clipping
    slip_tau      0.20 s      its correlation time
    hall_hyst_mm  0.5 mm      the hall sensor's hysteresis beyond its window
    engage_mm     3.0 mm      the worm meshes with joint j's gear while |d - r_j| <= this
    w_full        0.35 rad/s  joint rate at full rotation effort (the firmware's 0.28 rad/s is 80 %)
    rot_tau       0.030 s     the rotation drive's speed lag
    rot_a_max     5.0 rad/s^2 its acceleration limit
    stop_margin   0.05 rad    the joints' hard stops this far beyond the firmware's limits
    grip_s        0.30 s      gripper servo travel, closed <-> open
    rest_frac     0.001       a drive without effort stops dead below this fraction of its
                              full speed (static friction: the lag alone never reaches 0)
    edge_ring     16          hall edges the IRQ ring holds between two reads
    max_dt        0.001 s     longest integration sub-step
    """

    v_full: float = 0.12
    tau: float = 0.040
    a_max: float = 1.0
    slip_bound: float = 0.010
    slip_sigma: float = 0.004
    slip_tau: float = 0.20
    hall_hyst_mm: float = 0.5
    engage_mm: float = 3.0
    w_full: float = 0.35
    rot_tau: float = 0.030
    rot_a_max: float = 5.0
    stop_margin: float = 0.05
    grip_s: float = 0.30
    rest_frac: float = 0.001
    edge_ring: int = 16
    max_dt: float = 0.001


def drive_step(x: float, v: float, u: float, dt: float, v_full: float, tau: float, a_max: float,
               stalled: bool = False) -> tuple[float, float]:
    """One drive (the wheel: x = its travel in m; the worm: x = its angle in joint
    rad) after dt under effort u: plant.step's model (v follows u * v_full through
    the lag tau, its change clipped to a_max dt, x integrates v by the trapezoid;
    stalled: v = 0) on floats, since the MA steps its two drives every
    millisecond and numpy's one-element arrays cost 60 times as much
    (tests/test_ma_plant.py holds it equal to plant.step). Pure."""
    u = min(max(u, -1.0), 1.0)
    dv = (u * v_full - v) * (1.0 - math.exp(-dt / tau))
    lim = a_max * dt
    v1 = v + min(max(dv, -lim), lim)
    if stalled:
        return x, 0.0
    return x + 0.5 * (v + v1) * dt, v1


def loco_step(s: float, v: float, u: float, dt: float, p: MaParams, stalled: bool = False) -> tuple[float, float]:
    """The wheel's travel s (m) and speed v (m/s) after dt under effort u. Pure."""
    return drive_step(s, v, u, dt, p.v_full, p.tau, p.a_max, stalled)


def rot_step(w: float, om: float, u: float, dt: float, p: MaParams) -> tuple[float, float]:
    """The worm's angle w (joint-equivalent rad) and rate om after dt under effort u. Pure."""
    return drive_step(w, om, u, dt, p.w_full, p.rot_tau, p.rot_a_max)


def slip_step(slip: float, z: float, dt: float, p: MaParams) -> float:
    """Next slip fraction: AR(1) with correlation time slip_tau and stationary
    std slip_sigma, driven by the standard normal draw z, clipped to +-slip_bound. Pure."""
    a = math.exp(-dt / p.slip_tau)
    nxt = slip * a + p.slip_sigma * math.sqrt(1.0 - a * a) * z
    return min(max(nxt, -p.slip_bound), p.slip_bound)


def ground_step(d: float, ds: float, slip: float, length: float) -> tuple[float, float, bool]:
    """Ground truth d after the wheel travels ds with `slip`: (d, the wheel travel
    that happened, at_end). At a hard end (0 or l) the MA stops and the wheel
    with it: only the travel up to the end counts. Pure."""
    nd = d + ds * (1.0 + slip)
    if 0.0 <= nd <= length:
        return nd, ds, False
    end = 0.0 if nd < 0.0 else length
    k = 1.0 + slip
    return end, ((end - d) / k if k > 0 else 0.0), True


def counts(x: Any, quantum: float) -> np.ndarray:
    """Encoder counts of x (same unit as quantum): floor(x / quantum), numpy in and out. Pure."""
    return np.floor(np.asarray(x, dtype=float) / quantum + 1e-9).astype(np.int64)


def count(x: float, quantum: float) -> int:
    """`counts` of one float (the plant's per-step call)."""
    return math.floor(x / quantum + 1e-9)


def hall_step(level: bool, d: float, r: Sequence[float], window: float, hyst: float,
              present: Sequence[bool]) -> tuple[bool, int]:
    """The hall sensor at d: (new level, 0-based joint of a rising edge or -1).
    On within +-window of a present magnet r_j, off beyond window + hyst,
    unchanged between (hysteresis). Pure."""
    k, near = -1, math.inf
    for j, rj in enumerate(r):
        if present[j] and abs(rj - d) < near:
            k, near = j, abs(rj - d)
    if near <= window:
        return True, (-1 if level else k)
    if near > window + hyst:
        return False, -1
    return level, -1


def engaged(d: float, r: Sequence[float], tol: float) -> int:
    """The 0-based joint whose gear the worm meshes with at d (|d - r_j| <= tol), or -1. Pure."""
    for j, rj in enumerate(r):
        if abs(rj - d) <= tol:
            return j
    return -1


def backlash(theta: float, gap: float, dw: float, half: float, lo: float, hi: float,
             seized: bool) -> tuple[float, float, float]:
    """The worm turns dw (joint rad) against joint angle theta through play of
    +-half (gap: worm minus joint, in [-half, half]). -> (theta, gap, refused):
    the gap takes dw up first, what goes past it turns the joint; what the joint
    cannot take (seized, or at its hard stop lo/hi) is `refused` (the worm
    stops short by that much). Pure."""
    g = gap + dw
    push = g - half if g > half else (g + half if g < -half else 0.0)
    if push == 0.0:
        return theta, g, 0.0
    target = theta + push
    moved = target if not seized else theta
    moved = min(max(moved, lo), hi)
    refused = target - moved
    return moved, (half if push > 0 else -half), refused


class MaPlant:
    """The MA on its arm, with time, faults and seeded slip; see the module docstring.

    arm: the arm (link lengths, joint bounds); wheel_mm, gear_mrad: encoder
    quanta; hall_mm: the hall window; backlash_mrad: the worm's play; lo, hi:
    the firmware's joint limits (rad); q0: (theta_1..theta_{n-1}, d) in rad, m
    (default: every joint 0, the MA at the base).
    """

    def __init__(self, arm: MasrArm, wheel_mm: float, gear_mrad: float, hall_mm: float, backlash_mrad: float,
                 lo=None, hi=None, params: MaParams | None = None, q0=None, seed: int = 0) -> None:
        self.p = params or MaParams()
        self.arm = arm
        nj = arm.n
        self.n = nj + 1
        self.length = arm.total_length
        self.r = tuple(float(x) for x in arm.r)   # magnets and gears at r_j (eq. (1)), m
        self.wheel_q = float(wheel_mm) / 1000.0
        self.gear_q = float(gear_mrad) / 1000.0
        self.window = float(hall_mm) / 1000.0
        self.half = 0.5 * float(backlash_mrad) / 1000.0
        lo = -np.asarray(arm.theta_b, float) if lo is None else np.asarray(lo, float)
        hi = np.asarray(arm.theta_b, float) if hi is None else np.asarray(hi, float)
        self.lo_stop = [float(x) - self.p.stop_margin for x in lo]
        self.hi_stop = [float(x) + self.p.stop_margin for x in hi]
        self.rng = np.random.default_rng(seed)
        q = np.zeros(self.n) if q0 is None else np.asarray(q0, float)
        if q.shape != (self.n,):
            raise ArmbridgeError(f"MA q0 needs {self.n} values (theta_1..theta_{nj}, d), got {q.shape}")
        self.theta = [min(max(float(x), a), b) for x, a, b in zip(q[:nj], self.lo_stop, self.hi_stop)]
        self.d = min(max(float(q[nj]), 0.0), self.length)
        self.gap = [float(x) for x in self.rng.uniform(-self.half, self.half, nj)]  # worm minus joint, rad
        self.s = 0.0          # wheel travel (m)
        self.v = 0.0          # wheel speed (m/s)
        self.w = 0.0          # worm angle (joint rad)
        self.om = 0.0         # worm rate
        self.slip = 0.0
        self.u_loco = 0.0
        self.u_rot = 0.0
        self.grip_open = False
        self.grip_pos = 0.0   # 0 closed .. 1 open
        self.t = 0.0
        self.present = [True] * nj                  # magnets that fire (missed-magnet faults clear one)
        self.stall_from = [math.inf] * self.n       # joints 0..nj-1 seized, index nj: the wheel
        self.bursts: list[tuple[float, float, float]] = []  # (from s, for s, fraction F)
        self.engaged = engaged(self.d, self.r, self.p.engage_mm / 1000.0)
        self.level, _ = hall_step(False, self.d, self.r, self.window, self.p.hall_hyst_mm / 1000.0, self.present)
        self._ring: deque[int] = deque()
        self.edges: list[tuple[float, int, int, float]] = []   # (t, joint 1.., latched count, true d)
        self.ring_overflows = 0
        self.faults_applied: list[tuple[float, str, Any]] = []
        self._burst_on = False
        self._stalls_seen: set[int] = set()
        self._next_stall = math.inf

    # state ---------------------------------------------------------------
    @property
    def q(self) -> np.ndarray:
        """True (theta_1..theta_{n-1}, d) in rad and m."""
        return np.r_[self.theta, self.d]

    def points(self) -> np.ndarray:
        """The arm's polyline (n, 2): base, every joint, the tip (MasrArm.joint_points)."""
        return self.arm.joint_points(self.q)

    def ma_point(self) -> np.ndarray:
        """Where the MA is in the plane (x, y) (MasrArm.ma_point)."""
        return self.arm.ma_point(self.q)

    # drive ---------------------------------------------------------------
    def set_loco(self, u: float) -> None:
        self.u_loco = min(max(float(u), -1.0), 1.0)

    def set_rot(self, u: float) -> None:
        self.u_rot = min(max(float(u), -1.0), 1.0)

    def set_grip(self, open_: bool) -> None:
        self.grip_open = bool(open_)

    def off(self) -> None:
        """Both motors off (the worm holds the joints); the gripper holds."""
        self.u_loco = 0.0
        self.u_rot = 0.0

    # sensors -------------------------------------------------------------
    def wheel_count(self) -> int:
        return count(self.s, self.wheel_q)

    def gear_count(self) -> int:
        return count(self.w, self.gear_q)

    def pop_edges(self) -> list[int]:
        """The counts latched at the hall rising edges since the last call, oldest first."""
        out = list(self._ring)
        self._ring.clear()
        return out

    # faults --------------------------------------------------------------
    def stall(self, j: int, t: float) -> None:
        """Coordinate j (0-based) stalls from plant time t on: joint j+1 seizes (the
        rotation motor stalls while it turns it), j = n-1 (d): the wheel stalls."""
        if not 0 <= j < self.n:
            raise ArmbridgeError(f"stall {j + 1}: the MA has coordinates 1..{self.n} (joints 1..{self.n - 1}, d)")
        self.stall_from[j] = min(self.stall_from[j], float(t))
        self._next_stall = min(self._next_stall, self.stall_from[j])

    def miss(self, joint: int) -> None:
        """Magnet of joint `joint` (1..n-1) never fires."""
        if not 1 <= joint <= self.n - 1:
            raise ArmbridgeError(f"missed magnet {joint}: the arm has joints 1..{self.n - 1}")
        self.present[joint - 1] = False
        self.faults_applied.append((self.t, "missed", joint))

    def burst(self, start: float, duration: float, fraction: float) -> None:
        """From `start` for `duration` s the slip is -fraction (the wheel spins)."""
        self.bursts.append((float(start), float(duration), float(fraction)))

    def inject(self, faults: Any) -> None:
        """The MA's own faults of a `faults.Faults` (missed magnets, slip bursts)."""
        for j in faults.missed:
            self.miss(j)
        for s, dur, f in faults.slip:
            self.burst(s, dur, f)

    def _burst(self, t: float) -> float | None:
        for s, dur, f in self.bursts:
            if s <= t < s + dur:
                return -f
        return None

    # time ----------------------------------------------------------------
    def advance(self, dt: float) -> None:
        """Integrate dt seconds in sub-steps of at most max_dt."""
        while dt > 1e-12:
            h = min(dt, self.p.max_dt)
            self._step(h)
            self.t += h
            dt -= h

    def advance_to(self, t: float) -> None:
        if t > self.t:
            self.advance(t - self.t)

    def _step(self, h: float) -> None:
        p = self.p
        nj = self.n - 1
        t = self.t + h
        if self._next_stall <= t:
            self._note_stalls(t)
        # locomotion and slip
        self.slip = slip_step(self.slip, float(self.rng.standard_normal()), h, p)
        forced = self._burst(self.t + 0.5 * h)
        if (forced is not None) != self._burst_on:
            self._burst_on = forced is not None
            self.faults_applied.append((self.t, "slip", -forced if forced is not None else 0.0))
        slip = self.slip if forced is None else forced
        s1, v1 = loco_step(self.s, self.v, self.u_loco, h, p, self.stall_from[nj] <= t)
        self.d, ds, at_end = ground_step(self.d, s1 - self.s, slip, self.length)
        self.s += ds
        self.v = 0.0 if at_end or (self.u_loco == 0.0 and abs(v1) < p.rest_frac * p.v_full) else v1
        # hall sensor
        self.level, k = hall_step(self.level, self.d, self.r, self.window, p.hall_hyst_mm / 1000.0, self.present)
        if k >= 0:
            c = self.wheel_count()
            if len(self._ring) < p.edge_ring:
                self._ring.append(c)
            else:
                self.ring_overflows += 1
            self.edges.append((t, k + 1, c, self.d))
        # joint rotation through the worm
        j = engaged(self.d, self.r, p.engage_mm / 1000.0)
        if j != self.engaged and j >= 0:
            self.gap[j] = float(self.rng.uniform(-self.half, self.half))  # a fresh mesh: the play anywhere
        self.engaged = j
        w1, om1 = rot_step(self.w, self.om, self.u_rot, h, p)
        if self.u_rot == 0.0 and abs(om1) < p.rest_frac * p.w_full:
            om1 = 0.0
        if j >= 0:
            th, self.gap[j], refused = backlash(self.theta[j], self.gap[j], w1 - self.w, self.half,
                                                self.lo_stop[j], self.hi_stop[j], self.stall_from[j] <= t)
            self.theta[j] = th
            if refused != 0.0:
                w1 -= refused
                om1 = 0.0
        self.w, self.om = w1, om1
        # gripper
        target = 1.0 if self.grip_open else 0.0
        step = h / p.grip_s
        self.grip_pos += min(max(target - self.grip_pos, -step), step)

    def _note_stalls(self, t: float) -> None:
        for j, at in enumerate(self.stall_from):
            if at <= t and j not in self._stalls_seen:
                self._stalls_seen.add(j)
                self.faults_applied.append((at, "stall", j + 1))
        later = [at for j, at in enumerate(self.stall_from) if j not in self._stalls_seen]
        self._next_stall = min(later) if later else math.inf


def ma_plant(cfg: Any, params: MaParams | None, q0, seed: int) -> MaPlant:
    """The MA's plant from its firmware config (the registry's plant factory).
    Without `params`, MaParams with the config's SLIP_MAX as slip_bound and
    HALL_RING as edge_ring when it has them (the numbers the firmware was built for)."""
    if params is not None and not isinstance(params, MaParams):
        raise ArmbridgeError(f"the masr_ma plant takes MaParams, not {type(params).__name__}")
    if params is None:
        params = MaParams()
        if hasattr(cfg, "SLIP_MAX"):
            params = replace(params, slip_bound=float(cfg.SLIP_MAX))
        if hasattr(cfg, "HALL_RING"):
            params = replace(params, edge_ring=int(cfg.HALL_RING))
    need = ("LINK_LENGTHS_MM", "WHEEL_MM_PER_COUNT", "GEAR_MRAD_PER_COUNT", "HALL_WINDOW_MM", "BACKLASH_MRAD")
    missing = [k for k in need if not hasattr(cfg, k)]
    if missing:
        raise ArmbridgeError(f"the masr_ma firmware config lacks {', '.join(missing)}")
    links = np.asarray(cfg.LINK_LENGTHS_MM, float) / 1000.0
    nj = links.size
    lims = getattr(cfg, "LIMITS", None) or getattr(cfg, "LIMITS_MRAD", None)
    lo = hi = None
    if lims is not None:
        lim = np.asarray(lims, float)
        lo, hi = lim[:nj, 0] / 1000.0, lim[:nj, 1] / 1000.0
    vmax = getattr(cfg, "VMAX", None) or getattr(cfg, "VMAX_MRAD_S", None) or [280] * nj + [100]
    arm = MasrArm(name=str(getattr(cfg, "FW_NAME", "masr_ma")), link_lengths=links,
                  theta_b=(np.minimum(np.maximum(np.abs(lo), np.abs(hi)), np.pi) if lo is not None and hi is not None
                           else np.full(nj, np.deg2rad(50.0))),
                  ma_speed=float(vmax[nj]) / 1000.0, joint_speed=float(vmax[0]) / 1000.0, link_width=0.0)
    return MaPlant(arm, cfg.WHEEL_MM_PER_COUNT, cfg.GEAR_MRAD_PER_COUNT, cfg.HALL_WINDOW_MM, cfg.BACKLASH_MRAD,
                   lo, hi, params, q0=q0, seed=seed)
