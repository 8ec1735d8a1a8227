"""`armbridge bench masr-plan --parts margin`: what a clearance margin costs MASR-RRT* on E1-E3.

Per environment and margin (0, the paper's check; fractions and multiples of
the MA's execution bound, planning/masr/margin.py), `runs` runs of MASR-RRT*
(p_c 0.6, the shipped IK-NN as goal IK, 1,000 iterations, seeds 0..runs-1)
with Environment.planning_checker(margin): success, the median eq. (7) cost
of the successful runs and the least clearance of their paths along the
motion convention (path_clearance), which is at least the margin.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

#: Margins as multiples of the execution bound.
FACTORS = (0.0, 0.4, 1.0, 1.6)
ITERATIONS = 1000


def margins(runs: int, goal_ik: Callable, progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    from armbridge.planning.masr import rrt_star
    from armbridge.planning.masr.environment import FIXED, fixed_environment
    from armbridge.planning.masr.margin import execution_margin, path_clearance

    envs = {name: fixed_environment(name) for name in FIXED}
    bound = execution_margin(envs[FIXED[0]].arm)  # E1-E3 share their arm
    out: dict[str, Any] = {"iterations": ITERATIONS, "runs": runs, "p_c": 0.6, "environments": {},
                           "execution_bound_mm": bound * 1000.0}
    for name, env in envs.items():
        rows = []
        for f in FACTORS:
            chk = env.planning_checker(margin=f * bound)
            res = [rrt_star.plan(env, iterations=ITERATIONS, seed=s, goal_ik=goal_ik, checker=chk) for s in range(runs)]
            ok = [r for r in res if r.path is not None]
            clear = [path_clearance(env, r.path) * 1000.0 for r in ok]
            rows.append({"margin_mm": f * bound * 1000.0, "factor": f, "success": len(ok),
                         "median_cost_s": float(np.median([r.cost for r in ok])) if ok else None,
                         "median_clearance_mm": float(np.median(clear)) if clear else None,
                         "least_clearance_mm": float(min(clear)) if clear else None})
        out["environments"][name] = rows
        progress(f"margin: {name} done")
    return out


def table(result: dict[str, Any]) -> Any:
    from rich.table import Table

    m = result["margin"]
    t = Table(title=f"clearance margin: MASR-RRT* (p_c {m['p_c']}, {m['iterations']} iterations, {m['runs']} "
                    f"seeds) on E1-E3; the MA's execution bound is {m['execution_bound_mm']:.2f} mm")
    for col in ("env", "margin (mm)", "success", "median cost (s)", "clearance median / least (mm)"):
        t.add_column(col, justify="left" if col == "env" else "right")
    for env, rows in m["environments"].items():
        for r in rows:
            c = "-" if r["median_clearance_mm"] is None else \
                f"{r['median_clearance_mm']:.2f} / {r['least_clearance_mm']:.2f}"
            t.add_row(env, f"{r['margin_mm']:.2f}", f"{r['success']}/{m['runs']}",
                      "-" if r["median_cost_s"] is None else f"{r['median_cost_s']:.1f}", c)
    return t
