"""The report's picture (matplotlib, Agg): one figure per run, for any robot the recording draws.

    +------------------------------+---------------------------------+
    | the workspace: plan against  | per joint: set point (dashed)   |
    | what ran (plan path and      | and measured over board time;   |
    | waypoints, the measured tip  | the board's own columns (the    |
    | trace, the arm at a few      | MA's link and speed, the pump's |
    | times and at the end, the    | syringes); lines at ERROR-level |
    | obstacles, a soft plan's     | events (faults, e-stops)        |
    | planned tip path and poses)  |                                 |
    +------------------------------+---------------------------------+
    | the numbers (summary, link)  | events and errors               |
    +------------------------------+---------------------------------+

A spatial arm (3-D) is drawn in its x-y projection.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from armbridge.report.data import RunData, arm_at
from armbridge.report.numbers import summary_rows
from armbridge.telemetry.layout import BOARD_COLUMNS

BASE_FONT = 11
PLAN, TRACE, ARM, OBST = "#2f6fdb", "#f08c00", "#333333", "#d64545"
EVENT_LINES = 26  # at most this many lines of the logs in the picture (the HTML page has them all)


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover - a dependency of armbridge (pyproject.toml)
        from armbridge.errors import ArmbridgeError

        raise ArmbridgeError("the report needs matplotlib, a dependency of armbridge: "
                             "pip install 'matplotlib>=3.8'") from None
    return plt


def board_groups(data: RunData) -> dict[str, list[str]]:
    """The board's own series in the recording, by the view that plots them (telemetry.layout)."""
    groups: dict[str, list[str]] = {}
    for cols in BOARD_COLUMNS.values():
        for path, _scale, view in cols:
            if path in data.series:
                groups.setdefault(view, []).append(path)
    return groups


def log_lines(data: RunData, limit: int | None = EVENT_LINES) -> list[tuple[str, str]]:
    """The event and error logs as (level, line), board-time order; past `limit`, the ERROR and
    WARN lines and the errors log are kept before the plain events, and a last line says how many
    were left out."""
    lines = [(t, lv.upper(), f"{t:8.3f} s  {text}") for t, lv, text in data.events]
    lines += [(t, lv.upper(), f"{t:8.3f} s  [errors] {text}") for t, lv, text in data.errors]
    lines.sort(key=lambda x: x[0])
    if limit is None or len(lines) <= limit:
        return [(lv, text) for _t, lv, text in lines]
    keep = {i for i, (_t, lv, text) in enumerate(lines) if lv in ("ERROR", "WARN") or "[errors]" in text}
    rest = [i for i in range(len(lines)) if i not in keep]
    room = max(0, limit - 1 - len(keep))
    keep.update(rest[: room // 2] + rest[len(rest) - (room - room // 2):] if room else [])
    chosen = sorted(keep)[: limit - 1]
    out = [(lines[i][1], lines[i][2]) for i in chosen]
    out.append(("INFO", f"... {len(lines) - len(chosen)} more lines in the recording (the HTML report lists all)"))
    return out


def _poses(n: int, k: int = 5) -> list[int]:
    return sorted({int(round(x)) for x in np.linspace(0, n - 1, k)}) if n else []


def draw_workspace(ax, data: RunData) -> None:
    """Plan against execution in the arm's space (x-y)."""
    from matplotlib.patches import Polygon

    def xy(a: np.ndarray) -> np.ndarray:
        return np.asarray(a, float)[:, :2]

    for ring in data.strips.get("workspace", []):
        ax.plot(*xy(ring).T, color="#9a9a9a", lw=0.8, ls=":", label="reach")
    for i, ring in enumerate(data.strips.get("world/obstacles", [])):
        ax.add_patch(Polygon(xy(ring), closed=True, facecolor="#f4c7c7", edgecolor=OBST, lw=1.2,
                             label="obstacles" if i == 0 else None))
    for i, shape in enumerate(data.strips.get("plan/shapes", [])):
        ax.plot(*xy(shape).T, color=PLAN, lw=0.8, alpha=0.35, label="planned poses" if i == 0 else None)
    for strip in data.strips.get("plan/planned_tip", []):
        ax.plot(*xy(strip).T, color=PLAN, lw=1.2, ls="--", label="planned tip path (planner)")
    for i, strip in enumerate(data.strips.get("drawing/target", [])):
        ax.plot(*xy(strip).T, color=PLAN, lw=1.6, label="strokes (plan)" if i == 0 else None)
    for strip in data.strips.get("plan/path", []):
        ax.plot(*xy(strip).T, color=PLAN, lw=1.8, alpha=0.8, label="plan: tip path")
    if "plan/waypoints" in data.points:
        ax.plot(*xy(data.points["plan/waypoints"]).T, "o", color=PLAN, ms=3.5, label="plan: waypoints")
    for strip in data.strips.get("trace/tip", []):
        ax.plot(*xy(strip).T, color=TRACE, lw=1.6, label="executed: measured tip")
    for i, strip in enumerate(data.drawing_trace):
        ax.plot(*xy(strip).T, color="#c92a2a", lw=1.2, label="executed: pen down" if i == 0 else None)
    if "arm/links" in data.arm:
        n = len(data.arm["arm/links"][0])
        poses = _poses(n)
        for i in poses[:-1]:
            for strip in arm_at(data, "arm/links", i):
                ax.plot(*xy(strip).T, "-o", color=ARM, lw=1.0, ms=2.5, alpha=0.25)
        if poses:
            t_end = data.arm["arm/links"][0][poses[-1]]
            for j, strip in enumerate(arm_at(data, "arm/links", poses[-1])):
                ax.plot(*xy(strip).T, "-o", color=ARM, lw=2.2, ms=4,
                        label=f"executed: arm at {t_end:.1f} s (faint: earlier)" if j == 0 else None)
        if "arm/target" in data.arm and poses:
            for j, strip in enumerate(arm_at(data, "arm/target", poses[-1])):
                ax.plot(*xy(strip).T, "--", color=PLAN, lw=1.2, label="set point at the end" if j == 0 else None)
    _zoom(ax, data)
    ax.set_aspect("equal", adjustable="box")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("x (m)" if data.dim == 2 else "x (m), x-y projection")
    ax.set_ylabel("y (m)")
    ax.set_title("workspace: plan vs executed")
    ax.legend(loc="best", fontsize=BASE_FONT - 2, framealpha=0.85)


def _zoom(ax, data: RunData) -> None:
    """Limits around what ran and what was planned (the reach circle may be far larger)."""
    pts = [s[:, :2] for ent, strips in data.strips.items() if ent != "workspace" for s in strips]
    pts += [p[:, :2] for p in data.points.values()]
    if "arm/links" in data.arm and len(data.arm["arm/links"][0]):
        pts += [s[:, :2] for i in _poses(len(data.arm["arm/links"][0])) for s in arm_at(data, "arm/links", i)]
    if not pts:
        return
    allp = np.concatenate(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    half = 0.5 * float(np.max(hi - lo)) * 1.1 + 0.02  # a square around it all
    mid = 0.5 * (lo + hi)
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)


def _fault_lines(ax, data: RunData) -> None:
    for t, _lv, _text in [e for e in data.events + data.errors if e[1].upper() == "ERROR"]:
        ax.axvline(t, color=OBST, lw=1.0, alpha=0.7)


def draw_joints(axes: list, data: RunData, units: dict[str, str]) -> None:
    """One axis per joint: the board's set point and the measured value over board time."""
    for ax, name in zip(axes, data.joint_names):
        series = data.joints.get(name, {})
        if "target" in series:
            ax.plot(*series["target"], color=PLAN, lw=1.4, ls="--", label="set point")
        if "q" in series:
            ax.plot(*series["q"], color=TRACE, lw=1.4, label="measured")
        _fault_lines(ax, data)
        ax.set_ylabel(f"{name}\n({units.get(name, 'rad')})")
        ax.grid(True, alpha=0.3)
    if axes and data.joint_names:
        axes[0].legend(loc="upper right", fontsize=BASE_FONT - 2, ncol=2, framealpha=0.85)
        axes[0].set_title("joints: set point vs measured (red lines: ERROR events)")


def draw_board(axes: list, data: RunData, groups: dict[str, list[str]]) -> None:
    for ax, (view, paths) in zip(axes, groups.items()):
        for path in paths:
            ax.plot(*data.series[path], lw=1.2, label=path)
        _fault_lines(ax, data)
        ax.set_ylabel(view)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=BASE_FONT - 3, ncol=min(4, len(paths)), framealpha=0.85)


def _text_panel(ax, title: str, lines: list[tuple[str, str]], colors: dict[str, str]) -> None:
    ax.axis("off")
    ax.set_title(title, loc="left")
    n = max(len(lines), 1)
    step = min(1.0 / n, 0.055)
    for i, (kind, text) in enumerate(lines):
        ax.text(0.0, 1.0 - (i + 0.5) * step, text, family="monospace", fontsize=BASE_FONT - 1.5,
                color=colors.get(kind, "#222222"), va="center", ha="left", transform=ax.transAxes, clip_on=True)


def _cut(text: str, width: int) -> str:
    """One line of the picture's text at most `width` characters (the HTML page has it whole)."""
    return text if len(text) <= width else text[: max(1, width - 3)] + "..."


def figure(data: RunData, doc: dict[str, Any]):
    """The report's figure (module docstring) for the recording and its numbers (numbers.numbers)."""
    plt = _pyplot()
    plt.rcParams.update({"font.size": BASE_FONT, "axes.titlesize": BASE_FONT + 1, "axes.labelsize": BASE_FONT})
    groups = board_groups(data)
    plots = max(1, len(data.joint_names) + len(groups))
    rows = summary_rows(doc)
    logs = log_lines(data)
    lw = min(50, max((len(a) for a, _b in rows), default=20))
    top_h = max(7.0, 1.5 * plots)
    text_h = 0.24 * max(len(rows), len(logs), 6) + 0.8
    fig = plt.figure(figsize=(17, top_h + text_h + 1.2), layout="constrained")
    outer = fig.add_gridspec(2, 1, height_ratios=[top_h, text_h])
    top = outer[0].subgridspec(1, 2, width_ratios=[1.05, 1])
    ax_ws = fig.add_subplot(top[0])
    right = top[1].subgridspec(plots, 1)
    axes = [fig.add_subplot(right[0])]
    axes += [fig.add_subplot(right[i], sharex=axes[0]) for i in range(1, plots)]
    draw_workspace(ax_ws, data)
    units = {name: j["unit"] for name, j in doc["joints"].items()}
    draw_joints(axes[: len(data.joint_names)], data, units)
    draw_board(axes[len(data.joint_names):], data, groups)
    for ax in axes[:-1]:
        ax.tick_params(labelbottom=False)
    axes[-1].set_xlabel("board time (s)")
    if not data.joint_names:
        axes[0].text(0.5, 0.5, "no telemetry in this recording", ha="center", va="center", transform=axes[0].transAxes)
    bottom = outer[1].subgridspec(1, 2, width_ratios=[1.05, 1])
    table = [("row", f"{a:<{lw}}  {_cut(b, 98 - lw)}") for a, b in rows]
    _text_panel(fig.add_subplot(bottom[0]), "numbers" + ("" if doc["summary"] else " (no run summary in the recording)"),
                table, {})
    logs = [(lv, _cut(text, 92)) for lv, text in logs]
    _text_panel(fig.add_subplot(bottom[1]), f"events and errors ({doc['events']} + {doc['errors']} lines)", logs,
                {"ERROR": OBST, "WARN": "#b25e00"})
    from pathlib import Path

    title = f"run of {Path(doc.get('plan') or '(plan unknown)').name} - {doc.get('robot') or 'robot unknown'}"
    if doc.get("status"):
        title += f" - {_cut(doc['status'], 90)}"
    sub = str(data.path.name)
    if doc["missing"]:
        sub += "   |   not in this recording: " + "; ".join(m.split(":")[0] for m in doc["missing"])
    fig.suptitle(f"{title}\n{sub}", fontsize=BASE_FONT + 3)
    return fig


def save_png(fig, path) -> None:
    fig.savefig(path, dpi=110)


def png_bytes(fig) -> bytes:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()
