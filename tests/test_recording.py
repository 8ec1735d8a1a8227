"""The Rerun recording (telemetry/recording.py) read back with rerun's own reader, and `armbridge view`."""
from __future__ import annotations

import math
import uuid
from datetime import datetime
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader

from armbridge.errors import ArmbridgeError
from armbridge.plans.format import make_plan
from armbridge.robots import ARM3R, get_robot
from armbridge.telemetry import command as view
from armbridge.telemetry.layout import run_layout
from armbridge.telemetry.recording import Recording, default_rrd_path

MID = np.array([math.pi / 2, -math.pi / 2, 0.0])


def read(path: Path) -> dict[str, dict]:
    """entity path -> {"rows", "static_rows", "timelines", "columns": {name: [values...]}}"""
    out: dict[str, dict] = {}
    for chunk in RrdReader(path).stream():
        e = out.setdefault(chunk.entity_path, {"rows": 0, "static_rows": 0, "timelines": set(), "columns": {}})
        e["static_rows" if chunk.is_static else "rows"] += chunk.num_rows
        e["timelines"].update(chunk.timeline_names)
        rb = chunk.to_record_batch()
        for name in rb.schema.names:
            col = rb.column(name)
            if pa.types.is_duration(col.type) or pa.types.is_timestamp(col.type):  # time columns: ns as int
                col = col.cast(pa.int64())
            e["columns"].setdefault(name, []).extend(col.to_pylist())
    return out


def layout(path: Path) -> dict:
    """The file's one blueprint read back as a tree: {"kind", "name", "children"} per container,
    {"view", "name", "origin", "contents"} per view, from the root container of the viewport."""
    reader = RrdReader(path)
    (store,) = reader.blueprints()
    parts: dict[str, dict] = {}
    root = None

    def one(rb, col):
        return rb.column(col).to_pylist()[0] if col in rb.schema.names else None

    for chunk in reader.stream(store=store):
        rb, ent = chunk.to_record_batch(), chunk.entity_path.lstrip("/")
        if ent == "viewport":
            root = f"container/{uuid.UUID(bytes=bytes(one(rb, 'ViewportBlueprint:root_container')[0]))}"
        elif ent.endswith("/ViewContents"):
            parts.setdefault(ent.rsplit("/", 1)[0], {})["contents"] = one(rb, "ViewContents:query")
        elif ent.startswith("view/"):
            parts.setdefault(ent, {}).update(view=one(rb, "ViewBlueprint:class_identifier")[0],
                                             name=one(rb, "ViewBlueprint:display_name")[0],
                                             origin=one(rb, "ViewBlueprint:space_origin")[0])
        elif ent.startswith("container/"):
            kind = {1: "Tabs", 2: "Horizontal", 3: "Vertical", 4: "Grid"}[one(rb, "ContainerBlueprint:container_kind")[0]]
            name = one(rb, "ContainerBlueprint:display_name")
            parts.setdefault(ent, {}).update(kind=kind, name=name and name[0],
                                             children=one(rb, "ContainerBlueprint:contents"))

    def tree(key: str) -> dict:
        node = dict(parts[key])
        if "children" in node:
            node["children"] = [tree(c) for c in node["children"]]
        return node

    assert root is not None, "no viewport in the blueprint"
    return tree(root)


def names(node: dict) -> list:
    """A layout tree as nested lists of view names (containers as (kind, [children]))."""
    if "view" in node:
        return node["name"]
    return [node["kind"], [names(c) for c in node["children"]]]


def _plan():
    q = MID + np.outer(np.linspace(0, 1, 10), [0.3, -0.2, 0.4])
    return make_plan(ARM3R, q, 0.1, {"tool": "test_recording"})


def test_every_series_and_log_is_recorded(tmp_path):
    plan = _plan()
    path = tmp_path / "runs" / "a.rrd"
    n = 123  # not a multiple of flush_every: the tail is flushed at close
    with Recording(path, ARM3R, plan, flush_every=50) as rec:
        for i in range(n):
            t = 10.0 + 0.02 * i
            q = MID + 0.001 * i
            rec.telemetry(t, q, q + 0.01, [0.1, -0.2, 0.3], done=i // 10 if i >= 10 else None)
        rec.event(10.5, "DONE 3 31")
        rec.event(None, "state IDLE")  # no time of its own: at the latest board time
        rec.error(11.0, "board line dropped: CRC")
    assert rec.samples == n and rec.events == 2 and rec.errors == 1
    data = read(path)

    for name in ARM3R.joint_names:
        for series in ("q", "target", "error", "effort"):
            e = data[f"/joints/{name}/{series}"]
            assert e["rows"] == n and "board_time" in e["timelines"]
    q = np.array([v[0] for v in data["/joints/shoulder/q"]["columns"]["Scalars:scalars"]])
    np.testing.assert_allclose(q, MID[0] + 0.001 * np.arange(n))
    err = np.array([v[0] for v in data["/joints/elbow/error"]["columns"]["Scalars:scalars"]])
    np.testing.assert_allclose(err, 0.01, atol=1e-12)  # target - q
    # board_time is a duration timeline in ns
    bt = np.array(data["/joints/wrist/effort"]["columns"]["board_time"], dtype=float)
    np.testing.assert_allclose(bt / 1e9, 10.0 + 0.02 * np.arange(n), atol=1e-9)
    assert data["/board/done"]["rows"] == n - 10  # samples without a done id are left out

    # The arm as a line strip base -> tip, its set point, and the tip.
    for entity in ("/arm/links", "/arm/target", "/arm/tip"):
        assert data[entity]["rows"] == n
    strip = np.array(data["/arm/links"]["columns"]["LineStrips2D:strips"][0][0])
    np.testing.assert_allclose(strip, ARM3R.joint_points(MID), atol=1e-6)
    # Static: the planned tip path and waypoints, the workspace, the measured trace (at close).
    path_strip = np.array(data["/plan/path"]["columns"]["LineStrips2D:strips"][0][0])
    np.testing.assert_allclose(path_strip, plan.ee_path(), atol=1e-6)
    assert data["/plan/waypoints"]["static_rows"] == 1 and data["/workspace"]["static_rows"] == 1
    trace = np.array(data["/trace/tip"]["columns"]["LineStrips2D:strips"][0][0])
    assert trace.shape == (n, 2)
    assert "test_recording" in data["/plan/info"]["columns"]["TextDocument:text"][0][0]

    ev = [x for row in data["/events"]["columns"]["TextLog:text"] for x in row]
    assert ev == ["DONE 3 31", "state IDLE"]
    ev_t = np.array(data["/events"]["columns"]["board_time"], dtype=float) / 1e9
    assert ev_t[1] == pytest.approx(10.0 + 0.02 * (n - 1))
    er = [x for row in data["/errors"]["columns"]["TextLog:text"] for x in row]
    assert er == ["board line dropped: CRC"]


def test_several_recordings_at_once(tmp_path):
    a = Recording(tmp_path / "a.rrd", ARM3R, None)
    b = Recording(tmp_path / "b.rrd", ARM3R, _plan())
    for i in range(5):
        a.telemetry(i * 0.1, MID, MID, [0, 0, 0])
    b.telemetry(0.0, MID, MID, [0, 0, 0])
    a.close()
    b.close()
    b.close()  # idempotent
    ra, rb = read(tmp_path / "a.rrd"), read(tmp_path / "b.rrd")
    assert ra["/joints/shoulder/q"]["rows"] == 5 and rb["/joints/shoulder/q"]["rows"] == 1
    assert "/plan/path" not in ra and "/plan/path" in rb
    b.telemetry(1.0, MID, MID, [0, 0, 0])  # after close: ignored, no error


def test_default_path_and_unwritable_folder(tmp_path):
    p = default_rrd_path("square", tmp_path / "runs", now=datetime(2025, 3, 4, 5, 6, 7))
    assert p == tmp_path / "runs" / "20250304-050607-square.rrd"
    assert default_rrd_path("x").parent == Path("runs")
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ArmbridgeError, match="cannot create the recording folder"):
        Recording(blocker / "sub" / "x.rrd", ARM3R, None)


def test_view_missing_file(tmp_path):
    with pytest.raises(ArmbridgeError, match=r"nope.rrd: no such recording"):
        view.view_cmd(tmp_path / "nope.rrd")
    with pytest.raises(ArmbridgeError, match="is not a file"):
        view.view_cmd(tmp_path)


def test_view_starts_the_rerun_viewer(tmp_path, monkeypatch):
    rrd = tmp_path / "r.rrd"
    with Recording(rrd, ARM3R, None) as rec:
        rec.telemetry(0.0, MID, MID, [0, 0, 0])
    calls = []

    class Done:
        returncode = 0

    monkeypatch.setattr(view.subprocess, "run", lambda argv, check: calls.append(argv) or Done())
    monkeypatch.setattr(view, "has_display", lambda: True)  # the native viewer where there is a display
    view.view_cmd(rrd, web=False, port=None, bind="127.0.0.1", no_open=False)
    exe = view.rerun_executable()
    assert calls == [[exe, str(rrd)]]
    assert Path(exe).name == "rerun" and Path(exe).is_file()


@pytest.mark.hil
def test_rerun_verifies_the_file(tmp_path):
    """The file, blueprint and all, is a valid .rrd for the rerun CLI itself (`rerun rrd verify`)."""
    import subprocess

    from armbridge.demos.arm3r_ft_log import FtLog

    for name, robot, lay in (("v", ARM3R, None), ("ft", ARM3R, FtLog.layout(ARM3R)),  # a joint plan's, the demo's
                             ("s4", get_robot("spatial4r"), None)):                    # and a 3-D arm's layout
        rrd = tmp_path / f"{name}.rrd"
        q = MID if robot is ARM3R else np.zeros(robot.dof)
        with Recording(rrd, robot, _plan() if robot is ARM3R else None, layout=lay) as rec:
            for i in range(60):
                rec.telemetry(i * 0.02, q, q, np.zeros(robot.dof), done=None)
            rec.event(0.5, "DONE 0 32")
        assert layout(rrd)["kind"] == "Horizontal"
        r = subprocess.run([view.rerun_executable(), "rrd", "verify", str(rrd)], capture_output=True, text=True,
                           timeout=60)
        assert r.returncode == 0, name + ": " + r.stdout + r.stderr


@pytest.mark.parametrize("name", ["masr5", "spatial4r", "planar3r"])
def test_any_robot_goes_plan_file_to_recording(tmp_path, name):
    """A MASR (dof n+1, d in m) and DH chains (3-D and planar) go make_plan -> save
    -> load -> Recording, and the .rrd holds their arm strips from joint_points."""
    from armbridge.plans.format import load_plan, save_plan
    from armbridge.robots import get_robot

    robot = get_robot(name)
    lo, hi = robot.q_min, robot.q_max
    q = lo + (hi - lo) * np.linspace(0.3, 0.6, 8)[:, None]  # inside the limits, slowly
    plan = load_plan(save_plan(make_plan(robot, q, 2.0, {"tool": "test_recording"}), tmp_path / f"{name}.json"))
    assert plan.robot == robot and not plan.inline_robot
    np.testing.assert_array_equal(plan.q, q)
    rrd = tmp_path / f"{name}.rrd"
    n = 7
    with Recording(rrd, plan.robot, plan, flush_every=3) as rec:
        for i in range(n):
            rec.telemetry(0.1 * i, q[i], q[i + 1], np.zeros(robot.dof))
    data = read(rrd)
    kind = "LineStrips2D" if robot.draw_dim == 2 else "LineStrips3D"
    strips = [np.array(row[0]) for row in data["/arm/links"]["columns"][f"{kind}:strips"]]
    assert len(strips) == n
    for i, strip in enumerate(strips):
        np.testing.assert_allclose(strip, robot.joint_points(q[i]), atol=1e-6)
        assert strip.shape == (robot.joint_points(q[i]).shape[0], robot.draw_dim)
    points = "Points2D" if robot.draw_dim == 2 else "Points3D"
    tips = np.array([row[0] for row in data["/arm/tip"]["columns"][f"{points}:positions"]])
    np.testing.assert_allclose(tips, robot.ee_point(q[:n]), atol=1e-6)
    path = np.array(data["/plan/path"]["columns"][f"{kind}:strips"][0][0])
    np.testing.assert_allclose(path, robot.ee_point(q), atol=1e-6)
    for jn in robot.joint_names:
        assert data[f"/joints/{jn}/q"]["rows"] == n
    # Its layout: the arm in 2-D or 3-D as the robot draws, one plot per joint (its own names).
    tree = layout(rrd)
    arm = tree["children"][0]["children"][0]
    assert arm["view"] == ("2D" if robot.draw_dim == 2 else "3D") and "arm/**" in arm["contents"]
    grids = tree["children"][1]["children"]
    assert [names(g) for g in grids] == [["Grid", [f"{j}{s}" for j in robot.joint_names]]
                                         for s in ("", " error", " effort")]


def test_a_joint_plan_opens_in_its_own_layout(tmp_path):
    """A plan without pen flags (a joint plan): the .rrd holds a blueprint made for it (the
    arm over the logs, beside per-joint grids of position, error and effort) and the arm's
    line strips through FK of the measured q."""
    plan = _plan()
    rrd = tmp_path / "j.rrd"
    with Recording(rrd, ARM3R, plan, flush_every=4) as rec:
        for i in range(10):
            rec.telemetry(0.1 * i, plan.q[i], plan.q[min(i + 1, 9)], [0.1, 0, 0], done=i)
        rec.event(0.5, "DONE 4 0")
    joints = list(ARM3R.joint_names)
    tree = layout(rrd)
    assert names(tree) == ["Horizontal", [
        ["Vertical", ["arm", ["Tabs", ["events", "errors", "plan", "summary", "done waypoint"]]]],
        ["Tabs", [["Grid", joints], ["Grid", [f"{j} error" for j in joints]],
                  ["Grid", [f"{j} effort" for j in joints]]]]]]
    arm = tree["children"][0]["children"][0]
    assert arm["view"] == "2D" and arm["origin"] == "/"
    assert set(arm["contents"]) == {"arm/**", "plan/path", "plan/waypoints", "trace/**", "workspace"}
    logs = tree["children"][0]["children"][1]["children"]
    assert [(v["view"], v["origin"]) for v in logs] == [("TextLog", "events"), ("TextLog", "errors"),
                                                        ("TextDocument", "plan/info"), ("TextDocument", "run/summary"),
                                                        ("TimeSeries", "board")]
    pos, err, eff = tree["children"][1]["children"]
    assert [g["name"] for g in (pos, err, eff)] == ["position", "error", "effort"]
    # the position plot is the joint's series less error and effort: q, the set point (and a caller's extras)
    assert pos["children"][1]["origin"] == "joints/elbow"
    assert pos["children"][1]["contents"] == ["+ joints/elbow/**", "- joints/elbow/error", "- joints/elbow/effort"]
    assert err["children"][2]["contents"] == ["joints/wrist/error"]
    assert eff["children"][0]["contents"] == ["joints/shoulder/effort"]
    # what the views show is in the file: the arm's strips (FK of the measured q), the series, the log
    data = read(rrd)
    strips = [np.array(r[0]) for r in data["/arm/links"]["columns"]["LineStrips2D:strips"]]
    assert len(strips) == 10
    for i, strip in enumerate(strips):
        np.testing.assert_allclose(strip, ARM3R.joint_points(plan.q[i]), atol=1e-6)
    assert strips[0].shape == (ARM3R.n + 1, 2)
    for j in joints:
        for series in ("q", "target", "error", "effort"):
            assert data[f"/joints/{j}/{series}"]["rows"] == 10
    assert [x for r in data["/events"]["columns"]["TextLog:text"] for x in r] == ["DONE 4 0"]


def test_a_caller_passes_its_own_layout(tmp_path):
    """layout=: the run's layout with a caller's entities in the arm view and views of its own
    (the fault-tolerant demo's: the task in the arm view, one view per joint plane)."""
    from armbridge.demos.arm3r_ft_log import FtLog

    rrd = tmp_path / "c.rrd"
    with Recording(rrd, ARM3R, _plan(), layout=FtLog.layout(ARM3R)) as rec:
        rec.telemetry(0.0, MID, MID, [0, 0, 0])
    tree = layout(rrd)
    left = tree["children"][0]
    arm, planes, logs = left["children"]
    assert {"task/**", "recovery/**", "arm/**"} <= set(arm["contents"])
    assert [(v["view"], v["name"], v["origin"]) for v in planes["children"]] == [
        ("2D", "shoulder-elbow", "joint_space/shoulder-elbow"), ("2D", "elbow-wrist", "joint_space/elbow-wrist"),
        ("2D", "shoulder-wrist", "joint_space/shoulder-wrist")]
    assert names(logs)[0] == "Tabs"
    rrd2 = tmp_path / "d.rrd"
    with Recording(rrd2, ARM3R, None, layout=run_layout(ARM3R, spatial=("extra/**",))) as rec:
        rec.telemetry(0.0, MID, MID, [0, 0, 0])
    assert "extra/**" in layout(rrd2)["children"][0]["children"][0]["contents"]


def test_a_run_without_a_plan_has_the_layout_too(tmp_path):
    rrd = tmp_path / "n.rrd"
    with Recording(rrd, get_robot("spatial4r"), None) as rec:
        rec.telemetry(0.0, np.zeros(4), np.zeros(4), np.zeros(4))
    tree = layout(rrd)
    assert tree["children"][0]["children"][0]["view"] == "3D"
    assert names(tree["children"][1]["children"][0])[1] == list(get_robot("spatial4r").joint_names)
