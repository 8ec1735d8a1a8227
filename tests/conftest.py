"""Fixtures every test module may use (pytest finds them here by name)."""
from plan_runs import ports  # noqa: F401  (the fixture that keeps the ports run_plan opens)
