"""A PNG of a drawing plan (matplotlib, Agg backend).

Shows the safe region (the disk the drawing was fitted into) and the arm's
full reach, the target strokes (solid), the pen-up moves between them
(dashed), and the arm at a few poses along the plan (faded, darker later).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from armbridge.draw.build import Drawing

ARM_POSES = 5  # arm drawings along the plan


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


def draw_png(d: Drawing, out: Path | str, *, title: str, dpi: int = 120) -> Path:
    """Write the figure of drawing d to out; returns the path."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    robot = d.plan.robot
    out = Path(out)
    fig, ax = plt.subplots(figsize=(7, 7))
    try:
        ax.add_patch(Circle((0, 0), robot.reach, fill=False, ls=":", color="0.6", lw=0.8, label="reach"))
        ax.add_patch(Circle((float(d.region.center[0]), float(d.region.center[1])), d.region.radius, fc="#e8f4e8", ec="#3c963c", lw=1.0,
                            label="safe region"))
        if d.placement.margin > 0:
            ax.add_patch(Circle((float(d.region.center[0]), float(d.region.center[1])),
                                d.region.radius - d.placement.margin, fill=False, ls="--", color="#3c963c", lw=0.6,
                                label=f"safety margin ({d.placement.margin * 1000:.1f} mm)"))
        for n, (a, b) in enumerate(_runs(d.pen, 1)):
            ax.plot(d.xy[a:b + 1, 0], d.xy[a:b + 1, 1], "-", color="#1f3a93", lw=1.4, zorder=3,
                    label="pen down" if n == 0 else None)
        for n, (a, b) in enumerate(_runs(d.pen, 0)):
            ax.plot(d.xy[a:b + 1, 0], d.xy[a:b + 1, 1], "--", color="#d9534f", lw=0.8, zorder=3,
                    label="pen up" if n == 0 else None)
        picks = np.linspace(0, d.plan.k - 1, ARM_POSES).round().astype(int)
        for n, i in enumerate(picks):
            pts = robot.joint_points(d.plan.q[i])
            alpha = 0.25 + 0.75 * n / max(1, ARM_POSES - 1)
            ax.plot(pts[:, 0], pts[:, 1], "o-", color="0.2", alpha=alpha, lw=2, ms=3, zorder=1,
                    label="arm" if n == 0 else None)
        r = robot.reach
        ax.set_xlim(-r * 1.05, r * 1.05)
        ax.set_ylim(-r * 1.05, r * 1.05)
        ax.set_aspect("equal")
        ax.grid(True, lw=0.3)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(title)
        ax.legend(loc="lower left", fontsize=8)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=dpi, bbox_inches="tight")
    finally:
        plt.close(fig)
    return out
