"""A plan that fails validation sends nothing: run_plan checks it before it opens the port."""
from __future__ import annotations

import json

import pytest

import armbridge.link.transport as transport
from armbridge.errors import ArmbridgeError
from armbridge.executor.run import run_plan
from armbridge.plans.format import make_plan
from armbridge.robots import ARM3R

GOOD_Q = [[1.5, -1.5, 0.0], [1.6, -1.5, 0.0], [1.7, -1.5, 0.0]]


def _doc():
    return {
        "format": "armbridge-plan",
        "version": 1,
        "robot": "arm3r",
        "joints": [{"name": n, "unit": "rad"} for n in ARM3R.joint_names],
        "waypoints": [{"q": list(q), "duration": 0.2} for q in GOOD_Q],
        "provenance": {"tool": "test"},
    }


@pytest.fixture
def no_port(monkeypatch):
    """open_port must not be called: fail the test if it is."""
    calls = []

    def refuse(url, *a, **kw):
        calls.append(url)
        pytest.fail(f"open_port({url!r}) was called for a plan that should have been refused")

    monkeypatch.setattr(transport, "open_port", refuse)
    return calls


def _bad(kind: str) -> str:
    text = json.dumps(_doc(), indent=1)
    if kind == "malformed":
        return text.replace('"duration": 0.2', '"duration": 0.2,', 1)
    if kind == "nan":
        return text.replace("1.6", "NaN", 1)
    doc = _doc()
    if kind == "range":
        doc["waypoints"][2]["q"][0] = 3.5
    elif kind == "robot":
        doc["robot"] = "ur5"
    elif kind == "speed":
        doc["waypoints"][1]["duration"] = 0.01
    return json.dumps(doc, indent=1)


@pytest.mark.parametrize(
    "kind,pattern",
    [
        ("malformed", r"plan.json: line \d+, column \d+: not valid JSON"),
        ("nan", r"plan.json: waypoint 1, q\[0\] \(shoulder\) is nan: plans hold finite numbers only"),
        ("range", r"plan.json: waypoint 2, q\[0\] \(shoulder\) = 3.5 rad is outside \[0, 3.1416\]"),
        ("robot", r'plan.json: robot: unknown robot "ur5" \(known: [^)]*\barm3r\b'),
        ("speed", r"plan.json: waypoint 1, joint 0 \(shoulder\) moves 0.1 rad in 0.01 s = 10 rad/s"),
    ],
)
def test_bad_plan_sends_nothing(tmp_path, no_port, kind, pattern):
    path = tmp_path / "plan.json"
    path.write_text(_bad(kind))
    with pytest.raises(ArmbridgeError, match=pattern):
        run_plan(path, "emu:esp32", tmp_path / "never.rrd", progress=False)
    assert no_port == []
    assert not (tmp_path / "never.rrd").exists()


def test_bad_plan_object_and_rate_send_nothing(tmp_path, no_port):
    plan = make_plan(ARM3R, GOOD_Q, 0.2)
    plan.q[1, 1] = 0.3  # edited after it was made
    with pytest.raises(ArmbridgeError, match=r"waypoint 1, q\[1\] \(elbow\) = 0.3 rad is outside \[-3.1416, 0\]"):
        run_plan(plan, "emu:esp32", tmp_path / "never.rrd", progress=False)
    good = make_plan(ARM3R, GOOD_Q, 0.2)
    with pytest.raises(ArmbridgeError, match=r"telemetry rate 500 Hz is outside \[1, 100\]"):
        run_plan(good, "emu:esp32", tmp_path / "never.rrd", rate_hz=500, progress=False)
    with pytest.raises(ArmbridgeError, match="no such plan file"):
        run_plan(tmp_path / "missing.json", "emu:esp32", progress=False)
    assert no_port == []
