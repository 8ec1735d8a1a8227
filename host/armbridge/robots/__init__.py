"""Robot models: kinematics, joint limits and the catalog of named robots."""
from armbridge.robots.catalog import ARM3R, get_robot
from armbridge.robots.planar import PlanarChain, wrap_angle

__all__ = ["ARM3R", "PlanarChain", "get_robot", "wrap_angle"]
