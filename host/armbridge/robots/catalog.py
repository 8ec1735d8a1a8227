"""The named robots armbridge knows, and lookup by name.

ARM3R is the 3R planar servo arm that draws letters and shapes (Murai,
Vairagi, Semwal, "Optimal trajectory generation of various English alphabets
using deep learning model for 3-R manipulator"; ann-fabrik paper):

- Links 0.19, 0.12, 0.07 m: the lengths of its data-set section (the
  prototype paragraph says l1 = 18 cm once; the data the ANN learned from
  uses 19 cm).
- Joint limits are its eq. (1): phi1 in [0, pi], phi2 in [-pi, 0],
  phi3 in [-pi/2, pi/2]. Each is a 180-degree span, which is what a hobby
  servo (the arm uses three 35 kg serial servos) can turn, and the set keeps
  the elbow on one side. Section 5.2 quotes a different set
  ([-pi, pi], [-pi/2, pi/2], [-pi/4, pi/4]) as the range its CBF verified
  for predicted angles; that is a reported outcome, not the mechanism's
  range, so it is not used here. The first-quadrant constraints of eq. (2)
  restrict the drawing workspace, not the joints, and belong to planning.
- v_max 3.0 rad/s per joint is our choice, not the paper's: below the ~5 rad/s
  no-load speed of a 35 kg hobby servo, so the servo can hold it under load.

MASR5 is the experimental 5R Minimally Actuated Serial Robot of the masr paper
(Cohen, Sintov, Zarrouk, "Motion planning for a minimally actuated serial
robot", section V-A):

- Links 0.2, 0.2, 0.2, 0.1, 0.1 m (l = 0.8 m); every joint in [-50, 50] deg.
- MA speed 100 mm/s and joint rate 0.28 rad/s, both held by the MA's PIDs.
- link_width 0.03 m is our choice: the paper inflates obstacles by 0.5 w
  (Fig. 3a) but never gives w. 30 mm is a plausible 3D-printed link with an
  MA track; change it when the real arm is measured.
"""
from __future__ import annotations

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.robots.masr import MasrArm
from armbridge.robots.planar import PlanarChain

ARM3R = PlanarChain(
    name="arm3r",
    link_lengths=np.array([0.19, 0.12, 0.07]),
    q_min=np.array([0.0, -np.pi, -np.pi / 2]),
    q_max=np.array([np.pi, 0.0, np.pi / 2]),
    v_max=np.array([3.0, 3.0, 3.0]),
    joint_names=("shoulder", "elbow", "wrist"),
)

ROBOTS: dict[str, PlanarChain] = {r.name: r for r in (ARM3R,)}


def get_robot(name: str) -> PlanarChain:
    """The catalog robot called name (case-insensitive)."""
    robot = ROBOTS.get(name.lower())
    if robot is None:
        raise ArmbridgeError(f"unknown robot {name!r}; known robots: {', '.join(sorted(ROBOTS))}")
    return robot


MASR5 = MasrArm(
    name="masr5",
    link_lengths=np.array([0.2, 0.2, 0.2, 0.1, 0.1]),
    theta_b=np.full(5, np.deg2rad(50.0)),
    ma_speed=0.1,
    joint_speed=0.28,
    link_width=0.03,
)

MASRS: dict[str, MasrArm] = {r.name: r for r in (MASR5,)}


def get_masr(name: str) -> MasrArm:
    """The catalog MASR called name (case-insensitive)."""
    arm = MASRS.get(name.lower())
    if arm is None:
        raise ArmbridgeError(f"unknown MASR {name!r}; known MASRs: {', '.join(sorted(MASRS))}")
    return arm
