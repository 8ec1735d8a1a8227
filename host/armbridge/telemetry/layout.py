"""The layouts a run's recording opens in (Rerun blueprints, rerun-sdk 0.41), over the
entities of `telemetry.recording`.

Two, built from the same parts (`arm_view`, `joint_plots`, `logs`):

* `drawing_layout`: a drawing plan (one with pen flags): the canvas (target strokes,
  pen trace, the arm) beside one plot per joint (measured and set point).
* `run_layout`: every other plan (joint plans of any robot: arm3r, a MASR, a DH
  chain; the demos): the arm (2-D or, for a spatial chain, 3-D: the measured arm,
  its set point, the plan's path, the tip trace) over the board's logs (events,
  errors, the plan's text, the run's summary, the done waypoint), beside a grid of joint plots, one
  per joint, in three tabs: position (measured and set point, and anything else a
  caller logs under `joints/<joint>/`, e.g. the fault-tolerant demo's artificial
  limits), error (set point - measured) and effort. A caller with entities of its
  own adds them to the arm view (`spatial`) and as views of their own (`views`).

A board's own telemetry columns (the T line's after the 3n joint columns,
`Telemetry.extra`) are named by the board kind in `BOARD_COLUMNS`: entity path,
scale from the wire's integer, and the view that plots it (`board_views`); the
recording logs them (`Recording.board`) and the run layout shows their views.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence

import rerun.blueprint as rrb

# Entities of `telemetry.recording` drawn in the arm's space (see its docstring).
ARM_ENTITIES = ("arm/**", "plan/path", "plan/waypoints", "trace/**", "workspace")


#: board kind (its firmware name) -> its own T columns in order: (entity path, scale from the
#: wire's integer to the logged value, the name of the view that plots it). docs/protocol.md §4.
BOARD_COLUMNS: dict[str, tuple[tuple[str, float, str], ...]] = {
    # the MASR actuator: the link it is on, its distance along it (mm -> m), its speed (mm/s -> m/s)
    "masr_ma": (("ma/link", 1.0, "MA link"), ("ma/d_link", 1e-3, "MA link"), ("ma/speed", 1e-3, "MA speed")),
    # the syringe-pump board: syringe positions (per-mille of travel -> 0..1) and the end-stop bits
    # (bit 2k: pump k+1 retracted, 2k+1: extended), docs/pump.md
    "arduino_pump": (("pump/syringe1", 1e-3, "syringe positions"), ("pump/syringe2", 1e-3, "syringe positions"),
                     ("pump/syringe3", 1e-3, "syringe positions"), ("pump/end_stops", 1.0, "end stops")),
}


def board_views(kind: str) -> list[rrb.View]:
    """One time-series view per view name of the board kind's own columns (none for a
    board without any), in the order of BOARD_COLUMNS."""
    views: dict[str, list[str]] = {}
    for path, _scale, view in BOARD_COLUMNS.get(kind, ()):
        views.setdefault(view, []).append(path)
    return [rrb.TimeSeriesView(origin=paths[0].split("/")[0], contents=paths, name=name)
            for name, paths in views.items()]


def arm_view(dim: int, contents: Iterable[str], name: str) -> rrb.View:
    """A spatial view of the whole recording's space showing `contents`: 2-D or 3-D by the robot's draw_dim."""
    view = rrb.Spatial2DView if dim == 2 else rrb.Spatial3DView
    return view(origin="/", contents=list(contents), name=name)


def joint_plots(joint_names: Sequence[str], series: str | None = None, suffix: str = "") -> list[rrb.View]:
    """One time-series view per joint over board time: `joints/<joint>/<series>`, or (series None)
    every series of the joint but its error and effort (the measured q and the set point)."""
    def contents(n: str) -> list[str]:
        if series is not None:
            return [f"joints/{n}/{series}"]
        return [f"+ joints/{n}/**", f"- joints/{n}/error", f"- joints/{n}/effort"]

    return [rrb.TimeSeriesView(origin=f"joints/{n}", contents=contents(n), name=f"{n}{suffix}") for n in joint_names]


def logs() -> rrb.Tabs:
    """The board's logs: events and errors (TextLog), the plan's text, the run's summary (JSON),
    the last done waypoint."""
    return rrb.Tabs(rrb.TextLogView(origin="events", name="events"), rrb.TextLogView(origin="errors", name="errors"),
                    rrb.TextDocumentView(origin="plan/info", name="plan"),
                    rrb.TextDocumentView(origin="run/summary", name="summary"),
                    rrb.TimeSeriesView(origin="board", contents=["board/done"], name="done waypoint"))


def drawing_layout(joint_names: Sequence[str]) -> rrb.Blueprint:
    """A drawing's recording: the canvas (strokes, trace, arm) beside one plot per joint."""
    return rrb.Blueprint(
        rrb.Horizontal(
            arm_view(2, ["drawing/**", "arm/**", "workspace"], "canvas"),
            rrb.Vertical(*joint_plots(joint_names)),
            column_shares=[3, 2],
        ),
    )


def run_layout(robot, spatial: Iterable[str] = (), views: Sequence[rrb.View] = ()) -> rrb.Blueprint:
    """Any other run's recording (module docstring); `spatial`: more entities for the arm view,
    `views`: more views, in a row under it."""
    names = list(robot.joint_names)
    cols = min(3, len(names))
    left: list[rrb.View | rrb.Container] = [arm_view(int(robot.draw_dim), [*ARM_ENTITIES, *spatial], "arm")]
    if views:
        left.append(rrb.Horizontal(*views))
    left.append(logs())
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(*left, row_shares=[3, *([2] if views else []), 1]),
            rrb.Tabs(rrb.Grid(*joint_plots(names), grid_columns=cols, name="position"),
                     rrb.Grid(*joint_plots(names, "error", " error"), grid_columns=cols, name="error"),
                     rrb.Grid(*joint_plots(names, "effort", " effort"), grid_columns=cols, name="effort")),
            column_shares=[1, 1],
        ),
    )
