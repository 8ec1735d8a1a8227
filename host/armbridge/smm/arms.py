"""The arms whose self-motion manifolds armbridge computes, by name.

Every arm has exactly one degree of redundancy (n = m + 1), so its SMMs are
1-D loops (section III-B). All are DHChain objects (armbridge.robots.dh),
which carry the SmmArm API: name, n, m, reach, fk, task, task_error,
jacobian, canonical, uncanonical, fk_error.

- planar3r: the paper's equal-link planar 3R positioning arm (Fig. 4, 12).
  Links of 1 m each (L = 3 m); the paper does not state the length. With
  links l, the 2R sub-chain of links 1-2 must reach d(psi) = |x - l e(psi)|
  for the last link's direction psi, which spans [|r - l|, r + l]. For
  r < l it never reaches 0 or 2l, so elbow-up and elbow-down stay apart: 2
  branches. For l < r < 3l it reaches 2l, where the elbows join: 1 branch.
  Singular radii are r = l and r = 3l (links collinear). The Fig. 4 example
  [0.30, 0.00] shows two branches, so l > 0.3; with l = 1 it lies well
  inside (d in [0.7, 1.3]), far from both singular radii, as an
  illustrative example would. Unit links also match the metre scale of the
  Table I/II arms.
- spatial4r: the optimally fault-tolerant 4R positioning arm, Table I.
- spatial7r: the optimally fault-tolerant 7R positioning and orienting arm,
  Table II. Its joint 7 has a_7 = 0 and alpha_7 = 0, so it turns the tool
  about its own z axis without moving the tip: the SMM at (p, R Rz(psi)) is
  the SMM at (p, R) with theta_7 += psi (a second symmetry, checked in the
  tests). canonical() reduces both (`DHChain.tool_roll`): c has 4 numbers,
  rho, z and the tool axis's polar and azimuth angles.
- arm3r: the bridge's planar arm (armbridge.robots.catalog.ARM3R) as a DH
  chain; its joint limits are ignored by SMMs.
"""
from __future__ import annotations

import math

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.robots.catalog import ARM3R
from armbridge.robots.dh import DHChain

SmmArm = DHChain

_PI2 = math.pi / 2

PLANAR3R = DHChain(
    name="planar3r", a=np.ones(3), alpha=np.zeros(3), d=np.zeros(3), theta=np.zeros(3), space="xy"
)

# Table I.
SPATIAL4R = DHChain(
    name="spatial4r",
    a=np.array([1.4142, 1.4142, 1.4142, 1.2247]),
    alpha=np.array([_PI2, -_PI2, _PI2, 0.0]),
    d=np.array([0.0, 1.0, -1.0, 0.5]),
    theta=np.zeros(4),
    space="xyz",
)

# Table II.
SPATIAL7R = DHChain(
    name="spatial7r",
    a=np.array([0.17, 1.42, 1.42, 0.56, 1.32, 1.27, 0.0]),
    alpha=np.array([-1.7104, -1.9897, -1.1519, 0.8726, -1.6057, -1.6150, 0.0]),
    d=np.array([0.0, 1.67, -0.69, -1.77, 2.42, -0.38, 0.95]),
    theta=np.zeros(7),
    space="pose",
)

ARMS: dict[str, DHChain] = {a.name: a for a in (PLANAR3R, SPATIAL4R, SPATIAL7R, DHChain.from_planar(ARM3R))}


def get_smm_arm(name: str) -> DHChain:
    """The SMM arm called name (case-insensitive)."""
    arm = ARMS.get(name.lower()) if isinstance(name, str) else None
    if arm is None:
        raise ArmbridgeError(f"unknown SMM robot {name!r}; known: {', '.join(sorted(ARMS))}")
    return arm
