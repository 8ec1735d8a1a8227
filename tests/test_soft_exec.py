"""The soft arm's plans for the pump board (planning/soft/waypoints.py, plan_file.py, `armbridge plan
soft`) and the demo end to end: WJRRT on the three-arm scene, executed by the pump board's real .elf in
simavr (`emu:arduino_pump?speed=0`), the recording read back with rerun's own reader.

The waypoint criterion is checked on hand-worked cases: a joint-3-only excursion whose shape
distance is the tip's chord 2 l sin(theta / 2), a detour around an obstacle, the dead-band snapping
and its collision re-check, the timing model against the pneumatic plant itself.
"""
from __future__ import annotations

import io
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from armbridge.emulator.pump_plant import PumpParams, PumpPlant
from armbridge.errors import ArmbridgeError
from armbridge.planning.soft import waypoints as W
from armbridge.planning.soft.space import ChainChecker
from armbridge.robots import SOFT3

L = SOFT3.link_lengths
FREE = ChainChecker.create(SOFT3, [])


class Cfg:
    """The pump firmware's constants (config.h) that the timing model reads."""

    DBAND_DEFAULT_MRAD = 70
    KP_DEFAULT = 4000
    KP_INFLATE_PERMILLE = 600
    DUTY_MAX_INFLATE = 700
    DUTY_MAX_DEFLATE = 1000
    DUTY_MIN = 120
    FOLLOW_ERR_MRAD = 300
    FOLLOW_ERR_MS = 2000


def chord(theta: float, length: float = 0.1) -> float:
    """How far the tip of a last link of `length` moves when its joint turns by theta."""
    return 2 * length * math.sin(theta / 2)


# ---------------------------------------------------------------- (a) the tracking error

def test_the_shape_distance_of_a_last_joint_turn_is_the_tips_chord():
    assert W.shape_distance(L, [0, 0, 0], [0, 0, 0.3]) == pytest.approx(chord(0.3))
    # joint 1 turns the whole arm: the tip (0.3 m out) moves farthest
    assert W.shape_distance(L, [0, 0, 0], [0.2, 0, 0]) == pytest.approx(chord(0.2, 0.3))
    assert W.reach_of(L).tolist() == pytest.approx([0.3, 0.2, 0.1])


def test_the_tracking_error_is_two_sided():
    """A segment that overshoots the planned edge (to 0.4 where the plan stops at 0.2) is off by the
    chord of the overshoot (the segment-to-plan side); one that stops short, by the same."""
    planned = np.array([[0, 0, 0], [0, 0, 0.2]])
    h = 1e-4
    assert W.tracking_error(planned, L, planned[0], planned[1], h) == pytest.approx(0.0, abs=1e-12)
    assert W.tracking_error(planned, L, [0, 0, 0], [0, 0, 0.4], h) == pytest.approx(chord(0.2), abs=h / 2)
    assert W.tracking_error(planned, L, [0, 0, 0], [0, 0, 0.1], h) == pytest.approx(chord(0.1), abs=h / 2)


def excursion(theta: float, k: int = 41) -> np.ndarray:
    """Joint 3 out to theta and back, k nodes."""
    s = np.sin(np.linspace(0, np.pi, k))[:, None]
    return s * np.array([0, 0, theta])


@pytest.mark.parametrize("theta, kept", [(0.05, False), (0.2, True)])
def test_an_excursion_is_kept_only_beyond_the_tolerance(theta, kept):
    """Out and back along joint 3: the start-to-goal segment stands still, so its error is the chord
    of the excursion, 5.0 mm for 0.05 rad (dropped at 10 mm), 20.0 mm for 0.2 rad (kept)."""
    path = excursion(theta)
    nodes = W.select_nodes(path, L, 0.01, FREE.motion_valid)
    assert nodes[0] == 0 and nodes[-1] == len(path) - 1
    if kept:
        # One node between: it must come within the tolerance (less h / 2) of the farthest shape, as
        # the segment from it back to the start covers everything below it.
        assert len(nodes) == 3
        assert chord(theta - path[nodes[1], 2]) <= 0.01 - 0.01 / 8
        assert W.tracking_error(path, L, path[0], path[-1], 1e-4) == pytest.approx(chord(theta), abs=1e-4)
    else:
        assert nodes.tolist() == [0, len(path) - 1]


def test_a_straight_path_keeps_its_ends():
    path = np.linspace([0, 0, 0], [0.4, 0.8, 0.9], 50)
    assert W.select_nodes(path, L, 0.005, FREE.motion_valid).tolist() == [0, 49]


# An obstacle (found by search, checked below) that the corner of the L-shaped path avoids and its diagonal
# does not.
TRIANGLE = [[0.2469, 0.1566], [0.2529, 0.1566], [0.2499, 0.1626]]


def test_a_detour_around_an_obstacle_keeps_the_fewest_nodes():
    """Joint 2 bends, then joint 1 turns; the diagonal collides: with a tolerance too loose to matter
    the fewest nodes are three (start, one on the L, goal), and every chosen segment is free."""
    path = np.vstack([np.linspace([0, 0, 0], [0, 0.9, 0], 21), np.linspace([0, 0.9, 0], [0.5, 0.9, 0], 21)[1:]])
    chk = ChainChecker.create(SOFT3, [np.array(TRIANGLE)])
    assert chk.path_problem(path) is None and not chk.motion_valid(path[0], path[-1])
    assert W.select_nodes(path, L, 1.0, FREE.motion_valid).tolist() == [0, 40]
    nodes = W.select_nodes(path, L, 1.0, chk.motion_valid)
    assert len(nodes) == 3 and nodes[0] == 0 and nodes[-1] == 40
    assert all(chk.motion_valid(path[a], path[b]) for a, b in zip(nodes[:-1], nodes[1:]))


def test_a_bad_tolerance_is_refused():
    with pytest.raises(ArmbridgeError, match="tracking tolerance"):
        W.select_nodes(excursion(0.1), L, 0.0, FREE.motion_valid)


# ---------------------------------------------------------------- (c) the dead band

@pytest.mark.parametrize("values, snapped", [
    ([0, 0.03, 0.1, 0.12, 0.3], [0, 0, 0.1, 0.1, 0.3]),     # below the band: hold; at or above: move
    ([0, 0.2, 0.25], [0, 0.25, 0.25]),                      # the goal's last move merged back into the one before
    ([0, 0.02, 0.04], [0, 0.04, 0.04]),                     # the joint's only move, smaller than the band
    ([0.3, 0.3, 0.3], [0.3, 0.3, 0.3]),                     # no move at all
])
def test_changes_below_the_dead_band_are_held(values, snapped):
    q = np.zeros((len(values), 3))
    q[:, 1] = values
    out, changed = W.snap(q, 0.07, FREE.motion_valid)
    assert out[:, 1].tolist() == pytest.approx(snapped)
    assert (out[:, [0, 2]] == 0).all() and changed[:, 1].tolist() == [a != b for a, b in zip(values, snapped)]
    moves = np.abs(np.diff(out[:, 1]))
    moves = moves[moves > 0]
    assert len(moves) <= 1 or np.all(moves >= 0.07 - 1e-12)      # at least the band, or the only move


def test_a_snapped_segment_that_collides_gets_its_planned_values_back():
    """Joint 1 would be held at 0.3 (a change of 0.25 under a 0.3 band); held, the arm sweeps through a
    triangle that the planned values pass by: the waypoint keeps its planned joint 1."""
    q = np.array([[0.3, 0, 0], [0.05, 0.5, 0], [0.0, 0.5, 0.4]])
    held, _ = W.snap(q, 0.3, FREE.motion_valid)
    assert held[1].tolist() == [0.3, 0.5, 0.0]
    chk = ChainChecker.create(SOFT3, [np.array([[0.261, 0.1321], [0.271, 0.1321], [0.266, 0.1241]])])
    assert not chk.motion_valid(held[0], held[1]) and chk.motion_valid(q[0], q[1]) and chk.motion_valid(q[1], q[2])
    out, changed = W.snap(q, 0.3, chk.motion_valid)
    assert out.tolist() == q.tolist() and not changed.any()


# ---------------------------------------------------------------- (d) timing

def hand_opening(**kw) -> W.Opening:
    """An opening easy to integrate by hand: duty = e beyond the band (no dead zone, floor or cap),
    10 mm/s of plunger per unit duty, 1 mm to open."""
    args = dict(volume_mm=1.0, push_mm_s=10.0, dead=0.0, gain=1.0, floor=0.0, cap=10.0, follow_rad=1.0, follow_s=10.0)
    return W.Opening(**{**args, **kw})


def hand_timing() -> W.PumpTiming:
    n = np.ones(3)
    return W.PumpTiming(band=0.07 * n, rate_in=0.1 * n, rate_de=0.2 * n, settle_in_s=0.5 * n, settle_de_s=0.8 * n,
                        snap_rad=0.15 * n, rest=np.zeros(3), opening=hand_opening())


def test_the_opening_time_integrates_the_push():
    """Ramp at 0.1 rad/s, band 0.07: the push starts at 0.7 s with duty 0.1 t, 10 mm/s per unit:
    0.5 (t^2 - 0.49) = 1 mm at t = sqrt(2.49). A 0.1 rad move stops the lag at 0.1 after 1 s
    (0.255 mm by then), then pushes 1 mm/s: 1.745 s. A move inside the band never opens."""
    op = hand_opening()
    assert op.time(0.3, 0.1, 0.07) == pytest.approx((math.sqrt(2.49), 0.1), abs=0.006)
    assert op.time(0.1, 0.1, 0.07) == pytest.approx((1.745, 0.1), abs=0.006)
    assert op.time(0.05, 0.1, 0.07)[0] == math.inf
    # 4 mm to open, FOLLOW at 0.2 rad for 1 s: at 0.1 rad/s the lag stays above 0.2 for 0.91 s (> 0.75):
    # 0.08 rad/s still 0.78 s; 0.064 rad/s: opens at sqrt(4 / 0.32 + 1.196) = 3.70 s, 0.58 s above.
    t, rate = hand_opening(volume_mm=4.0, follow_rad=0.2, follow_s=1.0).time(0.5, 0.1, 0.07)
    assert rate == pytest.approx(0.064) and t == pytest.approx(math.sqrt(4 / 0.32 + (0.07 / 0.064) ** 2), abs=0.006)


def test_durations_follow_the_asymmetry():
    """Move = the longest ramp; hold = until the slowest joint rests (hand_timing)."""
    q = np.array([[0.3, 0, 0],        # closed joint 1 inflates 0.3: ramp 3 s, opens at 1.58; rests 3 + 0.8
                  [0.1, 0, 0],        # deflates 0.2 at 0.2 rad/s: 1 s + 0.8
                  [0.1, 0.1, 0],      # closed joint 2 inflates 0.1: ramp 1 s, opens at 1.745, + 0.8
                  [0.1, 0.1, 0.05],   # closed joint 3, 0.05 inside the band: never opens, already there
                  [0.0, 0.1, 0.05],   # joint 1 back to straight: 0.5 s + 0.8; closed again
                  [0.3, 0.1, 0.05]])  # so it opens again
    move, hold = W.durations(q, hand_timing())
    assert move.tolist() == pytest.approx([3.0, 1.0, 1.0, 0.5, 0.5, 3.0], abs=1e-9)
    assert hold.tolist() == pytest.approx([0.8, 0.8, 1.545, 0.0, 0.8, 0.8], abs=0.006)


def board_timing() -> W.PumpTiming:
    return W.pump_timing(PumpParams(), Cfg, SOFT3.q_max, SOFT3.v_max)


def test_the_rates_are_what_the_plant_does_at_the_controllers_ceilings():
    """The plant itself (emulator/pump_plant.py), driven at the inflation ceiling (700 per-mille) from
    straight: it opens after about the opening volume, then bends no slower than the model's rate at
    that duty (rate_in / RATE_FRACTION) over its range; deflating at full duty, no slower than
    rate_de / RATE_FRACTION. The asymmetry: inflation is the slower of the two."""
    tm = board_timing()
    assert np.all(tm.rate_in < tm.rate_de) and np.all(tm.rate_de <= SOFT3.v_max)
    plant = PumpPlant(SOFT3.q_max, [(205, 0, 716, 1047)] * 3)
    dt, t, log = 0.01, 0.0, []
    plant.drive([0.7] * 3)
    while t < 12.0:
        t += dt
        plant.advance_to(t)
        log.append((t, plant.q.copy()))
    ts = np.array([r[0] for r in log])
    qs = np.array([r[1] for r in log])
    op = tm.opening
    at_cap = op.volume_mm / (op.push_mm_s * (0.7 - op.dead))   # 12.2 mm at 13.7 mm/s: 0.89 s
    for j in range(3):
        opened = np.nonzero(qs[:, j] > 0)[0][0]
        # the plant starts 2 mm in (x0_mm): it opens a little sooner than the model's from atmospheric
        assert 0.75 * at_cap <= ts[opened] <= at_cap + 0.05, (ts[opened], at_cap)
        assert qs[opened + 10, j] >= 0.9 * tm.snap_rad[j]        # and snaps through at once (0.1 s)
        band = (qs[:, j] > tm.snap_rad[j] + 0.05) & (qs[:, j] < 0.9 * SOFT3.q_max[j])
        rate = np.diff(qs[band, j]) / dt
        assert rate.min() >= 0.97 * tm.rate_in[j] / W.RATE_FRACTION, j
    plant.drive([-1.0] * 3)
    t0, log = t, []
    while t < t0 + 6.0:
        t += dt
        plant.advance_to(t)
        log.append(plant.q.copy())
    qs = np.array(log)
    for j in range(3):
        falling = (qs[:, j] < 0.8 * SOFT3.q_max[j]) & (qs[:, j] > 0.2)
        rate = -np.diff(qs[:, j])[falling[1:]] / dt
        assert rate.size and np.median(rate) >= 0.9 * tm.rate_de[j] / W.RATE_FRACTION, j


def test_a_gentler_push_opens_later_and_the_settles_are_finite():
    tm = board_timing()
    op, r = tm.opening, float(tm.rate_in[2])
    assert op.time(0.5, r / 2, 0.07)[0] > op.time(0.5, r, 0.07)[0]     # a slower ramp: a smaller lag
    assert op.time(0.08, r, 0.07)[0] > op.time(0.5, r, 0.07)[0]        # a small move: a gentle push
    for x in (tm.settle_in_s, tm.settle_de_s):
        assert np.all(np.isfinite(x) & (x > 0) & (x < 5))
    assert tm.band.tolist() == [0.07] * 3
    assert np.all((tm.snap_rad > 0.1 * SOFT3.q_max) & (tm.snap_rad < 0.28 * SOFT3.q_max))  # below p_open's branch


# ---------------------------------------------------------------- the plan file and `armbridge plan soft`

def test_plan_soft_writes_a_plan_the_executor_takes_and_a_png(tmp_path):
    """The CLI on the demo's scene: a valid armbridge-plan (the executor's own validation) whose
    provenance holds the scene, the planner, the whole planned path and the selection; the rows are
    each pose then its hold; the waypoints are nodes of the planned path, snapped only below the band;
    the PNG is a PNG."""
    from typer.testing import CliRunner

    from armbridge.planning.command import plan_app
    from armbridge.plans.soft import recording_layers, soft_info
    from armbridge.plans.format import load_plan

    out, png, js = tmp_path / "soft.json", tmp_path / "soft.png", tmp_path / "summary.json"
    r = CliRunner().invoke(plan_app, ["soft", "--env", "three-arm", "--out", str(out), "--seed", "0",
                                      "--png", str(png), "--json", str(js)])
    assert r.exit_code == 0, r.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    plan = load_plan(out)
    info = soft_info(plan)
    assert info is not None and info.scene == "three-arm" and info.planner == "wjrrt"
    sec = plan.soft
    assert sec["seed"] == 0 and len(sec["planned_path"]) == len(info.planned_path) >= 2
    crit = sec["waypoints"]
    assert crit["planned_nodes"] == len(info.planned_path) and crit["tolerance_m"] == 0.01
    nodes = info.nodes
    assert nodes[0] == 0 and nodes[-1] == len(info.planned_path) - 1 and np.all(np.diff(nodes) > 0)
    poses = plan.q[info.pose_rows]
    assert np.abs(poses - info.planned_path[nodes]).max() < 0.07 * 2 + 1e-6     # snapping stays near the nodes
    assert np.allclose(poses[-1], info.planned_path[-1], atol=1e-6)              # the goal as planned
    for j in range(3):                                   # (c) on the file: a move is the band or more, or the only one
        moves = np.abs(np.diff(poses[:, j]))
        moves = moves[moves > 1e-9]
        assert len(moves) <= 1 or np.all(moves >= 0.07 - 1e-6), (j, moves)
    move = np.asarray(crit["move_s"])
    assert plan.durations[info.pose_rows] == pytest.approx(move, abs=1e-3)
    summary = json.loads(js.read_text())
    assert summary["waypoints"] == len(poses) and summary["planned_nodes"] == len(info.planned_path)
    layers = recording_layers(plan)
    assert set(layers) == {"world/obstacles", "plan/planned_tip", "plan/shapes"}
    assert len(layers["world/obstacles"][0]) == len(info.obstacles) and len(layers["plan/shapes"][0]) == len(poses)


def test_the_demo_writes_its_plan_only_when_asked(tmp_path):
    import io

    from rich.console import Console

    from armbridge.demos import DemoOptions, default_port, get_demo, run_demo
    from armbridge.plans.soft import soft_info
    from armbridge.plans.format import load_plan

    assert default_port("soft") == default_port("soft3") == "emu:arduino_pump"
    assert get_demo("soft").robot == "soft3"
    out = tmp_path / "demo.json"
    run_demo(DemoOptions(port="emu:arduino_pump", write_plan=out, seed=0), "soft", Console(file=io.StringIO()))
    info = soft_info(load_plan(out))
    assert info is not None and info.scene == "three-arm" and info.planner == "wjrrt"


def test_a_bad_scene_file_is_one_line_naming_the_field(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "armbridge-chain-env", "version": 1, "robot": "soft3", "obstacles": [], '
                   '"start": [0, 0, 1.2], "goal": {"point": [0.2, 0.1], "tol": 0.01}}')
    r = subprocess.run([str(Path(sys.executable).parent / "armbridge"), "plan", "soft", "--env", str(bad), "--out",
                        str(tmp_path / "p.json")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {bad}: start[2]") and "range" in lines[0], lines
    assert not (tmp_path / "p.json").exists()


# ---------------------------------------------------------------- the demo end to end in simavr

BAND = 0.070          # config.h DBAND_DEFAULT_MRAD
TOL = BAND + 1.047 / 511   # the settle tolerance: the band and one count of a bend sensor (executor/settle.py)


def needs_simavr() -> None:
    from require import missing

    if shutil.which("avr-gcc") is None or shutil.which("make") is None:
        missing("avr-gcc/make missing: the AVR toolchain (scripts/setup.sh as root installs it)")
    if not Path("/usr/include/simavr/sim_avr.h").is_file():
        missing("libsimavr-dev missing (scripts/setup.sh as root installs it)")


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """`armbridge demo --robot soft3` (seed 0) on emu:arduino_pump?speed=0, with the emulator kept for a look
    at the board's own records (its log of completed waypoints, the plant's true angles)."""
    needs_simavr()
    import io

    from rich.console import Console

    from armbridge.demos import DemoOptions
    from armbridge.demos.soft import execute
    from plan_runs import opened_ports

    rrd = tmp_path_factory.mktemp("soft") / "demo.rrd"
    out = io.StringIO()
    with opened_ports() as opened:
        run = execute(DemoOptions(port="emu:arduino_pump?speed=0", rrd=rrd, seed=0), Console(file=out, width=160))
        emu = opened[0].emulator
        yield {"run": run, "emu": emu, "rrd": rrd, "executed": list(emu.executed), "track": list(emu.hal.track),
               "text": out.getvalue()}


@pytest.mark.hil
def test_the_demo_settles_every_joint_in_its_dead_band_at_every_waypoint(demo):
    from plan_runs import assert_executed_once_with_values

    run, emu = demo["run"], demo["emu"]
    plan, rep, s = run.planning.plan, run.report, run.summary
    assert s.completed and s.final_state == "IDLE" and s.fw == "arduino_pump", s
    assert_executed_once_with_values(emu, plan)                      # the board's own log, with the values sent
    assert rep["scene"] == "three-arm" and rep["planner"] == "wjrrt" and rep["waypoints"] == len(run.planning.waypoints.q)
    assert rep["all_settled"], rep["poses"]
    assert rep["settle_tolerance_rad"] == pytest.approx([TOL] * 3, abs=1e-4)
    done = {wid: t / 1000.0 for t, wid, _ in demo["executed"]}
    rows = [p["row"] for p in rep["poses"]]
    holds = run.planning.waypoints.hold_s
    track = demo["track"]
    for i, p in enumerate(rep["poses"]):
        target = np.asarray(p["target"])
        assert p["inside_band"] and np.all(np.abs(np.asarray(p["settled"]) - target) <= TOL + 1e-6), p
        assert p["settle_s"] is not None and 0.0 <= p["settle_s"] <= max(holds[i], 0.1) + 0.05, (i, p, holds[i])
        # The plant's true angles at the end of the pose's window (the next move's start) inside the band
        # (the sensor's noise on top of the board's reading): from the emulator, not the host.
        end = done[rows[i + 1] - 1] if i + 1 < len(rows) else track[-1][0]
        true = [r[1] for r in track if end - 0.1 <= r[0] <= end]
        assert true and np.all(np.abs(np.asarray(true[-1]) - target) <= BAND + 0.01), (i, true[-1], target)
    # Summary fields present and sane: tip errors within what the band allows (each joint off by at most
    # TOL moves the tip by at most TOL times its length to the tip), times ordered, no collision.
    bound = TOL * float(W.reach_of(L).sum())
    assert 0.0 <= rep["tip_error_m"]["mean"] <= rep["tip_error_m"]["max"] <= bound
    errs = np.degrees(np.abs([p["error_rad"] for p in rep["poses"]]))
    assert rep["settled_joint_error_deg"]["max"] == pytest.approx(errs.max(), abs=2e-3)
    assert rep["settled_joint_error_deg"]["mean"] == pytest.approx(errs.mean(), abs=2e-3)
    assert rep["settled_joint_error_deg"]["max"] <= np.degrees(TOL) + 1e-3
    assert 0.0 <= rep["settle_s"]["mean"] <= rep["settle_s"]["max"]
    assert 0.0 <= rep["path_deviation_m"]["mean"] <= rep["path_deviation_m"]["max"] <= bound + 0.01
    assert rep["collision_free"] and rep["min_clearance_m"] > 0
    # the executed arm keeps the margin its plan was planned for (soft3's 4.8 mm; planning/soft/margin.py)
    assert rep["margin_mm"] == 4.8 and rep["keeps_margin"] and rep["executed_clearance_min_mm"] >= 4.8
    assert rep["planned_s"] == pytest.approx(plan.total_duration, abs=1e-3)
    assert rep["planned_arrival_s"] - 0.02 <= rep["executed_s"] <= rep["planned_s"] + 0.05
    assert s.measured_duration_s == pytest.approx(plan.total_duration, abs=0.05)
    assert rep["telemetry_samples"] > 10 * len(rows)
    assert "every joint settled in its band: yes" in demo["text"].replace("\n", " ").replace("  ", " ")


@pytest.mark.hil
def test_the_recording_shows_the_obstacles_the_planned_path_and_the_executed_one(demo):
    from test_recording import layout, read

    from armbridge.plans.soft import soft_info, to_base_frame

    run = demo["run"]
    plan, scene = run.planning.plan, run.planning.scene
    info = soft_info(plan)
    data = read(demo["rrd"])
    obstacles = data["/world/obstacles"]["columns"]["LineStrips2D:strips"][0]
    assert len(obstacles) == len(scene.obstacles)
    for ring, poly in zip(obstacles, scene.obstacles):
        assert np.allclose(np.asarray(ring)[: len(poly)], to_base_frame(poly, scene.base), atol=1e-6)
    planned = np.asarray(data["/plan/planned_tip"]["columns"]["LineStrips2D:strips"][0][0])
    assert planned.shape == (len(info.planned_path), 2)
    assert np.allclose(planned, plan.robot.ee_point(info.planned_path), atol=1e-6)
    shapes = data["/plan/shapes"]["columns"]["LineStrips2D:strips"][0]
    assert len(shapes) == len(info.pose_rows)
    # the executed arm over time and the whole executed tip trace, on the board's timeline
    assert data["/arm/links"]["rows"] >= 0.9 * run.summary.telemetry_samples
    assert "board_time" in data["/arm/links"]["timelines"]
    trace = np.asarray(data["/trace/tip"]["columns"]["LineStrips2D:strips"][0][0])
    assert len(trace) >= 0.9 * run.summary.telemetry_samples
    # every entity drawn in the same 2-D arm view
    views = []

    def walk(node):
        if "view" in node:
            views.append(node)
        for c in node.get("children", []):
            walk(c)

    walk(layout(demo["rrd"]))
    arm = next(v for v in views if v["name"] == "arm")
    assert arm["view"] == "2D"
    for ent in ("world/obstacles", "plan/planned_tip", "plan/shapes", "arm/**", "trace/**"):
        assert ent in arm["contents"], arm["contents"]
    assert any(v["name"] == "syringe positions" for v in views)


@pytest.mark.hil
def test_the_run_summary_checks_the_goal_against_where_the_tip_ended(demo):
    """The summary's goal (docs/formats.md §3): the scene's tip goal against the last sample, the
    same distance the demo's report measures from the recording; `reached` by the tolerance."""
    run = demo["run"]
    g = run.summary.goal
    assert g["what"] == "tip" and g["tolerance_mm"] == pytest.approx(run.report["goal_tol_m"] * 1000)
    assert g["distance_mm"] == pytest.approx(run.report["goal_distance_m"] * 1000, abs=0.5)
    assert g["reached"] == (g["distance_mm"] <= g["tolerance_mm"])
    assert run.summary.goal_missed == (not g["reached"])


def test_a_completed_run_that_missed_its_goal_exits_3(monkeypatch, tmp_path):
    """Exit codes (docs/formats.md §7): 0 for a run that reached its goal, 3 for one that ran
    to its end with the arm outside the goal's tolerance, after the summary is written."""
    import json

    import typer
    from rich.console import Console

    import armbridge.executor.command as cmd
    from armbridge.executor.summary import Summary
    from armbridge.executor.tracking import goal_check

    def fake_run(distance_m):
        def run_plan(*a, **kw):
            s = Summary(plan="p.json", port="emu:arduino_pump", rrd=None, robot="soft3", waypoints_total=2,
                        waypoints_done=2)
            s.goal = goal_check("tip", distance_m, 0.002)
            return s
        return run_plan

    out = tmp_path / "s.json"
    monkeypatch.setattr(cmd, "run_plan", fake_run(0.001))
    assert cmd.run_and_report("p.json", "emu:x", None, 50, str(out), False, False, Console(file=io.StringIO()))
    monkeypatch.setattr(cmd, "run_plan", fake_run(0.0086))
    with pytest.raises(typer.Exit) as exit_:
        cmd.run_and_report("p.json", "emu:x", None, 50, str(out), False, False, Console(file=io.StringIO()))
    assert exit_.value.exit_code == 3
    s = json.loads(out.read_text())
    assert s["completed"] and s["goal"]["reached"] is False and s["goal"]["distance_mm"] == pytest.approx(8.6)
