"""Fixtures every test module may use (pytest finds them here by name)."""
from bench_runs import bench_arm3r_quick  # noqa: F401  (one `bench arm3r --quick` run for two modules)
from plan_runs import ports  # noqa: F401  (the fixture that keeps the ports run_plan opens)
