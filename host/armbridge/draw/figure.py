"""A PNG of a drawing plan (matplotlib, Agg backend).

Framed on the drawing (its pen path, and the executed trace when there was a
run, plus FRAME_PAD on every side), not on the arm's whole reach: the target
strokes (solid), the pen-up moves between them (dashed, as the arm sweeps them:
one joint-space move bows off the straight line), the executed pen-down
trace (red, from the run's measured angles through FK), the edge of the safe
region and its margin where they pass through the frame, the page's edge when
there is one, and the arm at a few poses along the plan (faded, darker later;
cut at the frame).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from armbridge.draw.build import Drawing
from armbridge.draw.path import sweep

ARM_POSES = 5  # arm drawings along the plan
FRAME_PAD = 0.12  # the frame's margin around the drawing, as a fraction of its larger side
FRAME_MIN = 0.01  # m: the smallest frame side (a single short stroke still gets a readable figure)


def _runs(pen: np.ndarray, value: int) -> list[tuple[int, int]]:
    """(first, last) waypoint index pairs of the moves with pen == value (a move i-1 -> i has flag pen[i])."""
    runs, start = [], None
    for i in range(1, len(pen) + 1):
        on = i < len(pen) and pen[i] == value
        if on and start is None:
            start = i - 1
        elif not on and start is not None:
            runs.append((start, i - 1))
            start = None
    return runs


def frame(d: Drawing, trace: list[np.ndarray] | None = None) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1), m: the box around the drawing's pen path and the trace, padded by FRAME_PAD
    of its larger side (and at least FRAME_MIN a side)."""
    pts = np.vstack([d.xy[1:] if len(d.xy) > 1 else d.xy, *(trace or [])])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = float(np.max(hi - lo)) * FRAME_PAD
    side = np.maximum(hi - lo + 2 * pad, FRAME_MIN)
    mid = (lo + hi) / 2
    return mid[0] - side[0] / 2, mid[0] + side[0] / 2, mid[1] - side[1] / 2, mid[1] + side[1] / 2


def draw_png(d: Drawing, out: Path | str, *, title: str, dpi: int = 120,
             trace: list[np.ndarray] | None = None) -> Path:
    """Write the figure of drawing d to out, with the executed pen-down `trace` (m) of a run when
    given; returns the path."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    robot = d.plan.robot
    out = Path(out)
    x0, x1, y0, y1 = frame(d, trace)
    fig, ax = plt.subplots(figsize=(7, float(np.clip(7 * (y1 - y0) / (x1 - x0), 2.5, 9))))
    try:
        ax.add_patch(Circle((float(d.region.center[0]), float(d.region.center[1])), d.region.radius, fc="#e8f4e8", ec="#3c963c", lw=1.0,
                            label="safe region"))
        if d.placement.margin > 0:
            ax.add_patch(Circle((float(d.region.center[0]), float(d.region.center[1])),
                                d.region.radius - d.placement.margin, fill=False, ls="--", color="#3c963c", lw=0.6,
                                label=f"safety margin ({d.placement.margin * 1000:.1f} mm)"))
        for n, (a, b) in enumerate(_runs(d.pen, 1)):
            ax.plot(d.xy[a:b + 1, 0], d.xy[a:b + 1, 1], "-", color="#1f3a93", lw=1.4, zorder=3,
                    label="pen down" if n == 0 else None)
        for n, (a, b) in enumerate(_runs(d.pen, 0)):  # each pen-up move as the arm sweeps it (a joint line)
            swept = np.vstack([sweep(robot, d.plan.q[i], d.plan.q[i + 1]) for i in range(a, b)])  # type: ignore[arg-type]
            ax.plot(swept[:, 0], swept[:, 1], "--", color="#d9534f", lw=0.8, zorder=3,
                    label="pen up" if n == 0 else None)
        for n, strip in enumerate(trace or []):
            ax.plot(strip[:, 0], strip[:, 1], "-", color="#d62728", lw=0.9, alpha=0.8, zorder=4,
                    label="drawn (measured)" if n == 0 else None)
        if d.page is not None:
            from matplotlib.patches import Rectangle

            c = d.page.corner(d.placement.at)
            ax.add_patch(Rectangle((c[0], c[1] - d.page.height), d.page.width, d.page.height, fill=False,
                                   color="0.4", lw=0.8, label=f"page {d.page.name}"))
        picks = np.linspace(0, d.plan.k - 1, ARM_POSES).round().astype(int)
        for n, i in enumerate(picks):
            pts = robot.joint_points(d.plan.q[i])
            alpha = 0.15 + 0.45 * n / max(1, ARM_POSES - 1)
            ax.plot(pts[:, 0], pts[:, 1], "o-", color="0.2", alpha=alpha, lw=2, ms=3, zorder=1,
                    label="arm" if n == 0 else None)
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        ax.grid(True, lw=0.3)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.ticklabel_format(useOffset=False)
        ax.set_title(title)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=dpi, bbox_inches="tight")
    finally:
        plt.close(fig)
    return out
