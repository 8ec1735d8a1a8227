"""Rerun recording of a run: telemetry, events, the arm and the plan (rerun-sdk 0.41).

Entity paths (timeline `board_time`, a duration in s from the board's clock):

    joints/<joint>/q          measured position (rad)          Scalars
    joints/<joint>/target     the board's set point (rad)      Scalars
    joints/<joint>/error      target - q (rad)                 Scalars
    joints/<joint>/effort     output, [-1, 1]                  Scalars
    board/done                last completed waypoint id       Scalars
    arm/links                 the measured arm, base to tip    LineStrips2D (3D)
    arm/target                the arm at the set point         LineStrips2D (3D)
    arm/tip                   measured end effector            Points2D (3D)
    plan/path                 planned end-effector path        LineStrips2D (3D), static
    plan/waypoints            planned end effector per waypoint Points2D (3D), static
    trace/tip                 the whole measured tip trace     LineStrips2D (3D), static, at close
    world/obstacles           a plan's obstacles (MASR, soft)  LineStrips2D, static
    plan/planned_tip          a soft plan's whole planned tip  LineStrips2D, static (Recording.layers,
                              path (the planner's nodes)        plans/soft.py)
    plan/shapes               the planned arm at each pose     LineStrips2D, static (the same)
    drawing/target            a drawing plan's pen-down strokes LineStrips2D, static (plans with `pen`)
    drawing/trace             the measured tip while the pen is LineStrips2D, the trace so far at each
                              down (the active segment's flag)  flush (plans with `pen`)
    ma/*, pump/*              a board's own columns (the MA's  Scalars, per the board kind's
                              link, speed; the pump's syringe   telemetry.layout.BOARD_COLUMNS
                              positions, end-stop bits)
    events                    board events, state changes      TextLog
    errors                    link errors, refusals, resyncs   TextLog
    plan/info                 the plan's source, robot, size   TextDocument, static
    run/summary               the run's summary as JSON (docs/ TextDocument, static, logged as the
                              formats.md §3, `--json`'s)        run ends (`Recording.summary`)

Any robot of the robot interface (robots/base.py) is drawn the same way: the
arm is `robot.joint_points(q)` (one strip per sample), the tip is
`robot.ee_point(q)` (a MASR's MA, a chain's last frame), in 2-D or, for a
spatial chain (`draw_dim` 3), as the 3-D archetypes. `joints/<joint>` are the
robot's coordinate names (a MASR's d is in m).

Every recording opens in a layout made for it (a Rerun blueprint saved as the
file's default, `telemetry.layout`): a plan with pen flags (a drawing, draw/)
gets the `drawing/` entities and the drawing canvas beside the joint plots;
any other run gets the arm view (the arm, its set point, the plan's path, the
tip trace) over the event and error logs, beside per-joint grids of position
vs set point, error and effort. A caller with entities of its own passes its
layout (`layout=`, e.g. `telemetry.layout.run_layout(robot, spatial, views)`).
The pen state of a sample is the flag of the plan segment the executor says
is active (`telemetry(..., active=i)`).

Telemetry is buffered and sent in columns (`send_columns`) every `flush_every`
samples, so recording costs little time in the executor's loop; events and
errors are logged at once. Each Recording owns a non-global RecordingStream,
so several can be open at the same time (tests do).
"""
from __future__ import annotations

import json
import uuid
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr

from armbridge.errors import ArmbridgeError
from armbridge.telemetry.layout import BOARD_COLUMNS, drawing_layout, run_layout

APPLICATION_ID = "armbridge"
TIMELINE = "board_time"
SUMMARY_ENTITY = "run/summary"  # the run's summary, JSON text (Recording.summary; `armbridge report` reads it)

_LEVEL = {"info": rr.TextLogLevel.INFO, "warn": rr.TextLogLevel.WARN, "error": rr.TextLogLevel.ERROR,
          "debug": rr.TextLogLevel.DEBUG}


def default_rrd_path(plan_stem: str, runs_dir: Path | str = "runs", now: datetime | None = None) -> Path:
    """runs/<YYYYmmdd-HHMMSS>-<plan-stem>.rrd"""
    stamp = (now or datetime.now()).strftime("%Y%m%d-%H%M%S")
    return Path(runs_dir) / f"{stamp}-{plan_stem}.rrd"


def _short(value: Any, limit: int = 300) -> str:
    """A provenance value as one line of the plan's text, cut at `limit` characters (a soft plan
    carries its whole planned path there)."""
    text = str(value)
    return text if len(text) <= limit else text[:limit] + f"... ({len(text)} characters)"


class Recording:
    """One .rrd file for one run. Use as a context manager, or call close(). layout: the
    blueprint the file opens in (default: the drawing's or the run's, `telemetry.layout`)."""

    def __init__(self, path: Path | str, robot, plan=None, *, flush_every: int = 50,
                 recording_id: str | None = None, layout: Any = None) -> None:
        self.path = Path(path)
        self.robot = robot
        self.plan = plan
        self.flush_every = int(flush_every)
        self.joint_names = list(robot.joint_names)
        self._dim = int(robot.draw_dim)
        self._strips = rr.LineStrips2D if self._dim == 2 else rr.LineStrips3D
        self._points = rr.Points2D if self._dim == 2 else rr.Points3D
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ArmbridgeError(f"{self.path.parent}: cannot create the recording folder: {exc.strerror}") from None
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id or str(uuid.uuid4()))
        self._pen = None if plan is None or plan.pen is None or self._dim != 2 else np.asarray(plan.pen)
        if layout is None:
            layout = drawing_layout(self.joint_names) if self._pen is not None else run_layout(robot)
        try:
            self.rec.save(str(self.path), default_blueprint=layout)
        except Exception as exc:  # noqa: BLE001 - rerun raises plain exceptions for I/O
            raise ArmbridgeError(f"{self.path}: cannot write the recording: {exc}") from None
        self._closed = False
        self._buf: list[tuple[float, np.ndarray, np.ndarray, np.ndarray, float, int]] = []
        self._tip_trace: list[np.ndarray] = []
        self._down: list[np.ndarray] = []  # per flush: pen down at each sample (drawing plans)
        self._t = 0.0  # latest board time seen: lines without their own time go there
        self.samples = 0
        self.events = 0
        self.errors = 0
        self._static()

    # ------------------------------------------------------------------ static
    def _static(self) -> None:
        rec = self.rec
        for name in self.joint_names:
            for series in ("q", "target", "error", "effort"):
                rec.log(f"joints/{name}/{series}", rr.SeriesLines(names=f"{name} {series}"), static=True)
        rec.log("board/done", rr.SeriesLines(names="done"), static=True)
        reach = float(self.robot.reach)
        # The workspace circle (in the base x-y plane) as a light reference.
        a = np.linspace(0, 2 * np.pi, 97)
        circle = np.c_[reach * np.cos(a), reach * np.sin(a), np.zeros_like(a)][:, : self._dim]
        rec.log("workspace", self._strips([circle], colors=[(90, 90, 90)], radii=0.0005), static=True)
        if self.plan is not None:
            tips = np.asarray(self.plan.ee_path())
            rec.log("plan/path", self._strips([tips], colors=[(80, 160, 255)], radii=0.001), static=True)
            rec.log("plan/waypoints", self._points(tips, colors=[(80, 160, 255)], radii=0.0015), static=True)
            prov = self.plan.provenance or {}
            text = [f"plan: {self.plan.source or '(in memory)'}", f"robot: {self.robot.name}",
                    f"waypoints: {self.plan.k}, planned duration {self.plan.total_duration:.3f} s"]
            text += [f"provenance.{k}: {_short(v)}" for k, v in prov.items()]
            rec.log("plan/info", rr.TextDocument("\n".join(text)), static=True)
        if self._pen is not None:
            from armbridge.plans.drawing import pen_strips

            rec.log("drawing/target", rr.LineStrips2D(pen_strips(tips[:, :2], self._pen), colors=[(60, 60, 200)],
                                                      radii=0.0006), static=True)

    # ------------------------------------------------------------------ samples
    def telemetry(self, t: float, q, target, effort, done: int | None = None, active: int | None = None) -> None:
        """One telemetry sample at board time t (s, unwrapped); active: the plan index of
        the segment being run (a drawing's pen state), None when unknown (pen up)."""
        if self._closed:
            return
        self._t = max(self._t, float(t))
        self._buf.append((float(t), np.asarray(q, float).copy(), np.asarray(target, float).copy(),
                          np.asarray(effort, float).copy(), np.nan if done is None else float(done),
                          -1 if active is None else int(active)))
        self.samples += 1
        if len(self._buf) >= self.flush_every:
            self.flush()

    def obstacles(self, polygons) -> None:
        """The environment's obstacles, (k, 2) vertex arrays in m, as closed outlines
        (static, `world/obstacles`); the run layout of a MASR plan shows them with the arm."""
        rings = [np.vstack([np.asarray(p, float), np.asarray(p, float)[:1]]) for p in polygons]
        if rings and self._dim == 2:
            self.rec.log("world/obstacles", rr.LineStrips2D(rings, colors=[(200, 60, 60)], radii=0.001), static=True)

    def layers(self, layers: dict) -> None:
        """Static line strips in the arm's space, entity path -> (strips, colour): what a plan brings
        to draw beside the arm (a soft plan's obstacles, planned tip path and poses, in the arm's base
        frame: plans/soft.py recording_layers)."""
        for path, (strips, color) in layers.items():
            strips = [np.asarray(s, float)[:, : self._dim] for s in strips]
            if strips:
                self.rec.log(path, self._strips(strips, colors=[color], radii=0.001), static=True)

    def series(self, t: float, values: dict[str, float]) -> None:
        """A board's own scalar columns at board time t (the MA's speed, link, d_link),
        one time series per entity path."""
        if self._closed:
            return
        self._t = max(self._t, float(t))
        self.rec.set_time(TIMELINE, duration=float(t))
        for path, v in values.items():
            self.rec.log(path, rr.Scalars(float(v)))

    def board(self, t: float, kind: str, extra) -> None:
        """A telemetry sample's own columns of a board of this kind (Telemetry.extra), each
        scaled and logged at its path of BOARD_COLUMNS; a kind without columns logs nothing,
        and columns beyond the table's are not logged."""
        cols = BOARD_COLUMNS.get(kind, ())
        if cols and extra:
            self.series(t, {path: scale * float(v) for (path, scale, _view), v in zip(cols, extra)})

    def event(self, t: float | None, text: str, level: str = "info") -> None:
        """A board event (or a state change) as a line of the `events` log.
        t None: at the latest board time seen."""
        if self._closed:
            return
        self._text("events", t, text, level)
        self.events += 1

    def error(self, t: float | None, text: str, level: str = "warn") -> None:
        """A link error, a refusal, a resync: a line of the `errors` log."""
        if self._closed:
            return
        self._text("errors", t, text, level)
        self.errors += 1

    def _text(self, path: str, t: float | None, text: str, level: str) -> None:
        if t is None:
            t = self._t
        else:
            self._t = max(self._t, float(t))
        self.rec.set_time(TIMELINE, duration=float(t))
        self.rec.log(path, rr.TextLog(text, level=_LEVEL.get(level, rr.TextLogLevel.INFO)))

    def summary(self, doc: dict) -> None:
        """The run's summary (`Summary.to_dict()`, the `--json` document) as JSON text at
        `run/summary`, static: what `armbridge report` shows beside the telemetry. Logged
        once, as the run ends; nothing after close."""
        if self._closed:
            return
        text = json.dumps(doc, indent=2, default=float)
        self.rec.log(SUMMARY_ENTITY, rr.TextDocument(text, media_type=rr.MediaType.TEXT), static=True)

    def flush(self) -> None:
        """Send the buffered telemetry as columns."""
        if not self._buf:
            return
        buf, self._buf = self._buf, []
        t = np.array([b[0] for b in buf])
        q = np.stack([b[1] for b in buf])
        tg = np.stack([b[2] for b in buf])
        u = np.stack([b[3] for b in buf])
        done = np.array([b[4] for b in buf])
        idx = [rr.TimeColumn(TIMELINE, duration=t)]
        send = self.rec.send_columns
        for j, name in enumerate(self.joint_names):
            send(f"joints/{name}/q", indexes=idx, columns=rr.Scalars.columns(scalars=q[:, j]))
            send(f"joints/{name}/target", indexes=idx, columns=rr.Scalars.columns(scalars=tg[:, j]))
            send(f"joints/{name}/error", indexes=idx, columns=rr.Scalars.columns(scalars=tg[:, j] - q[:, j]))
            send(f"joints/{name}/effort", indexes=idx, columns=rr.Scalars.columns(scalars=u[:, j]))
        have = ~np.isnan(done)
        if have.any():
            send("board/done", indexes=[rr.TimeColumn(TIMELINE, duration=t[have])],
                 columns=rr.Scalars.columns(scalars=done[have]))
        arm = np.asarray(self.robot.joint_points(q))  # (m, points, draw_dim)
        arm_t = np.asarray(self.robot.joint_points(tg))
        tip = np.asarray(self.robot.ee_point(q))
        send("arm/links", indexes=idx, columns=self._strips.columns(strips=list(arm)))
        send("arm/target", indexes=idx, columns=self._strips.columns(strips=list(arm_t)))
        send("arm/tip", indexes=idx, columns=self._points.columns(positions=tip))
        self._tip_trace.append(tip)
        if self._pen is not None:
            from armbridge.plans.drawing import trace_strips

            a = np.array([b[5] for b in buf])
            ok = (a >= 0) & (a < len(self._pen))
            down = np.zeros(len(a), bool)
            down[ok] = self._pen[a[ok]] == 1
            self._down.append(down)
            strips = trace_strips(np.concatenate(self._tip_trace), np.concatenate(self._down))
            if strips:
                self.rec.set_time(TIMELINE, duration=float(t[-1]))
                self.rec.log("drawing/trace", rr.LineStrips2D(strips, colors=[(220, 30, 30)], radii=0.0006))

    def close(self) -> Path:
        """Flush, log the measured tip trace and close the file. Idempotent."""
        if self._closed:
            return self.path
        try:
            self.flush()
            if self._tip_trace:
                trace = np.concatenate(self._tip_trace)
                self.rec.log("trace/tip", self._strips([trace], colors=[(255, 140, 0)], radii=0.0008),
                             static=True)
            self.rec.flush()
        finally:
            self._closed = True
            self.rec.disconnect()
        return self.path

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

