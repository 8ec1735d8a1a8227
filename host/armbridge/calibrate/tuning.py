"""Relay experiment -> PID gains (the host's half of RELAY; firmware/common/relay.py).

The relay's describing function with hysteresis h gives the ultimate gain
Ku = 4 d / (pi sqrt(a^2 - h^2)) from the relay amplitude d and the limit cycle's
half peak-to-peak a (Astrom & Hagglund 1984, eq. 3); Tu is its period. The
rules below turn (Ku, Tu) into gains; Tyreus-Luyben's (kp = Ku/2.2,
Ti = 2.2 Tu, Td = Tu/6.3) is the default because it overshoots far less than
Ziegler-Nichols' classic rule, and a joint that overshoots leaves its plan.
"""
from __future__ import annotations

import math

RULES = {
    # name: (kp / Ku, Ti / Tu, Td / Tu); Ti 0 means no integral term
    "ziegler-nichols": (0.6, 0.5, 0.125),
    "tyreus-luyben": (1 / 2.2, 2.2, 1 / 6.3),
    "no-overshoot": (0.2, 0.5, 1 / 3),
    "pd": (0.45, 0.0, 0.1),
}


def ultimate(d: float, a: float, h: float = 0.0) -> float:
    """Ku from relay amplitude d (output units), limit-cycle half peak-to-peak a
    and hysteresis h (measurement units); ValueError when a <= h (no cycle seen)."""
    if not a > h >= 0:
        raise ValueError(f"the limit cycle's amplitude {a:g} is not above the relay's hysteresis {h:g}")
    return 4.0 * d / (math.pi * math.sqrt(a * a - h * h))


def pid_gains(ku: float, tu: float, rule: str = "tyreus-luyben") -> tuple[float, float, float]:
    """(kp, ki, kd) in the loop's units per second from Ku and Tu (s)."""
    c_kp, c_ti, c_td = RULES[rule]
    kp = c_kp * ku
    ki = kp / (c_ti * tu) if c_ti > 0 else 0.0
    kd = kp * c_td * tu
    return kp, ki, kd
