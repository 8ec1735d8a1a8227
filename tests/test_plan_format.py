"""The plan file format (host/armbridge/plans/format.py, docs/formats.md).

Every bad input must give one ArmbridgeError whose message names the file,
the waypoint index, the field and the allowed range.
"""
from __future__ import annotations

import copy
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from armbridge.errors import ArmbridgeError
from armbridge.plans.format import (
    FORMAT,
    VERSION,
    load_plan,
    loads_plan,
    make_plan,
    plan_to_dict,
    save_plan,
    validate,
)
from armbridge.robots import ARM3R


def _doc(k: int = 20) -> dict:
    """A valid arm3r plan document: a slow wave around the mid pose."""
    q = [[1.5 + 0.1 * math.sin(i / 3), -1.5 + 0.05 * i / k, 0.2 * math.cos(i / 4)] for i in range(k)]
    return {
        "format": FORMAT,
        "version": VERSION,
        "robot": "arm3r",
        "joints": [{"name": n, "unit": "rad"} for n in ("shoulder", "elbow", "wrist")],
        "waypoints": [{"q": qi, "duration": 0.1} for qi in q],
        "provenance": {"tool": "test", "created": "2025-01-01T00:00:00Z", "seed": 7},
    }


def _write(tmp_path, doc, name="plan.json") -> str:
    p = tmp_path / name
    p.write_text(json.dumps(doc, indent=1) if not isinstance(doc, str) else doc)
    return p


def _err(tmp_path, doc, name="plan.json") -> str:
    p = _write(tmp_path, doc, name)
    with pytest.raises(ArmbridgeError) as ei:
        load_plan(p)
    msg = str(ei.value)
    assert msg.startswith(f"{p}: "), msg  # every message names the file first
    assert "\n" not in msg  # one line
    return msg[len(str(p)) + 2:]


# ---------------------------------------------------------------- good plans

def test_round_trip(tmp_path):
    doc = _doc(50)
    p = _write(tmp_path, doc)
    plan = load_plan(p)
    assert plan.robot == ARM3R and not plan.inline_robot
    assert plan.q.shape == (50, 3) and plan.durations.shape == (50,)
    np.testing.assert_array_equal(plan.q, np.array([w["q"] for w in doc["waypoints"]]))
    assert plan.provenance == doc["provenance"]
    assert plan.source == p and plan.name == "plan"
    assert plan.total_duration == pytest.approx(5.0)

    out = save_plan(plan, tmp_path / "sub" / "again.json")
    again = load_plan(out)
    np.testing.assert_array_equal(again.q, plan.q)  # exact: floats written with repr precision
    np.testing.assert_array_equal(again.durations, plan.durations)
    assert again.provenance == plan.provenance
    assert plan_to_dict(again) == plan_to_dict(plan)
    # One waypoint a line: a diff of two plans reads well.
    text = out.read_text()
    assert text.count('{"q": ') == 50


def test_inline_robot_round_trip(tmp_path):
    doc = _doc(5)
    doc["robot"] = {
        "name": "arm2r", "link_lengths": [0.3, 0.2], "q_min": [-1.0, -2.0], "q_max": [1.0, 2.0],
        "v_max": [2.0, 2.0], "joint_names": ["a", "b"],
    }
    doc["joints"] = [{"name": "a", "unit": "rad"}, {"name": "b", "unit": "rad"}]
    doc["waypoints"] = [{"q": [0.1 * i, -0.1 * i], "duration": 0.5} for i in range(5)]
    plan = load_plan(_write(tmp_path, doc))
    assert plan.inline_robot and plan.robot.name == "arm2r" and plan.n == 2
    again = load_plan(save_plan(plan, tmp_path / "b.json"))
    assert again.robot == plan.robot and again.inline_robot


def test_make_plan_fills_provenance_and_validates():
    plan = make_plan(ARM3R, [[1.0, -1.0, 0.0], [1.1, -1.0, 0.0]], 0.1, {"tool": "unit"})
    assert plan.provenance["tool"] == "unit" and "created" in plan.provenance
    assert not plan.inline_robot
    with pytest.raises(ArmbridgeError, match=r"waypoint 1, q\[1\] \(elbow\) = 0.5 rad is outside \[-3.1416, 0\]"):
        make_plan(ARM3R, [[1.0, -1.0, 0.0], [1.0, 0.5, 0.0]], 1.0)


def test_boundary_values_are_allowed(tmp_path):
    doc = _doc(3)
    doc["waypoints"] = [
        {"q": [0.0, -math.pi, -math.pi / 2], "duration": 0.001},
        {"q": [0.0, -math.pi, -math.pi / 2], "duration": 60},
        # exactly v_max (3 rad/s) on the shoulder: allowed
        {"q": [3.0, -math.pi, -math.pi / 2], "duration": 1.0},
    ]
    plan = load_plan(_write(tmp_path, doc))
    assert plan.k == 3


def test_validate_a_plan_object():
    plan = loads_plan(json.dumps(_doc(4)), "mem.json")
    plan.q[2, 0] = 4.0  # edited in memory: validate catches it
    with pytest.raises(ArmbridgeError, match=r"^mem.json: waypoint 2, q\[0\] \(shoulder\) = 4 rad is outside"):
        validate(plan)


# ---------------------------------------------------------------- bad plans

def test_joint_out_of_range_message(tmp_path):
    doc = _doc(20)
    doc["waypoints"][17]["q"][1] = 0.4
    # (waypoint 16 -> 17 moves the elbow ~1.9 rad in 0.1 s, but the range check comes first)
    assert _err(tmp_path, doc) == "waypoint 17, q[1] (elbow) = 0.4 rad is outside [-3.1416, 0]"


def test_malformed_json_names_line_and_column(tmp_path):
    text = json.dumps(_doc(6), indent=1)
    lines = text.splitlines()
    n = next(i for i, ln in enumerate(lines) if '"duration"' in ln)
    lines[n] = lines[n].replace("0.1", "0.1,,")  # a syntax error on line n+1
    msg = _err(tmp_path, "\n".join(lines))
    m = re.match(r"line (\d+), column (\d+): not valid JSON: ", msg)
    assert m, msg
    assert int(m.group(1)) == n + 1


def test_truncated_file(tmp_path):
    text = json.dumps(_doc(6), indent=1)
    msg = _err(tmp_path, text[: len(text) // 2])
    assert re.match(r"line \d+, column \d+: not valid JSON", msg), msg


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_nan_and_infinity_are_refused(tmp_path, literal):
    text = json.dumps(_doc(6), indent=1)
    # json.dumps writes floats with repr, so this replaces waypoint 3's wrist value exactly.
    doc = _doc(6)
    wrist = json.dumps(doc["waypoints"][3]["q"][2])
    assert text.count(wrist) == 1
    msg = _err(tmp_path, text.replace(wrist, literal))
    assert msg.startswith("waypoint 3, q[2] (wrist) is "), msg
    assert "finite" in msg


def test_nan_duration(tmp_path):
    text = json.dumps(_doc(6))
    text = text.replace('"duration": 0.1}]', '"duration": NaN}]')
    assert _err(tmp_path, text) == "waypoint 5, duration is nan: plans hold finite numbers only"


def test_wrong_joint_count(tmp_path):
    doc = _doc(8)
    doc["waypoints"][4]["q"] = [1.0, -1.0]
    assert _err(tmp_path, doc) == (
        "waypoint 4, q has 2 values, robot arm3r has 3 joints (shoulder, elbow, wrist)"
    )
    doc = _doc(8)
    doc["joints"] = doc["joints"][:2]
    assert _err(tmp_path, doc) == "joints lists 2 joints, robot arm3r has 3 (shoulder, elbow, wrist)"


def test_unknown_robot_lists_the_known_ones(tmp_path):
    doc = _doc(3)
    doc["robot"] = "arm9x"
    assert _err(tmp_path, doc) == 'robot: unknown robot "arm9x" (known: arm3r, masr5, planar3r, soft2, soft3, soft7, spatial4r, spatial7r)'


@pytest.mark.parametrize("dur,shown", [(0.0, "0"), (0.0005, "0.0005"), (61, "61"), (-1, "-1")])
def test_duration_out_of_range(tmp_path, dur, shown):
    doc = _doc(8)
    doc["waypoints"][6]["duration"] = dur
    assert _err(tmp_path, doc) == f"waypoint 6, duration = {shown} s is outside [0.001, 60]"


def test_segment_speed_above_vmax(tmp_path):
    doc = _doc(8)
    doc["waypoints"][5]["q"][2] = doc["waypoints"][4]["q"][2] + 0.5  # 0.5 rad in 0.1 s = 5 rad/s
    msg = _err(tmp_path, doc)
    assert msg.startswith("waypoint 5, joint 2 (wrist) moves 0.5 rad in 0.1 s = 5 rad/s, above the robot's "
                          "v_max 3 rad/s"), msg
    assert "needs duration >= 0.1667 s" in msg


def test_unsupported_version_and_format(tmp_path):
    doc = _doc(3)
    doc["version"] = 3
    assert _err(tmp_path, doc) == "unsupported version 3 (this armbridge reads versions 1, 2)"
    doc = _doc(3)
    doc["format"] = "grbl"
    assert _err(tmp_path, doc) == 'format is "grbl", expected "armbridge-plan"'
    doc = _doc(3)
    del doc["version"]
    assert _err(tmp_path, doc) == 'missing field "version" (this armbridge reads versions 1, 2)'
    assert _err(tmp_path, [1, 2]) == "a plan is a JSON object, got a list of 2"


@pytest.mark.parametrize("field", ["robot", "joints", "waypoints", "format"])
def test_missing_top_level_field(tmp_path, field):
    doc = _doc(3)
    del doc[field]
    assert f'missing field "{field}"' in _err(tmp_path, doc)


def test_missing_and_unknown_waypoint_fields(tmp_path):
    doc = _doc(5)
    del doc["waypoints"][2]["duration"]
    assert _err(tmp_path, doc) == 'waypoint 2: missing field "duration"'
    doc = _doc(5)
    del doc["waypoints"][3]["q"]
    assert _err(tmp_path, doc) == 'waypoint 3: missing field "q"'
    doc = _doc(5)
    doc["waypoints"][1]["durations"] = 1
    assert _err(tmp_path, doc) == 'waypoint 1: unknown field "durations" (allowed: q, duration, pen)'
    doc = _doc(5)
    doc["waypont"] = []
    assert "unknown field \"waypont\"" in _err(tmp_path, doc)


def test_wrong_types(tmp_path):
    doc = _doc(5)
    doc["waypoints"][2]["q"][0] = "1.5"
    assert _err(tmp_path, doc) == 'waypoint 2, q[0] (shoulder) must be a number, got the string "1.5"'
    doc = _doc(5)
    doc["waypoints"][2]["q"][0] = True
    assert _err(tmp_path, doc) == "waypoint 2, q[0] (shoulder) must be a number, got true"
    doc = _doc(5)
    doc["waypoints"][1]["duration"] = None
    assert _err(tmp_path, doc) == "waypoint 1, duration must be a number of seconds, got null"
    doc = _doc(5)
    doc["waypoints"] = []
    assert _err(tmp_path, doc) == "waypoints is empty: a plan needs at least one waypoint"


def test_joint_names_and_units(tmp_path):
    doc = _doc(3)
    doc["joints"][1]["name"] = "knee"
    assert _err(tmp_path, doc) == (
        'joints[1].name is "knee", robot arm3r calls joint 1 "elbow" (joints: shoulder, elbow, wrist)'
    )
    doc = _doc(3)
    doc["joints"][2]["unit"] = "deg"
    assert _err(tmp_path, doc) == 'joints[2] (wrist).unit is "deg", allowed: "rad"'


def test_bad_inline_robot(tmp_path):
    doc = _doc(3)
    doc["robot"] = {"name": "x", "link_lengths": [0.1, 0.1, 0.1], "q_min": [0, 0, 0], "q_max": [1, 1],
                    "v_max": [1, 1, 1]}
    assert _err(tmp_path, doc) == "robot: robot 'x': q_max has 2 values, link_lengths has 3"


def test_missing_file_and_not_utf8(tmp_path):
    with pytest.raises(ArmbridgeError, match="no such plan file"):
        load_plan(tmp_path / "nope.json")
    p = tmp_path / "bin.json"
    p.write_bytes(b"\xff\xfe{}")
    with pytest.raises(ArmbridgeError, match="not UTF-8"):
        load_plan(p)


def test_save_refuses_invalid_plan(tmp_path):
    plan = make_plan(ARM3R, [[1.0, -1.0, 0.0]], 0.1)
    bad = copy.deepcopy(plan)
    bad.q[0, 2] = float("nan")
    with pytest.raises(ArmbridgeError, match=r"waypoint 0, q\[2\] \(wrist\) is nan"):
        save_plan(bad, tmp_path / "bad.json")
    assert not (tmp_path / "bad.json").exists()


# ---------------------------------------------------------------- any robot of the interface


def _masr_doc(robot="masr5") -> dict:
    from armbridge.robots import MASR5

    q = [[0.1 * i, -0.05 * i, 0.0, 0.02 * i, 0.0, 0.1 + 0.05 * i] for i in range(5)]
    return {
        "format": FORMAT, "version": VERSION, "robot": robot,
        "joints": [{"name": n, "unit": u} for n, u in zip(MASR5.joint_names, MASR5.joint_units)],
        "waypoints": [{"q": qi, "duration": 1.0} for qi in q],
    }


def test_a_masr_plan_has_its_d_in_m(tmp_path):
    from armbridge.robots import MASR5

    plan = load_plan(_write(tmp_path, _masr_doc()))
    assert plan.robot is MASR5 and plan.n == 6 and not plan.inline_robot
    np.testing.assert_allclose(plan.ee_path(), MASR5.ma_point(plan.q))  # the MA is the end effector
    doc = _masr_doc()
    doc["waypoints"][2]["q"][5] = 0.9
    assert _err(tmp_path, doc) == "waypoint 2, q[5] (d) = 0.9 m is outside [0, 0.8]"
    doc = _masr_doc()
    doc["waypoints"][1]["q"][5] = 0.5  # 0.4 m in 1 s at 0.1 m/s
    assert _err(tmp_path, doc) == ("waypoint 1, joint 5 (d) moves 0.4 m in 1 s = 0.4 m/s, above the "
                                   "robot's v_max 0.1 m/s (needs duration >= 4 s)")
    doc = _masr_doc()
    doc["joints"][5]["unit"] = "rad"
    assert _err(tmp_path, doc) == 'joints[5] (d).unit is "rad", allowed: "m"'


def test_inline_robots_of_every_kind_round_trip(tmp_path):
    from armbridge.robots import MASR5, get_robot, robot_to_dict

    spatial = get_robot("spatial4r")
    for robot in (MASR5.__class__.from_dict({**MASR5.to_dict(), "name": "masr-x"}),
                  spatial.__class__.from_dict({**spatial.to_dict(), "name": "dh-x", "v_max": [2.0] * 4})):
        q = (robot.q_min + robot.q_max) / 2 + np.zeros((3, robot.dof))
        plan = make_plan(robot, q, 0.5)
        assert plan.inline_robot
        doc = json.loads(save_plan(plan, tmp_path / f"{robot.name}.json").read_text())
        assert doc["robot"] == robot_to_dict(robot) and doc["robot"]["kind"] == robot.kind
        back = load_plan(tmp_path / f"{robot.name}.json")
        assert back.robot == robot and back.inline_robot
    doc = _masr_doc(robot={"kind": "masr", **{k: v for k, v in MASR5.to_dict().items() if k != "name"}})
    assert load_plan(_write(tmp_path, doc)).robot.name == "inline"  # a name may be left out
    doc["robot"]["kind"] = "delta"
    assert _err(tmp_path, doc) == "robot: unknown robot kind 'delta'; known kinds: planar, masr, dh"


# ---------------------------------------------------------------- older files keep loading
OLD = Path(__file__).parent / "vectors" / "old_plans"


def test_a_version_1_soft_plan_loads_with_its_section_and_saves_as_version_2(tmp_path):
    """Files written before the plan format's version 2 (made by that code, kept in
    tests/vectors/old_plans): a soft plan whose section rode in provenance["soft_plan"]."""
    from armbridge.plans.soft import soft_info

    plan = load_plan(OLD / "soft-three-arm-version1.json")
    info = soft_info(plan)
    assert info is not None and info.scene == "three-arm" and info.planner == "wjrrt"
    assert "soft_plan" not in plan.provenance and plan.soft is not None
    out = save_plan(plan, tmp_path / "v2.json")
    doc = json.loads(out.read_text())
    assert doc["version"] == 2 and doc["soft"] == plan.soft and "soft_plan" not in doc["provenance"]
    again = load_plan(out)
    assert np.array_equal(again.q, plan.q) and np.array_equal(again.durations, plan.durations)


def test_an_old_masr_plan_loads_as_a_plan_with_its_masr_section(tmp_path):
    """The old sibling format ("armbridge-masr-plan", version 1) loads into the one format:
    its path as the waypoints, each duration the action into it, the actions and goal as
    its masr section; the executor turns it into the MA's commands as before."""
    from armbridge.executor.masr import masr_commands
    from armbridge.plans import masr as M

    doc = json.loads((OLD / "masr-E1-format1.json").read_text())
    plan = load_plan(OLD / "masr-E1-format1.json")
    assert plan.robot.name == "masr5" and plan.masr is not None and plan.k == len(doc["waypoints"])
    assert np.allclose(M.tau(plan), [w["tau"] for w in doc["waypoints"]])
    assert M.total_time(plan) == pytest.approx(doc["tau"]) and M.steps(plan) == [
        s for a in doc["actions"] for s in a["steps"]]
    assert np.allclose(M.goal_pose(plan), doc["goal"]["pose"])
    steps, commands = masr_commands(plan)
    assert [v for v, _ in commands] == ["MV" if s["op"] == "move" else "ROT" for s in M.steps(plan)]
    assert steps.k == len(commands)
    # its own check, with its own message: a waypoint's tau off eq. (7)
    doc["waypoints"][1]["tau"] += 0.5
    with pytest.raises(ArmbridgeError, match=r"waypoint 1, tau = .* but eq. \(7\) along the path gives"):
        loads_plan(json.dumps(doc), "old.json")
    # saved again, it is version 2 of the one format, and loads the same
    out = save_plan(plan, tmp_path / "v2.json")
    v2 = json.loads(out.read_text())
    assert v2["format"] == "armbridge-plan" and v2["version"] == 2 and v2["masr"]["actions"] == plan.masr["actions"]
    assert np.array_equal(load_plan(out).q, plan.q)
