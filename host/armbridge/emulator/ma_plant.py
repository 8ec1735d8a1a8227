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
ma_steps.py's, with MaParams (re-exported here): `loco_step`, `slip_step`,
`hall_step`, `engaged`, `backlash`, `rot_step`, `counts`; `MaPlant` holds the
state, the faults and the seeded noise. The arm's pose is
`robots.masr.MasrArm`'s (`MaPlant.points()`, `MaPlant.ma_point()`).

Hidden truth (`plant=random`, truth.py): MaParams' wheel_scale, magnet_mm,
hall_window_mm, backlash_mrad, joint_friction and end_mm (neutral by default:
the plant above) say where this MA differs from its config: the wheel's true
travel per count (WHEEL_MM_PER_COUNT * wheel_scale), magnet j at r_j +
magnet_mm[j] (the gear stays at r_j), the sensor's true window, each worm's true
play, a dead band of friction on the rotation effort while the worm turns joint
j, the far end stop at l + end_mm, and the load the worm takes while it drives
a gear (mesh_load, plus the joint's friction), which `rot_load` reads with
noise as the rotation driver's current sense does (0 in the play: that is how
the firmware sees the play taken up).
`SPREADS` says how each varies (and v_full, w_full, slip_sigma), and
`hidden_truth(cfg, rng)` draws one MA (docs/emulator.md, "Hidden truth").
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np

from armbridge.emulator.ma_steps import (MaParams, backlash, count, counts, drive_step, engaged, friction,
                                         ground_step, hall_step, loco_step, per_joint, pushing, rot_step,
                                         slip_step)
from armbridge.emulator.truth import Spread, draw
from armbridge.errors import ArmbridgeError
from armbridge.robots.masr import MasrArm

__all__ = ["MaParams", "MaPlant", "SPREADS", "backlash", "count", "counts", "drive_step", "engaged", "ground_step",
           "hall_step", "hidden_truth", "loco_step", "ma_plant", "nominal_params", "rot_step", "slip_step"]


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
        self.length = arm.total_length + self.p.end_mm / 1000.0   # the far end stop (d's hard end)
        p = self.p
        self.r = tuple(float(x) for x in arm.r)   # gears at r_j (eq. (1)), m
        self.magnets = tuple(rj + m / 1000.0 for rj, m in zip(self.r, per_joint(p.magnet_mm, nj, "magnet_mm")))
        self.wheel_q = float(wheel_mm) / 1000.0 * p.wheel_scale   # the true travel per count
        self.gear_q = float(gear_mrad) / 1000.0
        self.window = float(hall_mm if p.hall_window_mm is None else p.hall_window_mm) / 1000.0
        play = per_joint(backlash_mrad if p.backlash_mrad is None else p.backlash_mrad, nj, "backlash_mrad")
        self.halves = [0.5 * b / 1000.0 for b in play]
        self.half = max(self.halves)
        self.friction = per_joint(p.joint_friction, nj, "joint_friction")
        lo = -np.asarray(arm.theta_b, float) if lo is None else np.asarray(lo, float)
        hi = np.asarray(arm.theta_b, float) if hi is None else np.asarray(hi, float)
        self.lo_stop = [float(x) - self.p.stop_margin for x in lo]
        self.hi_stop = [float(x) + self.p.stop_margin for x in hi]
        self.rng = np.random.default_rng(seed)
        self.seed = int(seed)
        self.load = 0.0       # the load the worm drives (effort), what the current sense reads less its noise
        q = np.zeros(self.n) if q0 is None else np.asarray(q0, float)
        if q.shape != (self.n,):
            raise ArmbridgeError(f"MA q0 needs {self.n} values (theta_1..theta_{nj}, d), got {q.shape}")
        self.theta = [min(max(float(x), a), b) for x, a, b in zip(q[:nj], self.lo_stop, self.hi_stop)]
        self.d = min(max(float(q[nj]), 0.0), self.length)
        h = np.asarray(self.halves)
        self.gap = [float(x) for x in self.rng.uniform(-h, h, nj)]  # worm minus joint, rad
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
        self.level, _ = hall_step(False, self.d, self.magnets, self.window, self.p.hall_hyst_mm / 1000.0,
                                  self.present)
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

    def rot_load(self) -> float:
        """The rotation driver's current sense (effort units): the load while the worm
        drives a gear, about 0 while it turns in the play or off a joint, plus noise.
        The noise is a function of the seed and the plant's time (us), not a stream,
        so a reading does not depend on how often anyone read before (the CPython and
        the MicroPython firmware read at different moments and must see one plant)."""
        z = np.random.default_rng([self.seed, 1, int(round(self.t * 1e6))]).standard_normal()
        return self.load + self.p.sense_noise * float(z)

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
        self.level, k = hall_step(self.level, self.d, self.magnets, self.window, p.hall_hyst_mm / 1000.0,
                                  self.present)
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
            self.gap[j] = float(self.rng.uniform(-self.halves[j], self.halves[j]))  # a fresh mesh: the play anywhere
        self.engaged = j
        u_rot = self.u_rot if j < 0 else friction(self.u_rot, self.friction[j])
        w1, om1 = rot_step(self.w, self.om, u_rot, h, p)
        if u_rot == 0.0 and abs(om1) < p.rest_frac * p.w_full:
            om1 = 0.0
        if j >= 0:
            th, self.gap[j], refused = backlash(self.theta[j], self.gap[j], w1 - self.w, self.halves[j],
                                                self.lo_stop[j], self.hi_stop[j], self.stall_from[j] <= t)
            self.theta[j] = th
            if refused != 0.0:
                w1 -= refused
                om1 = 0.0
        u = self.u_rot
        self.load = (min(abs(u), p.mesh_load + self.friction[j]) if j >= 0 and pushing(self.gap[j], self.halves[j], u)
                     else 0.0)
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


def nominal_params(cfg: Any) -> MaParams:
    """MaParams with the config's SLIP_MAX as slip_bound and HALL_RING as edge_ring
    when it has them (the numbers the firmware was built for)."""
    params = MaParams()
    if hasattr(cfg, "SLIP_MAX"):
        params = replace(params, slip_bound=float(cfg.SLIP_MAX))
    if hasattr(cfg, "HALL_RING"):
        params = replace(params, edge_ring=int(cfg.HALL_RING))
    return params


#: MaParams' hidden truth (`plant=random`, truth.py): what varies from MA to MA. The masr
#: paper gives no tolerances; its Table II (E1: 11 +- 3.1 mm, 1.2 +- 0.8 deg, 48.78 +- 1.81 s
#: over ten roll-outs, the errors "due to fabrication uncertainties") is what they are sized
#: against (docs/emulator.md, "Hidden truth"). Nominals: the config's where it has the number.
SPREADS: tuple[Spread, ...] = (
    Spread("wheel_scale", "scale", 0.004, lo=0.99, hi=1.01,
           source="rubber tyre on a printed hub: diameter within +-1 % (ours); WHEEL_MM_PER_COUNT uncalibrated"),
    Spread("magnet_mm", "normal", 0.5, per_joint=True, lo=-1.0, hi=1.0, unit="mm",
           source="a magnet glued into each printed joint, within +-1 mm of r_j (ours)"),
    Spread("hall_window_mm", "normal", 0.15, lo=1.0, hi=2.0, unit="mm",
           source="hall switch operate point (A3144-class data sheets: B_OP spreads tens of %) about HALL_WINDOW_MM"),
    Spread("backlash_mrad", "normal", 6.0, per_joint=True, lo=1.0, hi=30.0, unit="mrad",
           source="printed worm and gear: play about 15 mrad (0.9 deg), not the config's 3 (ours, sized to "
                  "Table II's 1.2 +- 0.8 deg)"),
    Spread("slip_sigma", "scale", 0.3, lo=0.001, hi=0.008,
           source="rubber on the link, load and dirt (ours); clipped at SLIP_MAX as ever"),
    Spread("v_full", "scale", 0.08, lo=0.097, hi=0.14, unit="m/s",
           source="motor constant and supply (ours); down to 97 % of the firmware's 100 mm/s"),
    Spread("w_full", "scale", 0.05, lo=0.30, hi=0.40, unit="rad/s",
           source="rotation motor (ours); kept above the firmware's 0.28 rad/s with the friction"),
    Spread("joint_friction", "uniform", 0.03, per_joint=True, lo=0.0, hi=0.06,
           source="each joint's friction through its worm: 0-6 % of full effort, about 0.03 (ours)"),
    Spread("end_mm", "normal", 0.2, lo=-0.5, hi=0.5, unit="mm",
           source="the end cap printed onto the last link: its stop within +-0.5 mm of l (ours)"),
    Spread("mesh_load", "normal", 0.008, lo=0.015, hi=0.05,
           source="the worm's mesh driving a printed gear: 1.5-5 % of full effort on the current sense, "
                  "above the joint's friction (ours; a self-locking worm is lossy)"),
)
#: the truth's centre where it is not the config's or MaParams' neutral default
TRUTH_NOMINAL: dict[str, Any] = {"backlash_mrad": 15.0, "joint_friction": 0.03}


def hidden_truth(cfg: Any, rng: np.random.Generator) -> MaParams:
    """One MA's hidden truth: `nominal_params(cfg)` with the config's hall window and
    backlash as the nominals, every SPREADS field drawn from rng (truth.truth_rng)."""
    centre = {"hall_window_mm": float(cfg.HALL_WINDOW_MM), "backlash_mrad": float(cfg.BACKLASH_MRAD)} | TRUTH_NOMINAL
    nominal = replace(nominal_params(cfg), **centre)
    return draw(nominal, SPREADS, rng, len(cfg.LINK_LENGTHS_MM))


def ma_plant(cfg: Any, params: MaParams | None, q0, seed: int) -> MaPlant:
    """The MA's plant from its firmware config (the registry's plant factory).
    Without `params`, `nominal_params(cfg)`."""
    if params is not None and not isinstance(params, MaParams):
        raise ArmbridgeError(f"the masr_ma plant takes MaParams, not {type(params).__name__}")
    if params is None:
        params = nominal_params(cfg)
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
