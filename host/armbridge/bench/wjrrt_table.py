"""`armbridge bench wjrrt`'s tables on the console: Table 1's rows, the generated groups, success against the
budget, and issue 24 section 3's WJRRT-Connect against RRTConnect (bench.wjrrt.versus)."""
from __future__ import annotations

from typing import Any

from armbridge.bench.wjrrt import LABELS, _generated


def _cell(v: Any, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def table_rows(result: dict[str, Any]) -> list[tuple[str, ...]]:
    """Table 1's rows (scene, planner, then COLUMNS as text), paper rows beside ours; generated scenes
    are in group_rows instead."""
    rows: list[tuple[str, ...]] = []
    skip = _generated(result)
    for name, sc in result["scenes"].items():
        if name in skip:
            continue
        for pl, d in sc["planners"].items():
            s = d["summary"]
            it = f"{s['iterations_budget']} ({s['iterations_median']:.0f})" if s["iterations_budget"] else \
                f"- ({s['iterations_median']:.0f})"
            rows.append((name, LABELS[pl], f"{s['success']}/{s['runs']}", it, _cell(s["time_median_s"], ".3g"),
                         _cell(s["nodes"], ".0f"), _cell(s["track_nodes"], ".0f"), _cell(s["goal_nodes"], ".0f"),
                         _cell(s["random_nodes"], ".0f"), _cell(s["obstacle_checks"], ".0f"),
                         _cell(s["final_H"], ".3g")))
    return rows


def group_rows(result: dict[str, Any]) -> list[tuple[str, ...]]:
    """Per group of generated scenes and planner: scenes, success over all its runs, the median time of
    the successful runs, time to success median / p90 (s)."""
    rows: list[tuple[str, ...]] = []
    for spec, g in result.get("groups", {}).items():
        for pl, d in g["planners"].items():
            s = d["summary"]
            rows.append((spec, LABELS[pl], str(len(g["scenes"])), f"{s['success']}/{s['runs']}",
                         f"{100 * s['success_rate']:.0f}", _cell(s["time_median_s"], ".3g"),
                         f"{_cell(s['time_to_success_median_s'], '.3g')} / {_cell(s['time_to_success_p90_s'], '.3g')}"))
    return rows


def print_result(result: dict[str, Any], console: Any) -> None:
    from rich.table import Table

    T = result["size"]["time_limit"]
    t = Table(title=f"armbridge bench wjrrt: Table 1 columns, {result['size']['seeds']} seeds per scene, "
                    f"budget {T:g} s per run (counts: means over successful runs)")
    for col in ("scene", "planner", "success", "iter. budget (median)", "time (s, median)", "nodes", "track",
                "goal", "random", "obstacle checks", "H"):
        t.add_column(col, justify="left" if col in ("scene", "planner") else "right")
    for row in table_rows(result):
        t.add_row(*row)
    if t.row_count:
        console.print(t)
    if result.get("groups"):
        g = Table(title=f"generated scenes ({result['size']['seeds']} seeds per scene, budget {T:g} s per run): "
                        "over all runs of a group")
        for col in ("scenes", "planner", "n", "success", "%", "time (s, median)", "time to success median / p90"):
            g.add_column(col, justify="left" if col in ("scenes", "planner") else "right")
        for row in group_rows(result):
            g.add_row(*row)
        console.print(g)
    e = Table(title="equal time: success (%) at a budget of t s, time to success median / p90 (s)")
    e.add_column("scene")
    e.add_column("planner")
    shown = [b for b in result["budgets_s"] if b >= 0.05 or b == result["budgets_s"][-1]]
    for b in shown:
        e.add_column(f"{b:g}", justify="right")
    e.add_column("median / p90", justify="right")
    skip = _generated(result)
    for name, sc in [*[(n, sc) for n, sc in result["scenes"].items() if n not in skip],
                     *result.get("groups", {}).items()]:
        for pl, d in sc["planners"].items():
            s = d["summary"]
            e.add_row(name, LABELS[pl], *[f"{100 * s['success_at'][f'{b:g}']:.0f}" for b in shown],
                      f"{_cell(s['time_to_success_median_s'], '.3g')} / {_cell(s['time_to_success_p90_s'], '.3g')}")
    console.print(e)
    for pl, why in result["not_run"].items():
        console.print(f"not run: {LABELS[pl]}: {why}")
    console.print("targets: " + "; ".join(f"{k} {'met' if v else 'MISSED'}" for k, v in result["targets"].items()
                                          if isinstance(v, bool)))
    v = result.get("versus") or {}
    if v:
        vt = Table(title=f"issue 24 section 3: {LABELS[v['ours']]} against {LABELS[v['peer']]}, success (%) at "
                         "every budget from 0.05 s, median time to success over all runs (s)")
        vt.add_column("scenes")
        vt.add_column("planner")
        for b in v["budgets_s"]:
            vt.add_column(f"{b:g}", justify="right")
        vt.add_column("median", justify="right")
        vt.add_column("met", justify="right")
        for key, part in v["parts"].items():
            for pl in (v["ours"], v["peer"]):
                met = "yes" if part["success_met"] and part["median_met"] else "NO"
                vt.add_row(key, LABELS[pl], *[f"{100 * x:.0f}" for x in part["success_at"][pl]],
                           _cell(part["time_to_success_median_s"][pl], ".3g"), met if pl == v["ours"] else "")
        console.print(vt)
        thin = v["clearance_below_margin"]
        console.print(f"clearance: {'every successful path kept its margin' if not thin else 'BELOW the margin: '}"
                      + ", ".join(thin[:10]))
