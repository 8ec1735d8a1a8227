"""The MASR's clearance margin (issue 24 section 2, planning/masr/margin.py): the execution bound from the
firmware's tolerance, a path's clearance along the motion convention against shapely, plans that keep a
margin, environment files and `plan masr --margin`."""
from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Polygon

from armbridge.boards import config
from armbridge.errors import ArmbridgeError
from armbridge.planning.command import resolve_goal_ik
from armbridge.planning.margin import CLEARANCE_RES, chain_margin
from armbridge.planning.masr import rrt_star
from armbridge.planning.masr.environment import environment_from_dict, fixed_environment
from armbridge.planning.masr.margin import execution_margin, joint_tolerance, path_clearance
from tests.cli_procs import ARMBRIDGE

#: Rotation samples of the shapely check: no point moves more than this between two (m).
DENSE = 5e-5


def test_the_execution_bound_is_the_firmwares_tolerance_through_the_chain():
    cfg = config("masr_ma")
    e = (cfg.ROT_TOL_MRAD + cfg.BACKLASH_MRAD / 2) / 1000
    assert joint_tolerance() == pytest.approx(e)
    arm = fixed_environment("E1").arm  # links 0.2, 0.2, 0.2, 0.1, 0.1: reaches 0.8 + 0.6 + 0.4 + 0.2 + 0.1
    assert execution_margin(arm) == pytest.approx(e * 2.1)
    assert chain_margin([0.1, 0.1], 0.01) == pytest.approx(0.003)
    with pytest.raises(ArmbridgeError, match="finite number >= 0 rad"):
        chain_margin([0.1], -1.0)


def test_no_joint_error_within_the_tolerance_moves_the_arm_farther_than_the_bound():
    arm = fixed_environment("E1").arm
    bound, e = execution_margin(arm), joint_tolerance()
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(500):
        q = np.concatenate([rng.uniform(-1, 1, arm.n), [0.1]])
        dq = np.concatenate([rng.choice([-e, e], arm.n) * rng.uniform(0.5, 1, arm.n), [0.0]])
        worst = max(worst, float(np.abs(arm.joint_points(q + dq) - arm.joint_points(q)).max()))
    assert worst <= bound and worst > 0.5 * bound  # the bound holds and is not loose by orders of magnitude


def _shapely_clearance(env, path):
    """The least distance of a link's surface to an obstacle, every rotation of the convention sampled
    DENSE apart, by shapely."""
    arm, polys = env.arm, [Polygon(p) for p in env.obstacles]
    union = shapely.union_all(polys)
    reach = np.cumsum(np.asarray(arm.link_lengths)[::-1])[::-1]
    least = np.inf
    for k in range(len(path) - 1):
        q = np.array(path[k], float)
        shapes = [q.copy()]
        for step in arm.action_sequence(path[k], path[k + 1]):
            if step[0] == "rotate":
                j, a, b = step[1] - 1, step[2], step[3]
                for t in np.linspace(0, 1, max(2, int(np.ceil(abs(b - a) * reach[j] / DENSE)) + 1)):
                    q[j] = a + t * (b - a)
                    shapes.append(q.copy())
        shapes.append(np.array(path[k + 1], float))
        for s in shapes:
            line = LineString(arm.joint_points(s))
            least = min(least, line.distance(union) - 0.5 * arm.link_width)
    return least


@pytest.fixture(scope="module")
def e1_plans():
    env = fixed_environment("E1")
    goal_ik = resolve_goal_ik(env)[0]  # the shipped IK-NN, as `plan masr` uses it
    out = {}
    for extra in (0.0, execution_margin(env.arm)):
        chk = env.planning_checker(margin=extra)
        out[extra] = rrt_star.plan(env, iterations=1000, seed=0, goal_ik=goal_ik, checker=chk)
    return env, out


def test_path_clearance_agrees_with_shapely(e1_plans):
    env, plans = e1_plans
    for r in plans.values():
        assert r.path is not None
        ours, dense = path_clearance(env, r.path), _shapely_clearance(env, r.path)
        assert dense - 1e-6 <= ours <= dense + CLEARANCE_RES / 2 + DENSE


def test_a_plan_keeps_its_margin_and_the_margin_binds(e1_plans):
    env, plans = e1_plans
    bound = execution_margin(env.arm)
    plain, kept = path_clearance(env, plans[0.0].path), path_clearance(env, plans[bound].path)
    assert kept >= bound
    assert plain < bound  # the paper's check alone passes closer than the arm can stray: the margin changes the plan
    assert plans[bound].cost > plans[0.0].cost


def test_without_a_margin_an_environment_keeps_the_execution_bound_and_the_papers_keep_theirs(tmp_path):
    e1 = fixed_environment("E1")
    assert e1.margin == 0.0 and e1.planning_margin == 0.0  # E1-E3: the paper's check, as published
    doc = e1.to_dict()
    assert doc["margin"] == 0.0
    del doc["margin"]
    mine = environment_from_dict(doc, tmp_path / "mine.json")
    assert mine.margin is None and "margin" not in mine.to_dict()
    assert mine.planning_margin == pytest.approx(execution_margin(mine.arm))
    assert mine.planning_checker().margin == pytest.approx(0.5 * mine.arm.link_width + execution_margin(mine.arm))
    from armbridge.planning.masr.random_env import random_environment

    assert random_environment(seed=0).margin == 0.0  # Fig. 5 as the paper ran it


def test_an_environment_file_carries_its_margin_and_refuses_a_bad_one(tmp_path):
    doc = fixed_environment("E1").to_dict()
    doc["margin"] = 0.003
    env = environment_from_dict(doc, tmp_path / "m.json")
    assert env.margin == 0.003 and env.to_dict()["margin"] == 0.003
    assert env.planning_checker().margin == pytest.approx(0.5 * env.arm.link_width + 0.003)
    assert fixed_environment("E1").planning_checker().margin == 0.5 * env.arm.link_width
    for bad, words in ((0.2, "margin 200 mm is outside [0, 50] mm"), ("x", "margin (m) must be a number"),
                       (True, "margin (m) must be a number")):
        doc["margin"] = bad
        with pytest.raises(ArmbridgeError) as exc:
            environment_from_dict(doc, tmp_path / "m.json")
        assert str(exc.value).startswith(str(tmp_path / "m.json")) and words in str(exc.value)


def _plan(tmp_path, *args):
    return subprocess.run([ARMBRIDGE, "plan", "masr", "--env", "E1", "--ik", "dls",
                           "--iterations", "300", "--out", str(tmp_path / "p.json"), *args],
                          capture_output=True, text=True, timeout=600)


def test_plan_masr_reports_the_margin_the_clearance_and_the_bound(tmp_path):
    r = _plan(tmp_path, "--margin", "3", "--json", str(tmp_path / "s.json"))
    assert r.returncode == 0, r.stdout + r.stderr
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["margin_mm"] == 3.0 and s["clearance_min_mm"] >= 3.0
    assert s["execution_bound_mm"] == pytest.approx(execution_margin(fixed_environment("E1").arm) * 1000)
    prov = json.loads((tmp_path / "p.json").read_text())["provenance"]
    assert prov["margin_mm"] == 3.0 and prov["clearance_min_mm"] == pytest.approx(s["clearance_min_mm"], abs=1e-3)
    # the note says so exactly when the path passes closer than the arm can stray
    assert ("can stray" in r.stdout) == (s["clearance_min_mm"] < s["execution_bound_mm"])


def test_a_margin_out_of_range_is_one_line_and_writes_nothing(tmp_path):
    r = _plan(tmp_path, "--margin", "80")
    assert r.returncode != 0
    assert "error: --margin 80 mm is outside [0, 50] mm" in r.stdout + r.stderr
    assert "Traceback" not in r.stdout + r.stderr
    assert not (tmp_path / "p.json").exists()


def test_bench_masr_plan_margin_part_keeps_every_margin():
    from armbridge.bench.masr_margin import FACTORS, margins

    env = fixed_environment("E1")
    m = margins(1, resolve_goal_ik(env)[0])
    assert m["execution_bound_mm"] == pytest.approx(execution_margin(env.arm) * 1000)
    for name, rows in m["environments"].items():
        assert [r["factor"] for r in rows] == list(FACTORS)
        assert rows[0]["success"] == 1, name  # the paper's check solves E1-E3
        for r in rows:
            if r["success"]:
                assert r["least_clearance_mm"] >= r["margin_mm"] - 1e-6, (name, r)


def test_a_margin_that_leaves_no_path_says_so_and_writes_nothing(tmp_path):
    r = _plan(tmp_path, "--margin", "50", "--iterations", "100")
    assert r.returncode != 0 and "Traceback" not in r.stdout + r.stderr
    assert "found no path to the goal of E1 in 100 iterations" in r.stdout + r.stderr
    assert "or a smaller --margin" in r.stdout + r.stderr
    assert not (tmp_path / "p.json").exists()


def test_a_run_of_a_planned_path_reports_its_planned_clearance_and_margin(tmp_path):
    """`plan masr --margin 3` on E1, then the plan on the emulated MA (lockstep): the run's summary carries
    the plan's margin and least clearance beside the MA's pose error."""
    from armbridge.executor.run import run_plan

    r = _plan(tmp_path, "--margin", "3", "--json", str(tmp_path / "s.json"))
    assert r.returncode == 0, r.stdout + r.stderr
    s = json.loads((tmp_path / "s.json").read_text())
    run = run_plan(tmp_path / "p.json", "emu:masr_ma?speed=0&seed=5", tmp_path / "r.rrd", progress=False, home=True)
    assert run.masr["margin_mm"] == 3.0
    assert run.masr["clearance_min_mm"] == pytest.approx(s["clearance_min_mm"], abs=1e-3)
    assert run.completed
