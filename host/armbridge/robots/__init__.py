"""Robot models: kinematics, joint limits and the catalog of named robots."""
from armbridge.robots.catalog import ARM3R, MASR5, get_masr, get_robot
from armbridge.robots.masr import MasrArm
from armbridge.robots.planar import PlanarChain, wrap_angle

__all__ = ["ARM3R", "MASR5", "MasrArm", "PlanarChain", "get_masr", "get_robot", "wrap_angle"]
