"""Inverse kinematics: joint angles for end-effector poses."""
from armbridge.ik.analytic3r import ik, solve_path

__all__ = ["ik", "solve_path"]
