"""`armbridge bench arm3r`'s Lyapunov section: the paper's Fig. 13 ("Lyapunov function with
CBF", section 5.2) on its twelve samples.

Each sample is drawn as the arm draws it: from the closed-form IK at its first
waypoint, the ANN + FABRIK answer of every waypoint in turn is the CBF-QP's
reference for `HOLD` filter steps (the bench's CbfConfig), all samples batched as
rows. V = 1/2 |q - q_ref|_H^2 along that run is checked to decrease at every step
(`ik.lyapunov.check`: V after each step against the reference it tracked is at most
V before it) and plotted per sample against time: it falls between target updates
and jumps at each one (red: the value right after the update, the "updated values"
of Fig. 13); steps where the filter changed the nominal input (the constraint is
active) are marked orange.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from armbridge.ik.cbf import CbfConfig
from armbridge.ik.lyapunov import LyapunovTrace, check, held_path, simulate
from armbridge.ik.region import SafeRegion
from armbridge.robots.planar import PlanarChain

HOLD = 10  # filter steps per waypoint: 0.1 s at dt 10 ms; K dt 0.2 leaves 1 % of V at the next update
V_FLOOR = 1e-14  # rad^2: where the log axis stops (V reaches rounding noise once converged)


def section(chain: PlanarChain, region: SafeRegion, cfg: CbfConfig, names: list[str], starts: list[np.ndarray],
            targets: list[np.ndarray], png: Path | None = None) -> dict[str, Any]:
    """The report's "lyapunov" key (and Fig. 13 at png): starts (n,) and targets (P, n) per sample."""
    tr = simulate(chain, region, np.stack(starts), held_path(targets, HOLD), cfg)
    out: dict[str, Any] = {"V": "1/2 (q - q_ref)^T H (q - q_ref), rad^2 (ik/lyapunov.py)", "hold_steps": HOLD,
                           "samples": names, **check(tr)}
    out["decreasing"] = out["violations"] == 0 and out["dvdt_violations"] == 0
    if png is not None:
        out["png"] = str(fig13_png(tr, names, [len(t) for t in targets], png))
    return out


def _holds(tr: LyapunovTrace, lengths: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """V over each waypoint's hold, as a fraction of V at its update: (holds, HOLD + 1), and
    whether the constraint was active in that hold (holds,)."""
    ratio, active = [], []
    for b, n in enumerate(lengths):
        k0 = np.arange(n) * HOLD
        v0 = tr.before[k0, b]
        ok = v0 > V_FLOOR
        after = tr.after[k0[:, None] + np.arange(HOLD), b]
        ratio.append(np.c_[np.ones(n), after / np.where(ok, v0, 1)[:, None]][ok])
        active.append(tr.constrained[k0[:, None] + np.arange(HOLD), b].any(axis=1)[ok])
    return np.concatenate(ratio), np.concatenate(active)


def fig13_png(tr: LyapunovTrace, names: list[str], lengths: list[int], out: Path | str, dpi: int = 200,
              window_s: float = 3.0) -> Path:
    """Fig. 13 at the size a paper prints (7.2 in wide, 8 pt type): one panel per row of tr, V
    over its first window_s on a log axis (blue: after each step; red: right after each target
    update; orange rings: the constraint active), the panels sharing their axes; below them,
    one wide panel with every hold of every sample as a fraction of V at its update, beside
    the unconstrained decay (1 - K dt)^(2k); the legend above the panels, outside the data."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    out = Path(out)
    cols = min(4, max(1, len(names)))
    rows = -(-len(names) // cols)
    with plt.rc_context({"font.size": 8, "axes.titlesize": 8, "axes.labelsize": 8, "xtick.labelsize": 7,
                         "ytick.labelsize": 7, "legend.fontsize": 8}):
        height = 1.5 * rows + 1.6 + 0.9          # the panels, the holds' panel, the title and legend band
        fig = plt.figure(figsize=(7.2, height))
        grid = fig.add_gridspec(rows + 1, cols, height_ratios=[1.0] * rows + [1.1], hspace=0.6, wspace=0.12,
                                left=0.09, right=0.985, top=1.0 - 0.75 / height, bottom=0.45 / height)
        t = tr.t
        first = None
        for b, name in enumerate(names):
            ax = fig.add_subplot(grid[b // cols, b % cols], sharex=first, sharey=first)
            first = first or ax
            n = min(lengths[b] * HOLD, int(round(window_s / tr.dt)))
            v = np.maximum(tr.after[:n, b], V_FLOOR)
            up = np.flatnonzero(tr.update[:n, b])
            vu = np.maximum(tr.before[up, b], V_FLOOR)
            # the curve through V at each update too: a vertical jump, then the hold's decay
            ax.semilogy(np.insert(t[:n], up, t[up] - tr.dt), np.insert(v, up, vu), lw=0.5, color="tab:blue",
                        label="$V$ along the run")
            ax.plot(t[up] - tr.dt, vu, ".", ms=2, color="tab:red", label="$V$ at a target update")
            c = np.flatnonzero(tr.constrained[:n, b])
            if c.size:
                ax.plot(t[c], v[c], "o", ms=4, mfc="none", mew=0.8, color="tab:orange",
                        label="CBF constraint active")
            total_c = int(tr.constrained[: lengths[b] * HOLD, b].sum())
            ax.set_title(f"{name} ({total_c} constrained)" if total_c else name, pad=2)
            if b % cols:
                ax.tick_params(labelleft=False)
            else:
                ax.set_ylabel("$V$ (rad$^2$)")
            if b // cols == rows - 1 or b + cols >= len(names):
                ax.set_xlabel("$t$ (s)")
            else:
                ax.tick_params(labelbottom=False)
        ax = fig.add_subplot(grid[rows, :])
        ratio, active = _holds(tr, lengths)
        k = np.arange(HOLD + 1)
        for r, colour in ((ratio[~active], "tab:blue"), (ratio[active], "tab:orange")):
            if len(r):
                ax.semilogy(k, r.T, lw=0.4, alpha=0.3, color=colour)
        ax.semilogy(k, (1 - tr.gain * tr.dt) ** (2 * k), "k--", lw=1.2,
                    label=r"$(1 - K\,\Delta t)^{2k}$: free decay")
        ax.set_title(f"every hold of every sample ({len(ratio)} holds): $V$ / $V$ at its update", pad=2)
        ax.set_xlabel(f"steps of {tr.dt * 1e3:g} ms since the target update")
        ax.set_ylabel("$V / V_0$")
        handles, labels = [], []
        for a in fig.axes:
            for h, lab in zip(*a.get_legend_handles_labels()):
                if lab not in labels:
                    handles.append(h)
                    labels.append(lab)
        fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 1.0 - 0.28 / height),
                   ncol=min(4, len(labels)), frameon=False, markerscale=2, handlelength=1.4, columnspacing=1.0,
                   fontsize=7)
        fig.suptitle(r"Lyapunov function under the CBF filter (paper's Fig. 13): "
                     r"$V = \frac{1}{2}\,\|q - q_{\mathrm{ref}}\|_H^2$, "
                     f"each waypoint held {HOLD} steps", y=1.0 - 0.04 / height, va="top")
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=dpi)
        plt.close(fig)
    return out
