"""The MASR actuator plant's parameters and pure step functions (ma_plant.py holds
the state, MaPlant; the model is in its docstring and docs/emulator.md,
"MASR actuator"). Every function here is pure: floats (or numpy) in, floats
out, the random draws passed in.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from armbridge.errors import ArmbridgeError


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

    Hidden truth (`plant=random`: ma_plant.SPREADS, docs/emulator.md); the
    defaults are neutral, the plant the firmware's config describes:
    wheel_scale     1.0       the wheel's true mm per count / WHEEL_MM_PER_COUNT
    magnet_mm       0.0       each magnet's offset from its joint's r_j (mm, + away
                              from the base; one per joint, or one for all)
    hall_window_mm  None      the hall sensor's true half-window (None: HALL_WINDOW_MM)
    backlash_mrad   None      each worm's true play (None: BACKLASH_MRAD; one per joint or one)
    joint_friction  0.0       effort lost to joint j's friction while the worm turns it
                              (a dead band, fraction of full effort; one per joint or one)
    end_mm          0.0       the far end stop's offset from l, the links' sum (mm, + beyond)
    mesh_load       0.03      the load (effort) the worm takes while it drives a gear, what the
                              rotation driver's current sense reads then (the mesh's and the
                              joint's friction, capped at the effort: w_full is the speed
                              while driving, so it holds this load's share already); 0 in the play
    sense_noise     0.002     the current sense's noise (sd, effort)
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
    wheel_scale: float = 1.0
    magnet_mm: float | tuple[float, ...] = 0.0
    hall_window_mm: float | None = None
    backlash_mrad: float | tuple[float, ...] | None = None
    joint_friction: float | tuple[float, ...] = 0.0
    end_mm: float = 0.0
    mesh_load: float = 0.03
    sense_noise: float = 0.002


def per_joint(x: Any, n: int, what: str) -> list[float]:
    """One float per joint from a scalar or a sequence of n. Pure."""
    if isinstance(x, (int, float)):
        return [float(x)] * n
    v = [float(y) for y in x]
    if len(v) != n:
        raise ArmbridgeError(f"MaParams.{what}: {len(v)} values for {n} joints")
    return v


def friction(u: float, f: float) -> float:
    """Effort u less a dead band f (Coulomb friction as a fraction of full effort). Pure."""
    if f <= 0.0:
        return u
    return math.copysign(max(abs(u) - f, 0.0), u)


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


def pushing(gap: float, half: float, u: float) -> bool:
    """The worm drives its gear: the play taken up (gap at +-half) on the side the
    effort u turns it toward. Pure."""
    return (u > 0.0 and gap >= half) or (u < 0.0 and gap <= -half)


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
