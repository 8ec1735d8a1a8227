"""`armbridge draw ... --port`: the paper's "ROBOTICS" drawn on the emulated arm end to end, the
drawing's recording read back, and the drawing-error function on worked cases."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from rerun.chunk import RrdReader
from typer.testing import CliRunner

from armbridge.cli import build_app
from armbridge.draw.sources import characters
from armbridge.plans.drawing import drawing_error, pen_strips, point_polyline_distance, trace_strips
from armbridge.emulator.plant import PlantParams
from armbridge.errors import ArmbridgeError
from armbridge.plans.format import load_plan

RATE_HZ = 50
PERIOD_S = 0.010  # the firmware's control period (emulator/board.py: cfg PERIOD_MS, default 10)


# ---------------------------------------------------------------- pure parts

def test_point_polyline_distance_worked_cases():
    seg = [np.array([[0.0, 0.0], [2.0, 0.0]])]
    pts = np.array([[1.0, 1.0], [-1.0, 0.0], [3.0, 4.0], [0.5, -0.25]])
    # above the middle: 1; before the start: 1 to (0,0); past the end: |(1,4)|; below: 0.25
    assert point_polyline_distance(pts, seg) == pytest.approx([1.0, 1.0, math.hypot(1, 4), 0.25])
    # the nearest of several strips; a one-point strip is a point
    two = seg + [np.array([[1.0, 0.9]])]
    assert point_polyline_distance(pts[:1], two) == pytest.approx([0.1])
    assert np.isinf(point_polyline_distance(pts, [])).all()


def test_drawing_error_both_ways():
    target = [np.array([[0.0, 0.0], [0.010, 0.0]])]  # a 10 mm stroke
    # A trace 0.2 mm off the stroke, drawing only its first half.
    trace = [np.array([[0.0, 0.0002], [0.005, 0.0002]])]
    e = drawing_error(target, trace, step=0.001)
    assert e.trace_mean == pytest.approx(0.0002) and e.trace_max == pytest.approx(0.0002)
    # Target points 0, 1, ..., 10 mm: 0..5 are 0.2 mm from the trace, 6..10 are hypot(k - 5 mm, 0.2 mm).
    d = [0.0002] * 6 + [math.hypot(k * 0.001, 0.0002) for k in range(1, 6)]
    assert e.target_mean == pytest.approx(np.mean(d)) and e.target_max == pytest.approx(d[-1])
    assert e.to_dict()["target_max_mm"] == pytest.approx(d[-1] * 1000, abs=1e-4)
    exact = drawing_error(target, target)
    assert exact.trace_max == 0 and exact.target_max == pytest.approx(0, abs=1e-12)
    empty = drawing_error(target, [])
    assert math.isnan(empty.trace_mean) and empty.to_dict()["trace_mean_mm"] is None
    assert math.isnan(empty.target_max)  # no trace: no distance is defined (the summary shows -)


def test_pen_and_trace_strips():
    pts = np.arange(12.0).reshape(6, 2)
    s = pen_strips(pts, [0, 1, 1, 0, 0, 1])  # strips start at the point before their first pen-down move
    assert [x.tolist() for x in s] == [pts[0:3].tolist(), pts[4:6].tolist()]
    t = trace_strips(pts, [1, 1, 0, 1, 0, 1])
    assert [x.tolist() for x in t] == [pts[0:2].tolist(), pts[3:4].tolist(), pts[5:6].tolist()]
    assert trace_strips(pts, np.zeros(6)) == []
    assert characters("I O\nA") == 3


# ---------------------------------------------------------------- end to end

def drawing_bounds(plan) -> tuple[float, float]:
    """(trace from strokes, strokes from trace) bounds in m, from the plant (PlantParams)
    and the plan, as test_executor.py's tracking_bound but in the drawing's plane:

    * Lag: with the feed-forward the servo follows its set point through a first-order
      lag tau, so a measured pose is a weighted average of past set points with a mean
      delay tau; the samples add one control period (q read before the tick advanced
      the set point), the zero-order hold one more, the plan-to-set-point anchor one
      more: a mean delay of tau + 3T. Along a stroke that stays on the stroke; where
      the pen comes down, the pose averages in the pen-up travel before it, whose
      distance from the stroke grows at the pen speed v, so (distance to a segment
      being convex) the trace is within v (tau + 3T) of the stroke.
    * The average is taken in joint space: the tip of an average pose is off the average
      of the tips by at most lever * (peak joint speed * window)^2 / 2 (the window: 98 %
      of the lag kernel, 4 tau, plus 3T); lever = sum over joints of |tip - joint|.
    * The acceleration limit: lever * dv^2 / (2 a_max), dv the largest change of a joint
      speed between two segments; potentiometer noise (4 sigma) and an ADC quantum per
      joint: lever * (4 sigma + span / 4095).
    * Between waypoints the plan moves linearly in joint space, so its own tip path bows
      off the straight strokes: that chord error is measured on the plan.
    * Strokes from trace: the trace is sampled at RATE_HZ, so a target point may lie a
      sample step of pen travel, v / RATE_HZ, further from the trace's vertices.
    """
    p = PlantParams()
    robot = plan.robot
    v = plan.provenance["drawing"]["speed"]
    speeds = np.diff(plan.q, axis=0) / plan.durations[1:, None]
    dv = float(np.abs(np.diff(np.vstack([np.zeros(plan.n), speeds]), axis=0)).max())
    peak_v = float(np.abs(speeds).max())
    tips = robot.joint_points(plan.q)  # (k, joints + 1, 2)
    lever = float(np.linalg.norm(tips[:, -1:, :] - tips[:, :-1, :], axis=2).sum(axis=1).max())
    target = pen_strips(plan.ee_path(), plan.pen)
    f = np.linspace(0, 1, 9)[1:-1]
    between = plan.q[:-1, None, :] + f[None, :, None] * np.diff(plan.q, axis=0)[:, None, :]
    chord = float(point_polyline_distance(robot.ee_point(between[plan.pen[1:] == 1].reshape(-1, plan.n)),
                                          target).max())
    quantum = (math.pi + 2 * p.stop_margin) / ((1 << p.adc_bits) - 1)
    fwd = (chord + v * (p.tau + 3 * PERIOD_S) + 0.5 * lever * (peak_v * (4 * p.tau + 3 * PERIOD_S)) ** 2
           + lever * (dv**2 / (2 * p.a_max) + 4 * p.sigma + quantum))
    return fwd, fwd + v / RATE_HZ


def test_draw_robotics_on_the_emulated_arm(tmp_path):
    """The paper's sample 9, "ROBOTICS", drawn end to end (issue 10 §6)."""
    out, rrd, js = tmp_path / "robotics.json", tmp_path / "robotics.rrd", tmp_path / "sum.json"
    # --travel-speed as --speed: drawing_bounds takes its peak joint speed over the whole plan
    r = CliRunner().invoke(build_app(), ["draw", "--sample", "text-robotics", "--speed", "0.03", "--travel-speed", "0.03",
                                         "--out", str(out),
                                         "--port", "emu:esp32?speed=0", "--rrd", str(rrd), "--json", str(js),
                                         "--rate", str(RATE_HZ), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "drawing error" in r.output and "time per character" in r.output
    s = json.loads(js.read_text())
    assert s["completed"] and s["rrd"] == str(rrd)
    d = s["drawing"]
    plan = load_plan(out)
    fwd, back = drawing_bounds(plan)
    assert 1e-3 < fwd < 8e-3, fwd  # the bound itself is a useful one (millimetres)
    assert d["trace_points"] > 100
    assert d["trace_max_mm"] <= fwd * 1000 and d["target_max_mm"] <= back * 1000, (d, fwd, back)
    assert d["trace_mean_mm"] <= d["trace_max_mm"] and d["target_mean_mm"] <= d["target_max_mm"]
    assert d["characters"] == 8 and d["s_per_character"] == pytest.approx(s["measured_duration_s"] / 8, abs=2e-3)

    # The recording: the target strokes (static) and the pen trace over time, and a layout.
    strips: dict[str, list] = {}
    reader = RrdReader(rrd)
    for chunk in reader.stream():
        if chunk.entity_path in ("/drawing/target", "/drawing/trace"):
            rb = chunk.to_record_batch()
            col = [c for c in rb.schema.names if c.endswith("LineStrips2D:strips")]
            strips.setdefault(chunk.entity_path, []).extend(rb.column(col[0]).to_pylist())
            if chunk.entity_path == "/drawing/trace":
                assert not chunk.is_static and "board_time" in chunk.timeline_names
    target = strips["/drawing/target"][-1]
    assert len(target) == len(pen_strips(plan.ee_path(), plan.pen)) == 10  # the strokes of ROBOTICS
    traces = strips["/drawing/trace"]
    assert len(traces) > 3  # logged as it grew
    last = [np.array(x) for x in traces[-1]]
    assert sum(len(x) for x in last) == d["trace_points"]
    assert point_polyline_distance(np.vstack(last), [np.array(x) for x in target]).max() <= fwd

    # The layout saved as the file's default blueprint: a 2-D canvas and one time-series view per joint.
    (store,) = reader.blueprints()
    views: dict[str, str] = {}
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        if "ViewBlueprint:class_identifier" in rb.schema.names:
            kind = rb.column("ViewBlueprint:class_identifier").to_pylist()[0][0]
            views[rb.column("ViewBlueprint:display_name").to_pylist()[0][0]] = kind
    assert views == {"canvas": "2D", **{n: "TimeSeries" for n in plan.robot.joint_names}}, views


def test_run_options_need_a_port(tmp_path):
    out = tmp_path / "p.json"
    r = CliRunner().invoke(build_app(), ["draw", "IO", "--out", str(out), "--rrd", str(tmp_path / "r.rrd")])
    assert isinstance(r.exception, ArmbridgeError) and "need --port" in str(r.exception)  # main(): exit 2
    assert not out.exists()
