"""How long the pump board takes to move a soft-arm joint: (d) of planning/soft/waypoints.py.

The syringe-pump board (docs/pump.md) ramps each joint's set point linearly over a
waypoint's duration and drives the joint with the P controller of the WJRRT paper's
eq. 24 and a dead band, with the asymmetry of its Fig. 9a: a joint inflates abruptly
once its pressure passes a threshold and deflates smoothly, so the firmware inflates
with a lower gain and ceiling than it deflates. `pump_timing` turns the pneumatic
plant's numbers (emulator/pump_plant.py PumpParams) and the firmware's constants
(config.h) into the rates and allowances of `PumpTiming`; `durations` times a list of
waypoints with them. Pure: numbers in, numbers out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

#: The set point's speed as a fraction of the fastest the joint can follow at the controller's ceiling.
RATE_FRACTION = 0.5
#: Shortest move duration, s (two control periods of the board).
MOVE_MIN_S = 0.02


@dataclass(frozen=True)
class Opening:
    """What opening a closed (straight) joint takes: the syringe must push `volume_mm` of plunger
    travel (atmospheric pressure to the plant's opening pressure) before the joint bends at all.

    The P controller pushes at duty u(e) = clip(gain e, floor, cap) for a lag e beyond the band (none
    inside it), and the plunger moves at push_mm_s (u - dead) (the motor's dead zone); while the
    joint is closed the lag is the set point itself, e(t) = min(delta, rate t). `time` integrates the
    pushed volume at dt to when it reaches volume_mm. A lag above follow_rad for follow_s latches the
    board's FOLLOW fault, so a ramp that would keep the lag there that long (3/4 of it, for margin) is
    slowed (the rate by 0.8 at a time) until it does not."""

    volume_mm: float
    push_mm_s: float
    dead: float
    gain: float
    floor: float
    cap: float
    follow_rad: float
    follow_s: float
    dt: float = 0.005
    horizon_s: float = 60.0

    def time(self, delta: float, rate: float, band: float) -> tuple[float, float]:
        """(time to open, s: inf when the push never gets there, e.g. a move inside the band; the
        set point's rate, rad/s, slowed for the FOLLOW fault where needed)."""
        t = np.arange(1, int(self.horizon_s / self.dt) + 1) * self.dt
        for _ in range(20):
            e = np.minimum(delta, rate * t)
            duty = np.where(e > band, np.clip(self.gain * e, self.floor, self.cap), 0.0)
            pushed = np.cumsum(self.push_mm_s * np.maximum(duty - self.dead, 0.0)) * self.dt
            k = int(np.searchsorted(pushed, self.volume_mm))
            t_open = float(t[k]) if k < len(t) else math.inf
            over = float(np.sum((e > self.follow_rad) & (t <= t_open))) * self.dt
            if over <= 0.75 * self.follow_s:
                return t_open, rate
            rate *= 0.8
        return t_open, rate


@dataclass(frozen=True)
class PumpTiming:
    """How fast the pump board moves each joint (rad, s), from the plant and the firmware's constants.

    The model (`pump_timing` builds it, `durations` applies it):

    * r_full: the joint's bend rate at full duty, at the slowest point of its open branch (the plunger
      speed over the plunger travel per radian of bend; the pneumatic plant's quasi-static
      dx/dtheta, largest at the low-pressure end).
    * rate_in / rate_de: the set point's speed while the joint inflates / deflates: RATE_FRACTION of
      r_full at the controller's ceiling for that direction (inflation 700 per-mille, deflation 1000:
      the asymmetry), at most the robot's v_max. Half the ceiling keeps the following error inside
      the controller's proportional range, so the joint trails the set point at a steady lag.
    * settle_in_s / settle_de_s: the time after the set point arrives until the joint rests in the
      band, inflating / deflating: the steady lag (the error whose duty moves the joint at the ramp's
      speed, plus the bend's own time constant times the speed) decays through the proportional
      range to the dead band, integrated in closed form, plus one time constant of the bend.
    * opening (Opening): a closed joint stays straight until the syringe has pushed the opening
      volume (the abrupt inflation's threshold, Fig. 9a); it then snaps to snap_rad (the open
      branch's equilibrium with the air at the opening volume, less what the bend takes in) and
      either deflates back to a target below that or inflates on: the larger settle of the two.

    Per joint and move, from where the joint rests: the ramp |dq| / rate and the time until it rests,
    ramp + settle of its direction, or for a closed joint max(ramp, time to open) + the larger
    settle (a move inside the band needs none: the joint is there). A joint counts as closed at the
    rest pose until a move opens it, and again after a move to the rest pose (the deflation may close
    it). The move lasts the longest ramp; the hold after it, until the slowest joint rests.
    """

    band: np.ndarray
    rate_in: np.ndarray
    rate_de: np.ndarray
    settle_in_s: np.ndarray
    settle_de_s: np.ndarray
    snap_rad: np.ndarray
    rest: np.ndarray  # the arm's pose before the first waypoint (straight: the board at power on)
    opening: Opening

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {k: [round(float(x), 6) for x in getattr(self, k)] for k in
                             ("band", "rate_in", "rate_de", "settle_in_s", "settle_de_s", "snap_rad", "rest")}
        d["opening"] = {k: round(float(v), 6) for k, v in self.opening.__dict__.items()}
        return d


def _approach_s(e0: np.ndarray, band: float, g: float, cap: float, dead: float, floor: float, r_full: np.ndarray,
                tau: float) -> np.ndarray:
    """Time for the P controller's error to fall from e0 to band (rad): de/dt = -r_full (u - dead)/(1 - dead),
    u = clip(g e, floor, cap); closed form over the saturated and the proportional pieces; plus tau."""
    lo = max(band, floor / g)
    sat = np.maximum(e0 - cap / g, 0.0) * (1.0 - dead) / (r_full * (cap - dead))
    top = np.clip(e0, lo, cap / g)
    prop = (1.0 - dead) / (r_full * g) * np.log((g * top - dead) / (g * lo - dead))
    return sat + prop + tau


def pump_timing(params: Any, cfg: Any, q_max: Any, v_max: Any, q_rest: Any | None = None,
                rate_fraction: float = RATE_FRACTION) -> PumpTiming:
    """The PumpTiming of a pump board (its firmware constants `cfg`: DBAND_DEFAULT_MRAD, KP_DEFAULT,
    KP_INFLATE_PERMILLE, DUTY_MAX_INFLATE, DUTY_MAX_DEFLATE, DUTY_MIN) driving the pneumatic plant
    `params` (emulator.pump_plant.PumpParams) with joint ranges q_max (rad); see PumpTiming."""
    p = params
    rng = np.asarray(q_max, float)
    area = p.area_mm2 / 1000.0                                # mL per mm of plunger
    dx_dth = (p.p0_kpa * p.v_rest_ml * (p.p_full_kpa - p.p_hold_kpa) / (rng * (p.p_hold_kpa + p.p0_kpa) ** 2)
              + p.k_vol_ml) / area                            # mm per rad, largest at p_hold
    r_full = p.v_motor / dx_dth
    dead = p.dead_duty
    g_de = cfg.KP_DEFAULT / 1000.0                            # duty (fraction) per rad: per-mille per mrad
    g_in = g_de * cfg.KP_INFLATE_PERMILLE / 1000.0
    cap_in, cap_de, floor = cfg.DUTY_MAX_INFLATE / 1000.0, cfg.DUTY_MAX_DEFLATE / 1000.0, cfg.DUTY_MIN / 1000.0
    band = cfg.DBAND_DEFAULT_MRAD / 1000.0
    vmax = np.asarray(v_max, float)
    rate_in = np.minimum(rate_fraction * r_full * (cap_in - dead) / (1 - dead), vmax)
    rate_de = np.minimum(rate_fraction * r_full * (cap_de - dead) / (1 - dead), vmax)

    def lag(rate: np.ndarray, g: float, tau: float) -> np.ndarray:
        duty = dead + rate / r_full * (1 - dead)              # the duty that moves the joint at `rate`
        return np.maximum(duty, floor) / g + tau * rate

    settle_in = _approach_s(lag(rate_in, g_in, p.tau_inflate), band, g_in, cap_in, dead, floor, r_full,
                            p.tau_inflate)
    settle_de = _approach_s(lag(rate_de, g_de, p.tau_deflate), band, g_de, cap_de, dead, floor, r_full,
                            p.tau_deflate)
    opening = Opening(volume_mm=p.v_rest_ml * (1.0 - p.p0_kpa / (p.p0_kpa + p.p_open_kpa)) / area,
                      push_mm_s=p.v_motor / (1 - dead), dead=dead, gain=g_in, floor=floor, cap=cap_in,
                      follow_rad=cfg.FOLLOW_ERR_MRAD / 1000.0, follow_s=cfg.FOLLOW_ERR_MS / 1000.0)
    # The bend it snaps to: the open branch's equilibrium with the air at the opening volume, the bend
    # itself taking k_vol per rad (theta = R frac(p(theta)), decreasing in theta: bisection).
    v_at_open = p.v_rest_ml * p.p0_kpa / (p.p0_kpa + p.p_open_kpa)
    lo_b, hi_b = np.zeros(len(rng)), rng.copy()
    for _ in range(60):
        mid = 0.5 * (lo_b + hi_b)
        pk = p.p0_kpa * (p.v_rest_ml / (v_at_open + p.k_vol_ml * mid) - 1.0)
        above = rng * np.clip((pk - p.p_hold_kpa) / (p.p_full_kpa - p.p_hold_kpa), 0, 1) > mid
        lo_b, hi_b = np.where(above, mid, lo_b), np.where(above, hi_b, mid)
    snap_rad = 0.5 * (lo_b + hi_b)
    rest = np.zeros(len(rng)) if q_rest is None else np.asarray(q_rest, float)
    return PumpTiming(np.full(len(rng), band), rate_in, rate_de, settle_in, settle_de, snap_rad, rest, opening)


def durations(q: Any, timing: PumpTiming) -> tuple[np.ndarray, np.ndarray]:
    """(move_s, hold_s), each (m,), for waypoints q (m, n) reached one after the other, the first from
    timing.rest (PumpTiming's model)."""
    Q = np.asarray(q, dtype=float)
    n = Q.shape[1]
    closed = np.ones(n, dtype=bool)
    a = timing.rest.copy()
    move = np.zeros(len(Q))
    hold = np.zeros(len(Q))
    for i, b in enumerate(Q):
        ramp, ready = np.zeros(n), np.zeros(n)
        for j in range(n):
            d = float(b[j] - a[j])
            if d < 0:
                ramp[j] = -d / timing.rate_de[j]
                ready[j] = ramp[j] + timing.settle_de_s[j]
            elif d > 0 and not closed[j]:
                ramp[j] = d / timing.rate_in[j]
                ready[j] = ramp[j] + timing.settle_in_s[j]
            elif d > 0:
                t_open, rate = timing.opening.time(d, float(timing.rate_in[j]), float(timing.band[j]))
                ramp[j] = d / rate
                if math.isfinite(t_open):
                    ready[j] = max(ramp[j], t_open) + max(timing.settle_in_s[j], timing.settle_de_s[j])
                    closed[j] = False
                else:
                    ready[j] = ramp[j]                  # inside the band: the joint is already there
            if b[j] <= timing.rest[j] + 1e-9:
                closed[j] = True
        move[i] = max(MOVE_MIN_S, float(ramp.max()))
        hold[i] = max(0.0, float(ready.max()) - move[i])
        a = b
    return move, hold


def board_timing(robot: Any, fw: str = "arduino_pump", params: Any = None) -> PumpTiming:
    """The PumpTiming of `robot` on the pump board `fw`: its firmware constants read from its config
    header (the same values the board runs with), the rig's numbers from boards/pump_rig.py
    PumpParams (ours: the paper gives none; docs/emulator.md), the rest pose straight (q_min: the
    board at power on, every syringe retracted)."""
    from armbridge import boards
    from armbridge.boards.pump_rig import PumpParams

    cfg = boards.config(fw)
    return pump_timing(params or PumpParams(), cfg, robot.q_max, robot.v_max, q_rest=robot.q_min)
