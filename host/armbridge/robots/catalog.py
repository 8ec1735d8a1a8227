"""The one registry of named robots: `get_robot(name)`, `names()`, `register(robot)`.

Robots are data: every entry is a JSON description with a `kind` (the model
class: "planar" PlanarChain, "masr" MasrArm, "dh" DHChain), built on first
use, so listing the names imports nothing heavy (a DH chain needs torch only
when one is asked for). `robot_from_dict` builds an inline description the
same way (a plan file's robot object, a planning environment's robot).

The entries:

ARM3R (planar) is the 3R planar servo arm that draws letters and shapes
(Murai, Vairagi, Semwal, "Optimal trajectory generation of various English
alphabets using deep learning model for 3-R manipulator"; ann-fabrik paper):

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

MASR5 (masr) is the experimental 5R Minimally Actuated Serial Robot of the
masr paper (Cohen, Sintov, Zarrouk, "Motion planning for a minimally actuated
serial robot", section V-A):

- Links 0.2, 0.2, 0.2, 0.1, 0.1 m (l = 0.8 m); every joint in [-50, 50] deg.
- MA speed 100 mm/s and joint rate 0.28 rad/s, both held by the MA's PIDs.
- link_width 0.03 m is our choice: the paper inflates obstacles by 0.5 w
  (Fig. 3a) but never gives w. 30 mm is a plausible 3D-printed link with an
  MA track; change it when the real arm is measured.

SOFT3 (planar) is the three-joint soft arm of the WJRRT paper (Khan, Li,
Kadry, Nam, section V-B/C): polypropylene links bent at polychloroprene joints
inflated by 100 mL syringes on the syringe-pump board (firmware/arduino_pump):

- Joint ranges 0-30, 0-55 and 0-60 deg (section V-C): a joint only bends one
  way, from straight (deflated) to its largest bend (inflated).
- Links 0.10 m each and v_max 0.5 rad/s are our choices: the paper gives
  neither; 0.5 rad/s is about what a 12 V linear motor on a 100 mL syringe
  inflates a joint at (docs/emulator.md, the pneumatic plant).

SOFT2 (planar) is the paper's two-arm soft prototype (section V-C-1): joint
ranges 0-30 deg (base) and 0-55 deg (end joint), as measured there; links
0.10 m and v_max 0.5 rad/s are our choices, as for SOFT3.

SOFT7 (planar) is the seven-arm redundant manipulator of section IV-C, which
plans "in a narrow tube without colliding the walls". The paper gives no
dimensions or ranges for it; everything here is our choice: links 0.06 m
(reach 0.42 m, near SOFT3's 0.30 m), every joint in [-40, 40] deg
(symmetric: a snake in a tube must bend both ways; 40 deg is inside the
largest bend the prototype's joints reached, 40-60 deg), v_max 0.5 rad/s.

The SMM arms (dh) of Clark and Xie's self-motion-manifold paper; each has one
degree of redundancy (n = m + 1), so its SMMs are 1-D loops (section III-B).
Their joints have no stops (the DHChain defaults); SMMs ignore limits anyway.

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
  about its own z axis without moving the tip (`DHChain.tool_roll`).
"""
from __future__ import annotations

import importlib
import math
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.robots.base import Robot
from armbridge.robots.masr import MasrArm
from armbridge.robots.planar import PlanarChain

#: kind -> (module, class) of the model; imported when a robot of that kind is built.
KINDS: dict[str, tuple[str, str]] = {
    "planar": ("armbridge.robots.planar", "PlanarChain"),
    "masr": ("armbridge.robots.masr", "MasrArm"),
    "dh": ("armbridge.robots.dh", "DHChain"),
}
#: kind -> the optional dependency it needs and the extra that installs it.
_NEEDS = {"dh": ("torch", "armbridge[train]")}

_PI2 = math.pi / 2

ARM3R = PlanarChain(
    name="arm3r",
    link_lengths=np.array([0.19, 0.12, 0.07]),
    q_min=np.array([0.0, -np.pi, -np.pi / 2]),
    q_max=np.array([np.pi, 0.0, np.pi / 2]),
    v_max=np.array([3.0, 3.0, 3.0]),
    joint_names=("shoulder", "elbow", "wrist"),
)

MASR5 = MasrArm(
    name="masr5",
    link_lengths=np.array([0.2, 0.2, 0.2, 0.1, 0.1]),
    theta_b=np.full(5, np.deg2rad(50.0)),
    ma_speed=0.1,
    joint_speed=0.28,
    link_width=0.03,
)

SOFT3 = PlanarChain(
    name="soft3",
    link_lengths=np.array([0.10, 0.10, 0.10]),
    q_min=np.zeros(3),
    q_max=np.deg2rad([30.0, 55.0, 60.0]),
    v_max=np.full(3, 0.5),
    joint_names=("joint1", "joint2", "joint3"),
)

SOFT2 = PlanarChain(
    name="soft2",
    link_lengths=np.array([0.10, 0.10]),
    q_min=np.zeros(2),
    q_max=np.deg2rad([30.0, 55.0]),
    v_max=np.full(2, 0.5),
    joint_names=("joint1", "joint2"),
)

SOFT7 = PlanarChain(
    name="soft7",
    link_lengths=np.full(7, 0.06),
    q_min=np.full(7, -np.deg2rad(40.0)),
    q_max=np.full(7, np.deg2rad(40.0)),
    v_max=np.full(7, 0.5),
    joint_names=tuple(f"joint{i + 1}" for i in range(7)),
)

# name -> description (with its kind); built robots are kept in _BUILT.
_DATA: dict[str, dict[str, Any]] = {
    "planar3r": {"kind": "dh", "name": "planar3r", "a": [1.0, 1.0, 1.0], "alpha": [0.0] * 3, "d": [0.0] * 3,
                 "theta": [0.0] * 3, "space": "xy"},
    # Table I.
    "spatial4r": {"kind": "dh", "name": "spatial4r", "a": [1.4142, 1.4142, 1.4142, 1.2247],
                  "alpha": [_PI2, -_PI2, _PI2, 0.0], "d": [0.0, 1.0, -1.0, 0.5], "theta": [0.0] * 4, "space": "xyz"},
    # Table II.
    "spatial7r": {"kind": "dh", "name": "spatial7r", "a": [0.17, 1.42, 1.42, 0.56, 1.32, 1.27, 0.0],
                  "alpha": [-1.7104, -1.9897, -1.1519, 0.8726, -1.6057, -1.6150, 0.0],
                  "d": [0.0, 1.67, -0.69, -1.77, 2.42, -0.38, 0.95], "theta": [0.0] * 7, "space": "pose"},
}
_BUILT: dict[str, Any] = {}


def register(robot: Robot) -> Robot:
    """Add a robot to the registry (a board or demo of a new robot calls this once); returns it.
    A second robot under a taken name is an ArmbridgeError."""
    key = robot.name.lower()
    if key in _DATA or key in _BUILT:
        if _BUILT.get(key) == robot:
            return robot
        raise ArmbridgeError(f"robot {robot.name!r} is already registered")
    _BUILT[key] = robot
    return robot


for _r in (ARM3R, MASR5, SOFT2, SOFT3, SOFT7):
    register(_r)


def names() -> list[str]:
    """The registered robot names, sorted."""
    return sorted({*_DATA, *_BUILT})


def get_robot(name: str) -> Any:
    """The registered robot called name (case-insensitive)."""
    key = name.lower() if isinstance(name, str) else None
    if key not in _BUILT:
        if key not in _DATA:
            raise ArmbridgeError(f"unknown robot {name!r}; known robots: {', '.join(names())}")
        _BUILT[key] = robot_from_dict(_DATA[key])
    return _BUILT[key]


def is_registered(robot: Any) -> bool:
    """True when robot is the registry's robot of its name (so a file may name it instead of describing it)."""
    try:
        return bool(get_robot(robot.name) == robot)
    except ArmbridgeError:
        return False


def robot_class(kind: Any) -> Any:
    """The model class of a kind; a missing optional dependency is one line naming its extra."""
    if kind not in KINDS:
        raise ArmbridgeError(f"unknown robot kind {kind!r}; known kinds: {', '.join(KINDS)}")
    module, cls = KINDS[kind]
    try:
        return getattr(importlib.import_module(module), cls)
    except ModuleNotFoundError as exc:
        dep, extra = _NEEDS.get(kind, (exc.name, "it"))
        raise ArmbridgeError(f"robots of kind {kind!r} need {dep}, which is not installed: "
                             f"pip install '{extra}'") from None


def robot_from_dict(d: Any, default_kind: str = "planar") -> Any:
    """A robot from its JSON description: `kind` (default_kind when absent) and the
    class's own keys (its to_dict()). The class checks every value."""
    if not isinstance(d, dict):
        raise ArmbridgeError(f"a robot description must be a JSON object, got {type(d).__name__}")
    body = {k: v for k, v in d.items() if k != "kind"}
    return robot_class(d.get("kind", default_kind)).from_dict(body)


def robot_to_dict(robot: Robot) -> dict[str, Any]:
    """The JSON description of a robot with its kind: robot_from_dict(robot_to_dict(r)) == r."""
    return {"kind": robot.kind, **robot.to_dict()}


def get_masr(name: str) -> MasrArm:
    """The registered MASR called name (case-insensitive)."""
    masrs = [n for n in names() if isinstance(_BUILT.get(n), MasrArm) or _DATA.get(n, {}).get("kind") == "masr"]
    key = name.lower() if isinstance(name, str) else None
    if key not in masrs:
        what = "is not a MASR" if key in names() else "is unknown"
        raise ArmbridgeError(f"unknown MASR {name!r} (the robot {what}); known MASRs: {', '.join(masrs)}")
    return get_robot(key)
