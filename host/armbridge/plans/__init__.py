"""Plan files: the versioned JSON format (`format.py`) and plan builders."""
from armbridge.plans.format import Plan, load_plan, loads_plan, make_plan, save_plan, validate

__all__ = ["Plan", "load_plan", "loads_plan", "make_plan", "save_plan", "validate"]
