"""Fig. 5 and Fig. 7 of `armbridge bench masr-plan` (masr paper, section V-C) as matplotlib figures.

Both put iterations on a log axis with plain 1-2-5 ticks (1, 2, 5, 10, ...,
1000): the interesting part of a success curve is its first tens of
iterations, the costs settle over thousands. Every curve has its own marker
and line style, so curves lying on top of each other stay visible, and the
legend sits below the panels. Colours are Okabe-Ito (colour-blind safe):
MASR-RRT* in blues, the RRT* baseline in oranges, in both figures.

`fig5_figure(result["fig5"])` / `fig7_figure(result["fig7"])` return the
unsaved figure (tests read its lines); masr_plan.plots saves them.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from armbridge.planning.figure import OKABE_ITO

#: Per planner a colour family: (darker, lighter), the darker for the 15th-percentile curve of Fig. 7.
FAMILIES = {"masr": (OKABE_ITO["blue"], OKABE_ITO["sky"]),
            "rrt": (OKABE_ITO["vermillion"], OKABE_ITO["orange"])}
MARKERS = ("o", "s", "^", "D", "v", "P")
LINESTYLES = ("-", (0, (5, 2)), (0, (3, 1, 1, 1)), (0, (1, 1.2)))


def family(planner: str) -> str:
    """"masr" for the MASR-RRT* labels of masr_plan.label, "rrt" for the baseline."""
    return "masr" if planner.startswith("MASR") else "rrt"


def _planner_colors(planners: Sequence[str]) -> dict[str, str]:
    """One colour per planner: the baseline vermillion, MASR-RRT* blues light to dark in the order given."""
    masr = [p for p in planners if family(p) == "masr"]
    shades = (OKABE_ITO["sky"], OKABE_ITO["blue"], "#003F63") if len(masr) > 1 else (OKABE_ITO["blue"],)
    out = {p: shades[min(i, len(shades) - 1)] for i, p in enumerate(masr)}
    return {p: out.get(p, FAMILIES["rrt"][0]) for p in planners}


def log_iterations_axis(ax: Any, last: int, first: int = 1) -> None:
    """Log x from first to last iterations, ticks at 1-2-5 steps written plainly (1, 2, 5, 10, ..., no 10^k).

    Over more than three decades only 1-10-100 steps keep labels (2 and 5 stay as unlabelled ticks).
    """
    from matplotlib.ticker import FixedLocator, NullFormatter, StrMethodFormatter

    steps = [m * 10 ** e for e in range(7) for m in (1, 2, 5) if first <= m * 10 ** e <= last]
    major = steps if len(steps) <= 10 else [t for t in steps if str(t)[0] == "1"]
    ax.set_xscale("log")
    ax.set_xlim(first / 1.15 if first > 1 else 1, last * (1.15 if first > 1 else 1))
    ax.xaxis.set_major_locator(FixedLocator(major))
    ax.xaxis.set_major_formatter(StrMethodFormatter("{x:.0f}"))
    ax.xaxis.set_minor_locator(FixedLocator([t for t in steps if t not in major]))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.tick_params(axis="x", labelsize=8)
    ax.grid(True, which="major", lw=0.3, color="0.85")


def _marks(its: int, k: int) -> np.ndarray:
    """Marker indices on a curve over 1..its: about 4 per decade, shifted per curve k so markers do not stack."""
    pts = np.unique(np.round(np.logspace(0, np.log10(its), 4 * max(1, int(np.log10(its))) + 1)
                             * 10 ** (0.06 * k)).astype(int))
    return pts[(pts >= 1) & (pts <= its)] - 1


def _new(ncols: int, width: float) -> tuple[Any, Any]:
    from armbridge.planning.figure import pyplot

    plt = pyplot()
    fig, axes = plt.subplots(1, ncols, figsize=(width, 4.2), layout="constrained", squeeze=False)
    return fig, axes[0]


def _legend(fig: Any, ax: Any, ncol: int) -> None:
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=ncol, fontsize=8, frameon=False)


def fig5_figure(f5: dict[str, Any]) -> Any:
    """Fig. 5: success rate (left) and mean cost over the commonly solved environments (right) vs iterations."""
    fig, (a, b) = _new(2, 10.0)
    planners = list(f5["curves"])
    colors = _planner_colors(planners)
    its = int(f5["iterations"])
    x = np.arange(1, its + 1)
    ks = [r["iterations"] for r in f5["rows"]]
    for k, pl in enumerate(planners):
        style = {"color": colors[pl], "marker": MARKERS[k % len(MARKERS)], "ls": LINESTYLES[k % len(LINESTYLES)],
                 "mfc": "white", "mew": 1.3, "ms": 5, "lw": 1.5, "label": pl, "gid": pl}
        a.plot(x, np.asarray(f5["curves"][pl]["success_rate"], float) * 100, markevery=list(_marks(its, k)),
               drawstyle="steps-post", **style)
        ys = [r[pl]["mean_cost_common_s"] for r in f5["rows"]]
        b.plot(ks, [np.nan if y is None else y for y in ys], **style)
    log_iterations_axis(a, its)
    log_iterations_axis(b, its, first=min(ks) if ks else 1)
    for ax in (a, b):
        ax.set_xlabel("iterations N_c")
    a.set_ylim(-3, 103)
    a.set_ylabel("success rate (%)")
    a.set_title(f"{f5['environments']} random environments", fontsize=10)
    n_common = f5["rows"][-1]["common_solved"] if f5["rows"] else 0
    b.set_ylabel("mean cost tau (s), environments all solved")
    b.set_title(f"eq. (7) cost; {n_common} of {f5['environments']} solved by all at N_c = {its}", fontsize=10)
    _legend(fig, a, len(planners))
    return fig


def fig7_figure(f7: dict[str, Any], levels: Sequence[float] = (0.15, 0.25)) -> Any:
    """Fig. 7: per environment (one panel each) the share of trials below the 15th / 25th percentile cost.

    Planner -> colour family (MASR-RRT* blues, RRT* oranges); level -> shade and line
    style (15th darker and solid, 25th lighter and dashed); every curve its own marker.
    """
    envs = list(f7["environments"])
    fig, axes = _new(len(envs), 3.6 * len(envs) + 0.6)
    its = int(f7["iterations"])
    x = np.arange(1, its + 1)
    for ax, name in zip(axes, envs):
        curves = f7["environments"][name]["curves"]
        k = 0
        for pl in sorted(curves, key=family):
            fam = FAMILIES[family(pl)]
            for j, lv in enumerate(levels):
                y = np.asarray(curves[pl][f"below_p{int(lv * 100)}"], float) * 100
                ax.plot(x, y, color=fam[j], ls="-" if j == 0 else (0, (5, 2)), lw=1.6 if j == 0 else 1.4,
                        marker=MARKERS[k % len(MARKERS)], ms=5, mfc="white", mew=1.3,
                        markevery=list(_marks(its, k)), drawstyle="steps-post",
                        label=f"{pl}, below the {int(lv * 100)}th percentile", gid=f"{pl}|{lv}")
                k += 1
        log_iterations_axis(ax, its)
        ax.set_ylim(-3, 103)
        ax.set_xlabel("iterations N_c")
        ax.set_title(name, fontsize=10)
    axes[0].set_ylabel("trials below the percentile (%)")
    fig.suptitle(f"{f7['trials']} trials per planner and environment; percentiles of the normalised cost range",
                 fontsize=10)
    _legend(fig, axes[0], 2)
    return fig
