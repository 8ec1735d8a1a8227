"""A PNG of a MASR planning problem and its path (matplotlib, Agg backend).

Shows the workspace reach, the obstacles and their inflated margins (half
the link width), the goal region (a circle of radius e_p and the goal
heading with its +-e_phi wedge), the start configuration (solid), the arm
along the path (faded, darker towards the end), the final configuration
and the MA (gripper) positions at the waypoints.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError


def draw(env: Any, path: Optional[np.ndarray] = None, out: Any = None, *, title: Optional[str] = None,
         dpi: int = 120, show_tree: Any = None) -> Path:
    """Write a PNG of env and (optionally) a configuration path (K, n+1) to out; returns the path."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon as MplPolygon, Wedge
    from shapely.geometry import Polygon  # type: ignore[import-untyped]

    arm = env.arm
    out = Path(out if out is not None else f"{env.name}.png")
    L = arm.total_length
    r = 0.5 * arm.link_width
    fig, ax = plt.subplots(figsize=(7, 7))
    try:
        ax.add_patch(Circle((0, 0), L, fill=False, ls=":", color="0.6", lw=0.8))
        for i, p in enumerate(env.obstacles):
            inflated = Polygon(p).buffer(r, quad_segs=16)
            xs, ys = inflated.exterior.xy
            ax.add_patch(MplPolygon(np.c_[xs, ys], closed=True, fc="#f4c7c3", ec="#d9534f", lw=0.6, ls="--",
                                    label="margin (w/2)" if i == 0 else None))
            ax.add_patch(MplPolygon(p, closed=True, fc="#8c8c8c", ec="k", lw=0.8,
                                    label="obstacle" if i == 0 else None))
            c = np.mean(p, axis=0)
            ax.text(c[0], c[1], str(i), ha="center", va="center", fontsize=8, color="w")
        gx, gy, gphi = env.goal_pose
        ax.add_patch(Circle((gx, gy), env.e_p, color="tab:green", alpha=0.35, label="goal region (e_p)"))
        wedge_r = 0.06
        ax.add_patch(Wedge((gx, gy), wedge_r, math.degrees(gphi - env.e_phi), math.degrees(gphi + env.e_phi),
                           color="tab:green", alpha=0.25))
        ax.plot([gx, gx + wedge_r * math.cos(gphi)], [gy, gy + wedge_r * math.sin(gphi)], color="tab:green", lw=1.5)

        if show_tree is not None:
            Q, parent = show_tree
            P = arm.ma_point(Q)
            for v in range(1, len(Q)):
                if parent[v] >= 0:
                    a, b = P[parent[v]], P[v]
                    ax.plot([a[0], b[0]], [a[1], b[1]], color="0.8", lw=0.3, zorder=1)

        def arm_line(q: np.ndarray, **kw: Any) -> None:
            pts = arm.joint_points(q)
            ax.plot(pts[:, 0], pts[:, 1], "-o", ms=2.5, solid_capstyle="round", **kw)

        arm_line(env.start, color="tab:blue", lw=2.2, label="start", zorder=4)
        ma = arm.ma_point(env.start)
        ax.plot(*ma, "s", color="tab:blue", ms=6, zorder=5)
        if path is not None and len(path) > 0:
            path = np.asarray(path, float)
            # the arm after every step of the convention, faded
            shapes = []
            for a, b in zip(path[:-1], path[1:]):
                shapes.extend(arm.intermediate_configs(a, b))
            for k, q in enumerate(shapes[:-1]):
                arm_line(q, color="tab:orange", lw=1.0, alpha=0.15 + 0.45 * k / max(1, len(shapes)), zorder=3)
            arm_line(path[-1], color="tab:red", lw=2.2, label="final", zorder=4)
            mas = arm.ma_point(path)
            ax.plot(mas[:, 0], mas[:, 1], "--", color="tab:purple", lw=1.0, label="MA at waypoints", zorder=5)
            ax.plot(*mas[-1], "s", color="tab:red", ms=6, zorder=6)
            tau = float(arm.path_time(path)) if len(path) > 1 else 0.0
            sub = f"{len(path)} waypoints, tau = {tau:.2f} s"
        else:
            sub = "no path"
        ax.plot(0, 0, "k^", ms=8)
        ax.set_aspect("equal")
        ax.set_xlim(-L - 0.05, L + 0.05)
        ax.set_ylim(-L - 0.05, L + 0.05)
        ax.grid(True, lw=0.3)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(f"{title or env.name}: {sub}")
        ax.legend(loc="lower left", fontsize=7)
        out.parent.mkdir(parents=True, exist_ok=True)
        try:
            fig.savefig(out, dpi=dpi, bbox_inches="tight")
        except OSError as exc:
            raise ArmbridgeError(f"{out}: cannot write the figure: {exc.strerror}") from None
    finally:
        plt.close(fig)
    return out
