"""Robot models behind one interface (base.Robot) and one registry of named robots (catalog)."""
from armbridge.geometry import wrap_angle
from armbridge.robots.base import Robot
from armbridge.robots.catalog import (
    ARM3R,
    MASR5,
    SOFT2,
    SOFT3,
    SOFT7,
    get_masr,
    get_robot,
    is_registered,
    names,
    register,
    robot_from_dict,
    robot_to_dict,
)
from armbridge.robots.masr import MasrArm
from armbridge.robots.planar import PlanarChain

__all__ = ["ARM3R", "MASR5", "SOFT2", "SOFT3", "SOFT7", "MasrArm", "PlanarChain", "Robot", "get_masr", "get_robot",
           "is_registered", "names", "register", "robot_from_dict", "robot_to_dict", "wrap_angle"]
