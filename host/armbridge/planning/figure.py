"""PNGs of planar-arm planning problems and their paths (matplotlib, Agg backend).

`draw(env, path, out)` writes the figure of a MASR planning problem (masr
paper, Fig. 6 style): the workspace reach, the obstacles with their inflated
margins (half the link width, Fig. 3a) and a number inside each, the goal
region (a circle of radius e_p and the goal heading with its +-e_phi wedge,
eq. 9) drawn on top of everything, the start configuration, the arm after
every step of the motion convention (section II-C, lighter = earlier), the
final configuration, the MA's real path (it drives along the links between
rotations, `ma_trace`) and the MA at the waypoints. A detail panel zooms on
the goal, where the 8 mm tolerance is only a few pixels wide in the main
view, and the legend sits beside the data, never on it.

The pieces are generic over any planar serial chain (a chain is an (n+1, 2)
array of points, base -> tip), so another arm's plan figure uses the same
code:

    pf = plan_axes()                                   # main, detail and legend panels
    style_workspace(pf.ax, reach); draw_reach(pf.ax, reach)
    draw_obstacles(pf.ax, polygons, margin=w / 2)      # numbers inside each polygon
    draw_chain(pf.ax, start_points, role="start")      # (n+1, 2)
    draw_shapes(pf.ax, chains)                         # (S, n+1, 2), faded, one legend entry
    draw_chain(pf.ax, final_points, role="final")
    draw_tip_path(pf.ax, tips, label="tip path")       # (M, 2)
    draw_goal(pf.ax, goal_xy, tolerance)
    zoom(pf, goal_xy, half)                            # redraw the same calls on pf.detail first
    finish(pf, "plan.png")                             # legend, save, close

All colours are the Okabe-Ito colour-blind-safe palette (`OKABE_ITO`).
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, NamedTuple, Optional, Union

import numpy as np

from armbridge.errors import ArmbridgeError

#: Okabe & Ito (2008) colour-blind-safe palette.
OKABE_ITO = {"black": "#000000", "orange": "#E69F00", "sky": "#56B4E9", "green": "#009E73", "yellow": "#F0E442",
             "blue": "#0072B2", "vermillion": "#D55E00", "purple": "#CC79A7"}
#: Colour, line width, legend label per chain role.
ROLES = {"start": (OKABE_ITO["blue"], 2.4, "start configuration"),
         "final": (OKABE_ITO["vermillion"], 2.4, "final configuration"),
         "shape": (OKABE_ITO["orange"], 1.0, "arm after each step (lighter = earlier)")}
MA_COLOR = OKABE_ITO["purple"]
GOAL_COLOR = OKABE_ITO["green"]
Z = {"tree": 1, "margin": 2, "obstacle": 2.5, "goal_fill": 3, "shape": 4, "chain": 5, "path": 6, "point": 7,
     "goal": 8, "label": 9}


class PlanFigure(NamedTuple):
    """A plan figure's panels: the workspace (ax), the goal detail (detail, or None) and the legend (key)."""

    fig: Any
    ax: Any
    detail: Any
    key: Any


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def plan_axes(*, detail: bool = True, figsize: tuple[float, float] = (10.0, 7.0)) -> PlanFigure:
    """A figure with the square workspace panel on the left, the detail panel and the legend on the right."""
    plt = pyplot()
    fig = plt.figure(figsize=figsize, layout="constrained")
    gs = fig.add_gridspec(2, 2, width_ratios=(7, 3), height_ratios=(1, 1.15))
    ax = fig.add_subplot(gs[:, 0])
    det = fig.add_subplot(gs[0, 1]) if detail else None
    key = fig.add_subplot(gs[1, 1] if detail else gs[:, 1])
    key.axis("off")
    return PlanFigure(fig, ax, det, key)


def style_workspace(ax: Any, half_width: float, center: Sequence[float] = (0.0, 0.0), *, pad: float = 0.05) -> None:
    """Equal axes of +-(half_width + pad) m around center, a light grid, labelled x/y in m."""
    cx, cy = center
    h = half_width + pad
    ax.set_aspect("equal")
    ax.set_xlim(cx - h, cx + h)
    ax.set_ylim(cy - h, cy + h)
    ax.grid(True, lw=0.3, color="0.85")
    ax.set_axisbelow(True)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def draw_reach(ax: Any, radius: float, center: Sequence[float] = (0.0, 0.0), *, base: bool = True) -> None:
    """The reach circle (dotted) and, with base, the base as a black triangle."""
    from matplotlib.patches import Circle

    ax.add_patch(Circle((float(center[0]), float(center[1])), radius, fill=False, ls=":", color="0.45", lw=1.0,
                        label=f"reach ({radius:.2f} m)"))
    if base:
        ax.plot(*center, "^", color="k", ms=8, zorder=Z["chain"] + 0.5, label="base")


def label_point(polygon: Any) -> np.ndarray:
    """The pole of inaccessibility of a polygon ((k, 2) vertices): the inside point farthest from its edges.

    Unlike the vertex mean it always lies inside, also for a U-shaped pocket.
    """
    from shapely.geometry import Polygon  # type: ignore[import-untyped]
    from shapely.ops import polylabel  # type: ignore[import-untyped]

    poly = Polygon(np.asarray(polygon, float))
    if not poly.is_valid:
        poly = poly.buffer(0)
    size = max(poly.bounds[2] - poly.bounds[0], poly.bounds[3] - poly.bounds[1])
    p = polylabel(poly, tolerance=max(size * 1e-3, 1e-9))
    return np.array([p.x, p.y])


def _halo_text(ax: Any, xy: Sequence[float], s: str, **kw: Any) -> Any:
    import matplotlib.patheffects as pe

    return ax.text(xy[0], xy[1], s, ha="center", va="center", color="k", zorder=Z["label"], clip_on=True,
                   path_effects=[pe.withStroke(linewidth=2.5, foreground="white")], **kw)


def draw_obstacles(ax: Any, polygons: Iterable[Any], *, margin: float = 0.0,
                   labels: Union[bool, Sequence[str]] = True) -> np.ndarray:
    """Obstacles ((k, 2) vertex arrays) in grey, their margin-inflated outline dashed, a number inside each.

    A 2-vertex obstacle is a wall segment: a thick black line, its number at its middle (none on
    walls shorter than 4 % of the obstacles' extent, where numbers would pile up).

    labels: True numbers them 0, 1, ... (the index of obstacles[i] in environment files and
    error messages), a sequence gives the texts, False draws none. Returns the label
    points (m, 2): each the polygon's `label_point`, inside it.
    """
    from matplotlib.patches import Polygon as MplPolygon
    from shapely.geometry import LineString, Polygon  # type: ignore[import-untyped]

    polys = [np.asarray(p, float) for p in polygons]
    names = [str(i) for i in range(len(polys))] if labels is True else list(labels) if labels else []
    if names and len(names) != len(polys):
        raise ArmbridgeError(f"draw_obstacles: {len(names)} labels for {len(polys)} obstacles")
    points = np.empty((len(polys), 2))
    walls = 0
    every = np.concatenate(polys) if polys else np.zeros((1, 2))
    span = float(np.ptp(every, axis=0).max()) if len(every) > 1 else 1.0  # walls shorter than 4 % go unnumbered
    for i, p in enumerate(polys):
        wall = p.shape[0] == 2  # a wall segment (OMPL's kinematic-chain environments)
        if margin > 0:
            shape = LineString(p) if wall else Polygon(p)
            xs, ys = shape.buffer(margin, quad_segs=16).exterior.xy
            ax.add_patch(MplPolygon(np.c_[xs, ys], closed=True, fc="#F6D5C8", ec=OKABE_ITO["vermillion"], lw=0.6,
                                    ls="--", zorder=Z["margin"],
                                    label=f"obstacle margin ({margin * 1000:.0f} mm)" if i == 0 else None))
        if wall:
            ax.plot(p[:, 0], p[:, 1], "-", color="k", lw=2.0, solid_capstyle="butt", zorder=Z["obstacle"],
                    label="wall" if walls == 0 else None)
            walls += 1
            points[i] = p.mean(axis=0)
        else:
            ax.add_patch(MplPolygon(p, closed=True, fc="0.6", ec="k", lw=0.8, zorder=Z["obstacle"],
                                    label="obstacle" if i - walls == 0 else None))
            points[i] = label_point(p)
        if names and (not wall or np.linalg.norm(p[1] - p[0]) >= 0.04 * span):
            _halo_text(ax, points[i], names[i], fontsize=7 if wall else 9, fontweight="bold")
    return points


def draw_chain(ax: Any, points: Any, *, role: str = "start", label: Optional[str] = "", **kw: Any) -> Any:
    """One planar chain, (n+1, 2) points base -> tip, as links with joint dots; role picks colour and label.

    label "" takes the role's legend label, None gives no legend entry. Returns the Line2D.
    """
    color, lw, default = ROLES[role]
    pts = np.asarray(points, float)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ArmbridgeError(f"draw_chain: points must have shape (n+1, 2), got {pts.shape}")
    opts = {"color": color, "lw": lw, "ms": 3.0, "zorder": Z["chain"], "solid_capstyle": "round",
            "label": default if label == "" else label, **kw}
    return ax.plot(pts[:, 0], pts[:, 1], "-o", **opts)[0]


def draw_shapes(ax: Any, chains: Any, *, role: str = "shape", label: Optional[str] = "") -> None:
    """Several chains (S, n+1, 2) in order, alpha rising from 0.2 to 0.75; one legend entry (the last)."""
    chains = np.asarray(chains, float)
    if chains.size == 0:
        return
    for k, pts in enumerate(chains):
        last = k == len(chains) - 1
        draw_chain(ax, pts, role=role, label=label if last else None, ms=2.0, zorder=Z["shape"],
                   alpha=0.2 + 0.55 * (k + 1) / len(chains))


def draw_tip_path(ax: Any, points: Any, *, label: Optional[str] = "tip path", color: str = MA_COLOR,
                  ls: Any = "-", **kw: Any) -> Any:
    """A path of tip (or MA) positions (M, 2) as a line."""
    pts = np.asarray(points, float).reshape(-1, 2)
    return ax.plot(pts[:, 0], pts[:, 1], ls=ls, color=color, lw=1.4, zorder=Z["path"], label=label, **kw)[0]


def draw_points(ax: Any, points: Any, *, label: Optional[str] = None, color: str = MA_COLOR, marker: str = "s",
                ms: float = 5.5, **kw: Any) -> Any:
    """Positions (M, 2) as hollow markers, not joined (so whatever lies under them stays visible)."""
    pts = np.asarray(points, float).reshape(-1, 2)
    return ax.plot(pts[:, 0], pts[:, 1], ls="none", marker=marker, ms=ms, mfc="white", mec=color, mew=1.4,
                   zorder=Z["point"], label=label, **kw)[0]


def draw_goal(ax: Any, xy: Sequence[float], radius: float, *, heading: Optional[float] = None,
              half_angle: float = 0.0, wedge: float = 0.06, label: Optional[str] = "") -> None:
    """The goal tolerance circle (outline on top of everything, light fill below), heading and +-half_angle."""
    from matplotlib.patches import Circle, Wedge

    x, y = xy
    if label == "":
        label = f"goal (e_p = {radius * 1000:g} mm" + (f", e_phi = {math.degrees(half_angle):.0f} deg)"
                                                      if heading is not None else ")")
    ax.add_patch(Circle((x, y), radius, fc=GOAL_COLOR, alpha=0.25, lw=0, zorder=Z["goal_fill"]))
    ax.add_patch(Circle((x, y), radius, fill=False, ec=GOAL_COLOR, lw=1.6, zorder=Z["goal"], label=label))
    if heading is not None:
        ax.add_patch(Wedge((x, y), wedge, math.degrees(heading - half_angle), math.degrees(heading + half_angle),
                           color=GOAL_COLOR, alpha=0.3, lw=0, zorder=Z["goal_fill"]))
        ax.plot([x, x + wedge * math.cos(heading)], [y, y + wedge * math.sin(heading)], color=GOAL_COLOR, lw=1.6,
                zorder=Z["goal"])


def zoom(pf: PlanFigure, center: Sequence[float], half: float) -> None:
    """Limit the detail panel (already drawn into) to +-half m around center; outline that square on ax."""
    from matplotlib.patches import Rectangle

    if pf.detail is None:
        return
    style_workspace(pf.detail, half, center, pad=0.0)
    pf.detail.set_title("goal detail", fontsize=9)
    pf.ax.add_patch(Rectangle((center[0] - half, center[1] - half), 2 * half, 2 * half, fill=False, ec="0.3",
                              lw=0.8, ls="-", zorder=Z["label"]))


def finish(pf: Union[PlanFigure, Any], out: Any, *, dpi: int = 150) -> Path:
    """Put the legend of pf.ax's labelled artists in pf.key (if pf is a PlanFigure), write the PNG, close."""
    plt = pyplot()
    fig = pf.fig if isinstance(pf, PlanFigure) else pf
    out = Path(out)
    try:
        if isinstance(pf, PlanFigure):
            handles, labels = pf.ax.get_legend_handles_labels()
            pf.key.legend(handles, labels, loc="upper left", fontsize=8, frameon=False, borderaxespad=0.0)
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            fig.savefig(out, dpi=dpi)
        except OSError as exc:
            raise ArmbridgeError(f"{out}: cannot write the figure: {exc.strerror}") from None
    finally:
        plt.close(fig)
    return out


# --------------------------------------------------------------------------- MASR
def step_shapes(arm: Any, path: Any) -> np.ndarray:
    """The arm's shape (S, n+1, 2) after every rotation of the motion convention along path (K, n+1).

    Moves of the MA leave the shape unchanged, so repeated shapes are dropped; the
    start and the final configuration (drawn on their own) are left out.
    """
    path = np.asarray(path, float)
    qs = [path[0]] + [q for a, b in zip(path[:-1], path[1:]) for q in arm.intermediate_configs(a, b)]
    shapes = [arm.joint_points(q) for q in qs]
    keep = [s for prev, s in zip(shapes[:-1], shapes[1:]) if not np.allclose(prev, s)]
    final = arm.joint_points(path[-1])
    keep = [s for s in keep if not np.allclose(s, final)]
    return np.array(keep).reshape(-1, arm.n + 1, 2)


def ma_trace(arm: Any, path: Any, step: float = 0.002) -> np.ndarray:
    """Where the MA really goes along path (K, n+1): (M, 2) points, at most step m apart along the arm.

    By the motion convention (section II-C, MasrArm.action_sequence) the arm is still
    while the MA drives, so a move is the MA sliding along the current shape; during a
    rotation of joint j the MA stands on joint j, which that rotation does not move.
    """
    path = np.asarray(path, float)
    pts = [arm.ma_point(path[0])[None]]
    for a, b in zip(path[:-1], path[1:]):
        q = a
        for nxt in arm.intermediate_configs(a, b):
            if nxt[-1] != q[-1]:  # a move: same angles, d from q[-1] to nxt[-1]
                m = max(2, int(math.ceil(abs(nxt[-1] - q[-1]) / step)) + 1)
                qs = np.repeat(q[None], m, axis=0)
                qs[:, -1] = np.linspace(q[-1], nxt[-1], m)
                pts.append(arm.ma_point(qs)[1:])
            q = nxt
    return np.concatenate(pts)


def masr_figure(env: Any, path: Optional[np.ndarray] = None, *, title: Optional[str] = None, show_tree: Any = None,
                detail: bool = True) -> PlanFigure:
    """The figure of env and a configuration path (K, n+1), not yet saved (see `draw`)."""
    arm = env.arm
    pf = plan_axes(detail=detail)
    gx, gy, gphi = (float(v) for v in env.goal_pose)
    path = None if path is None or len(path) == 0 else np.asarray(path, float)
    for ax in (pf.ax, pf.detail):
        if ax is None:
            continue
        draw_reach(ax, arm.total_length)
        draw_obstacles(ax, env.obstacles, margin=0.5 * arm.link_width, labels=ax is pf.ax)
        if show_tree is not None:
            Q, parent = show_tree
            P = arm.ma_point(Q)
            for v in range(1, len(Q)):
                if parent[v] >= 0:
                    ax.plot(*np.c_[P[parent[v]], P[v]], color="0.8", lw=0.3, zorder=Z["tree"],
                            label="tree (MA positions)" if v == 1 else None)
        draw_chain(ax, arm.joint_points(env.start), role="start")
        if path is not None:
            draw_shapes(ax, step_shapes(arm, path))
            draw_chain(ax, arm.joint_points(path[-1]), role="final")
            draw_tip_path(ax, ma_trace(arm, path), label="MA path (along the links)", ls=(0, (4, 2)))
            draw_points(ax, arm.ma_point(path), label="MA at waypoints")
        else:
            draw_points(ax, arm.ma_point(env.start), label="MA")
        draw_goal(ax, (gx, gy), env.e_p, heading=gphi, half_angle=env.e_phi)
    style_workspace(pf.ax, arm.total_length)
    zoom(pf, (gx, gy), max(0.04, 6 * env.e_p))
    if path is not None:
        tau = float(arm.path_time(path)) if len(path) > 1 else 0.0
        sub = f"{len(path)} waypoints, tau = {tau:.2f} s"
    else:
        sub = "no path"
    pf.ax.set_title(f"{title or env.name}: {sub}")
    return pf


def draw(env: Any, path: Optional[np.ndarray] = None, out: Any = None, *, title: Optional[str] = None,
         dpi: int = 150, show_tree: Any = None) -> Path:
    """Write a PNG of env and (optionally) a configuration path (K, n+1) to out; returns the path.

    show_tree: optional (Q, parent) of a planner's tree, drawn as MA positions joined to their parents.
    """
    out = Path(out if out is not None else f"{env.name}.png")
    return finish(masr_figure(env, path, title=title, show_tree=show_tree), out, dpi=dpi)
