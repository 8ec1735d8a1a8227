"""The clearance soft-arm plans keep (issue 24 section 2; planning/soft/margin.py).

The margin is the pump controller's joint tolerance through the chain (a sampled check that the bound
holds and is tight); the margined checker refuses states and edges that come within it; every planner's
path, smoothed or not, keeps it when checked densely with shapely (an independent geometry library);
smoothing never lowers the path's clearance below min(target, what it was); plan files and `plan soft`
carry margin_mm and clearance_min_mm; the demo's report measures the executed arm's clearance; a bad
--margin is one line naming the range.
"""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import shapely

from armbridge.errors import ArmbridgeError
from armbridge.planning.smoothing import shortcut
from armbridge.planning.soft import planners
from armbridge.planning.margin import CLEARANCE_RES, check_margin
from armbridge.planning.soft.margin import ClearanceObjective, execution_margin, joint_tolerance
from armbridge.planning.soft.random_scene import random_scene
from armbridge.planning.soft.scene import fixed_scene, scene_from_dict
from armbridge.robots.catalog import get_robot

#: States along a path no more than this of point motion apart for the shapely check (m).
DENSE = 1e-4


def dense_states(scene, path, step=DENSE):
    """Every edge of path cut so that no point of the arm moves more than step between two states."""
    reach = np.cumsum(scene.robot.link_lengths[::-1])[::-1]
    P = np.asarray(path, float)
    out = [P[:1]]
    for a, b in zip(P[:-1], P[1:]):
        k = max(1, int(math.ceil(float(np.abs(b - a) @ reach) / step)))
        out.append(a + np.linspace(0, 1, k + 1)[1:, None] * (b - a))
    return np.concatenate(out)


def shapely_clearance(scene, path):
    """The least distance of the arm's surface (centre lines less w/2) to the obstacles over dense_states."""
    chk = scene.checker()
    Q = dense_states(scene, path)
    lines = shapely.linestrings(np.array([chk.points(q) for q in Q]))
    obstacles = shapely.union_all([shapely.Polygon(p) if len(p) > 2 else shapely.LineString(p)
                                   for p in scene.obstacles])
    shapely.prepare(obstacles)
    return float(shapely.distance(lines, obstacles).min()) - 0.5 * scene.link_width


# ---------------------------------------------------------------- the margin
@pytest.mark.parametrize("robot, mm", [("soft2", 2.4), ("soft3", 4.8), ("soft7", 13.44)])
def test_the_margin_is_the_joint_tolerance_through_the_chain(robot, mm):
    """e (sum of the reaches from each joint): 8 mrad x (0.3 + 0.2 + 0.1) m = 4.8 mm for soft3; e is the
    firmware's re-seek threshold."""
    assert joint_tolerance() == 0.008
    r = get_robot(robot)
    reach = np.cumsum(r.link_lengths[::-1])[::-1]
    assert execution_margin(r) == pytest.approx(joint_tolerance() * reach.sum(), rel=1e-12)
    assert execution_margin(r) * 1000 == pytest.approx(mm, abs=1e-9)
    assert execution_margin(r, 0.0) == 0.0
    assert execution_margin(r, 2 * joint_tolerance()) == pytest.approx(2 * execution_margin(r))


@pytest.mark.parametrize("robot", ["soft3", "soft7"])
def test_no_joint_error_within_the_tolerance_moves_a_point_farther_than_the_margin(robot):
    """Random configurations and joint errors |delta_i| <= e (many at the box's corners): every point of
    every link moves at most the margin, and the straight arm with delta = (e, ..., e) comes within 1 %."""
    r = get_robot(robot)
    chk = fixed_scene("three-arm").checker() if robot == "soft3" else fixed_scene("seven-tube").checker()
    rng = np.random.default_rng(3)
    e, m = joint_tolerance(), execution_margin(r)
    s = np.linspace(0, 1, 11)
    worst = 0.0
    for _ in range(2000):
        q = r.q_min + rng.random(r.n) * (r.q_max - r.q_min)
        d = e * np.where(rng.random(r.n) < 0.7, rng.choice([-1.0, 1.0], r.n), rng.uniform(-1, 1, r.n))
        a, b = chk.points(q), chk.points(q + d)
        pa = a[:-1, None] + s[None, :, None] * (a[1:] - a[:-1])[:, None]
        pb = b[:-1, None] + s[None, :, None] * (b[1:] - b[:-1])[:, None]
        worst = max(worst, float(np.linalg.norm(pb - pa, axis=-1).max()))
    assert worst <= m
    straight = np.zeros(r.n)
    tip = np.linalg.norm(chk.points(straight + e)[-1] - chk.points(straight)[-1])
    assert tip >= 0.99 * m


def test_a_margin_out_of_range_is_refused_with_the_range():
    assert check_margin(0.0) == 0.0 and check_margin(0.05) == 0.05
    for bad in (-0.001, 0.08, math.nan, math.inf):
        with pytest.raises(ArmbridgeError, match=r"outside \[0, 50\] mm"):
            check_margin(bad, "--margin")


# ---------------------------------------------------------------- the checker
def test_the_checker_refuses_states_and_edges_within_the_margin():
    """States whose least link clearance is below the margin are refused by the margined checker and
    taken by the touch check; states beyond it are taken by both; an edge into a refused state is refused."""
    scene = fixed_scene("three-arm")
    touch, held = scene.checker(), scene.planning_checker()
    m = scene.planning_margin
    assert held.margin == m == pytest.approx(0.0048)
    rng = np.random.default_rng(0)
    Q = scene.space().sample(rng, 20000)
    cl = np.array([touch.clearance(q) for q in Q])
    near = Q[(cl > 0) & (cl < m)]
    far = Q[cl > m + 1e-6]
    assert len(near) > 20 and len(far) > 100
    assert all(touch.is_valid(q) and not held.is_valid(q) for q in near)
    assert all(held.is_valid(q) for q in far if touch.is_valid(q))
    refused = 0
    for q in near[:50]:
        start = far[np.argmin(np.linalg.norm(far - q, axis=1))]
        if held.is_valid(start):
            assert not held.motion_valid(start, q)
            refused += 1
    assert refused > 10
    assert "margin" in held.describe(held.code(near[0]))


def test_a_start_inside_the_margin_is_one_clear_error():
    scene = fixed_scene("seven-tube")                     # its start keeps 42.5 mm
    c = scene.checker().clearance(scene.start)
    with pytest.raises(ArmbridgeError, match=r"seven-tube: the start keeps 42.5 mm from the obstacles, less than "
                                             r"the 45 mm clearance margin"):
        scene.problem(margin=0.045)
    assert scene.problem(margin=c - 0.001).checker.margin == pytest.approx(c - 0.001)


def test_a_scene_file_carries_its_margin_and_refuses_one_out_of_range():
    scene = fixed_scene("three-arm")
    doc = scene.to_dict()
    doc["margin"] = 0.003
    s = scene_from_dict(doc, "mine.json")
    assert s.planning_margin == 0.003 and s.planning_checker().margin == 0.003
    assert s.to_dict()["margin"] == 0.003
    doc["margin"] = 0.2
    with pytest.raises(ArmbridgeError, match=r"mine.json: margin = 200 mm is outside \[0, 50\] mm"):
        scene_from_dict(doc, "mine.json")


# ---------------------------------------------------------------- planners and smoothing
SCENES = ["two-arm", "three-arm", "random:3:passage:1"]


def _scene(name):
    if name.startswith("random:"):
        _, links, kind, seed = name.split(":")
        return random_scene(int(links), kind, int(seed))
    return fixed_scene(name)


@pytest.mark.parametrize("name", SCENES)
@pytest.mark.parametrize("planner", planners.PLANNERS)
def test_every_planners_path_keeps_the_margin_checked_densely_with_shapely(name, planner):
    scene = _scene(name)
    m = scene.planning_margin
    assert m > 0
    solved = 0
    for seed in range(3):
        r = planners.plan(scene, planner, seed=seed)
        assert r.settings["margin_m"] == m
        if r.path is None:
            assert r.stats["clearance_min_m"] is None
            continue
        solved += 1
        c = shapely_clearance(scene, r.path)
        assert c >= m, (name, planner, seed, c, m)
        # the reported clearance: sampled at CLEARANCE_RES, so within res / 2 above the dense one
        assert r.stats["clearance_min_m"] >= m
        assert c - DENSE <= r.stats["clearance_min_m"] <= c + CLEARANCE_RES / 2 + DENSE
    assert solved >= 2, (name, planner)


@pytest.mark.parametrize("name", SCENES)
@pytest.mark.parametrize("planner", ["jt-rrt", "birrt"])
def test_smoothing_keeps_the_margin_and_never_lowers_the_clearance_below_its_target(name, planner):
    scene = _scene(name)
    m = scene.planning_margin
    for seed in range(3):
        raw = planners.plan(scene, planner, seed=seed)
        smooth = planners.plan(scene, planner, seed=seed, smooth=True)
        if raw.path is None:
            continue
        assert np.array_equal(smooth.path[0], raw.path[0]) and np.array_equal(smooth.path[-1], raw.path[-1])
        assert len(smooth.path) <= len(raw.path)
        assert shapely_clearance(scene, smooth.path) >= m
        target = 2 * m
        assert smooth.stats["clearance_min_m"] >= min(target, raw.stats["clearance_min_m"]) - 1e-12


class Objective:
    """A clearance objective on the real line: the clearance of an edge is given per pair of points."""

    def __init__(self, table):
        self.table = table

    def edge(self, a, b):
        return self.table.get((float(a[0]), float(b[0])), 1.0)


class AlwaysFree:
    def motion_valid(self, a, b):
        return True


def test_a_shortcut_that_would_lower_the_clearance_is_refused():
    """0 -> 1 -> 2 -> 3 with edges of clearance 1: a shortcut 0 -> 3 of clearance 0.2 is refused for a target of
    0.5, taken for a target of 0.1 (0.2 >= min(0.1, 1)); 0 -> 2 of clearance 0.6 is taken for 0.5."""
    path = np.array([[0.0], [1.0], [2.0], [3.0]])
    rng = np.random.default_rng(0)
    low = Objective({(0.0, 3.0): 0.2, (0.0, 2.0): 0.2, (1.0, 3.0): 0.2})
    assert len(shortcut(path, AlwaysFree(), rng, objective=low, target=0.5)) == 4
    assert len(shortcut(path, AlwaysFree(), rng, objective=low, target=0.1)) == 2
    mid = Objective({(0.0, 3.0): 0.2, (0.0, 2.0): 0.6, (1.0, 3.0): 0.2})
    out = shortcut(path, AlwaysFree(), rng, tries=0, objective=mid, target=0.5)
    assert out[:, 0].tolist() == [0.0, 2.0, 3.0]


def test_the_clearance_objective_is_the_least_over_the_edge():
    """ClearanceObjective.edge against the state clearance at 20x finer steps; it is at least the path's."""
    scene = fixed_scene("three-arm")
    chk = scene.checker()
    obj = ClearanceObjective(chk)
    assert obj.is_better(0.02, 0.01)
    r = planners.plan(scene, "birrt", seed=0)
    for a, b in zip(r.path[:-1], r.path[1:]):
        fine = min(chk.clearance(q) for q in dense_states(scene, [a, b], CLEARANCE_RES / 20))
        assert fine - 1e-12 <= obj.edge(a, b) <= fine + CLEARANCE_RES / 2
    assert obj.path(r.path) == pytest.approx(r.stats["clearance_min_m"])


# ---------------------------------------------------------------- plan files, the CLI, the demo's report
def test_plan_soft_reports_the_margin_and_the_least_clearance(tmp_path):
    import json

    from typer.testing import CliRunner

    from armbridge.planning.command import plan_app
    from armbridge.plans.format import load_plan
    from armbridge.plans.soft import soft_info

    out, js = tmp_path / "p.json", tmp_path / "s.json"
    r = CliRunner().invoke(plan_app, ["soft", "--env", "three-arm", "--out", str(out), "--planner", "birrt",
                                      "--margin", "8", "--json", str(js)])
    assert r.exit_code == 0, r.output
    summary = json.loads(js.read_text())
    plan = load_plan(out)
    info = soft_info(plan)
    assert summary["margin_mm"] == info.margin_mm == plan.soft["margin_mm"] == 8.0
    assert summary["clearance_min_mm"] == info.clearance_min_mm >= 8.0
    assert summary["planned_clearance_min_mm"] >= 8.0
    scene = fixed_scene("three-arm")
    assert shapely_clearance(scene, plan.q) * 1000 >= 8.0               # the rows the board is sent
    assert "margin_mm" in r.output and "clearance_min_mm" in r.output
    # the default: soft3's execution margin
    r = CliRunner().invoke(plan_app, ["soft", "--env", "three-arm", "--out", str(out), "--json", str(js)])
    assert r.exit_code == 0, r.output
    assert json.loads(js.read_text())["margin_mm"] == 4.8


def test_a_bad_margin_is_one_line_naming_the_range(tmp_path):
    exe = str(Path(sys.executable).parent / "armbridge")
    r = subprocess.run([exe, "plan", "soft", "--env", "three-arm", "--out", str(tmp_path / "p.json"), "--margin", "80"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert lines == ["error: --margin 80 mm is outside [0, 50] mm"], lines
    assert not (tmp_path / "p.json").exists()
    r = subprocess.run([exe, "plan", "soft", "--help"], capture_output=True, text=True, timeout=120)
    assert "--margin" in r.stdout
    # a margin the start itself does not keep (seven-tube's start keeps 42.5 mm)
    r = subprocess.run([exe, "plan", "soft", "--env", "seven-tube", "--out", str(tmp_path / "p.json"), "--margin",
                        "45"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert lines == ["error: seven-tube: the start keeps 42.5 mm from the obstacles, less than the 45 mm clearance "
                     "margin; plan with a smaller --margin; no plan written"], lines
    assert not (tmp_path / "p.json").exists()


def test_the_demo_report_measures_the_executed_clearance_against_the_margin():
    """soft_report on traces of the plan itself (the arm exactly on its rows, 50 samples per move) keeps the
    margin; the same trace pushed into the pit's rim reports the contact."""
    from armbridge.demos.soft import clearance_line
    from armbridge.demos.soft_report import Trace, soft_report
    from armbridge.planning.soft.command import plan_for_pump
    from armbridge.plans.soft import soft_info

    sp = plan_for_pump("three-arm", "wjrrt", seed=0)
    plan, info = sp.plan, soft_info(sp.plan)
    Q = np.concatenate([a + np.linspace(0, 1, 50)[:, None] * (b - a) for a, b in zip(plan.q[:-1], plan.q[1:])])
    t = np.arange(len(Q)) * 0.02
    chk = sp.scene.checker()
    rep = soft_report(plan, info, Trace(t, Q, {}, {}), np.full(3, 0.072), chk)
    assert rep["margin_mm"] == 4.8 and rep["keeps_margin"] and rep["collision_free"]
    assert rep["executed_clearance_min_mm"] >= 4.8 and rep["executed_contact"] == "free"
    assert clearance_line(rep) is None
    rng = np.random.default_rng(1)
    bad = next(q for q in sp.scene.space().sample(rng, 5000) if not chk.is_valid(q) and chk.code(q) >= 0)
    Qb = np.vstack([Q, bad])
    rep = soft_report(plan, info, Trace(np.arange(len(Qb)) * 0.02, Qb, {}, {}), np.full(3, 0.072), chk)
    assert not rep["collision_free"] and not rep["keeps_margin"] and rep["executed_clearance_min_mm"] <= 0
    assert "obstacle" in rep["executed_contact"] or "between" in rep["executed_contact"]
    line = clearance_line(rep)
    assert line is not None and line.startswith("error: the executed arm touched an obstacle: least clearance ")
    assert "\n" not in line and "the plan kept 4.8 mm" in line
