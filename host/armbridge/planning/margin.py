"""The clearance a plan keeps, from how the arm executes: shared by every planar serial chain (issue 24 section 2).

A controller leaves each joint within some error e of where the plan put it
(the pump board's re-seek band, the MASR's angle tolerance plus its worm's
half play). How far that can move the arm follows from the motion bound of
planning/soft/space.py: joint i sits at p_i and turns every link k >= i, so a
joint error delta with |delta_i| <= e moves a point x of link k by at most

    sum_{i<=k} |delta_i| |x - p_i|  <=  e sum_{i<=k} R_ik,    R_ik = L_i + ... + L_k,

largest on the last link: e (reach_0 + ... + reach_{n-1}), reach_i =
L_i + ... + L_{n-1} (`chain_margin`). A plan that keeps this clearance from
every obstacle is one the arm, resting anywhere within its controller's
tolerance of a planned state, still follows without touching anything.
The robot-specific pieces (which tolerance, read from which firmware) are
planning/soft/margin.py and planning/masr/margin.py.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError

#: The largest margin a scene, an environment or --margin may ask for (m).
MARGIN_MAX_M = 0.05
#: Point motion between the states at which a path's clearance is measured (m): a tenth of the certified
#: checks' 2 mm probe spacing; the true least is within CLEARANCE_RES / 2 below the sampled one.
CLEARANCE_RES = 0.0002


def chain_margin(lengths: Any, joint_error: float) -> float:
    """The largest displacement of any point of a chain of link `lengths` (m; or a robot with link_lengths)
    when every joint is off by at most `joint_error` (rad): e * sum_i reach_i (module doc), m."""
    L = np.asarray(getattr(lengths, "link_lengths", lengths), dtype=float).ravel()
    if not (joint_error >= 0 and math.isfinite(joint_error)):
        raise ArmbridgeError(f"joint error must be a finite number >= 0 rad, got {joint_error}")
    return float(joint_error) * float(np.sum(np.cumsum(L[::-1])))


def check_margin(margin: float, where: str = "margin") -> float:
    """margin (m) if it is in [0, MARGIN_MAX_M], else one ArmbridgeError naming the range in mm."""
    m = float(margin)
    if not (math.isfinite(m) and 0.0 <= m <= MARGIN_MAX_M):
        raise ArmbridgeError(f"{where} {m * 1000:g} mm is outside [0, {MARGIN_MAX_M * 1000:g}] mm")
    return m
