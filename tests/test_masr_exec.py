"""MASR plans executed end to end on the emulated mobile actuator (issue 11, sections 3-4).

Every plan here is planned in the test itself (MASR-RRT* with the shipped
IK-NN, a few hundred iterations, seeded; nothing is cached between tests),
run by the executor (`run_plan` / `armbridge run --home`) on the MA's own
firmware in the emulator (`emu:masr_ma?speed=0`: lockstep, about 25x real
time), and judged against the truth the host cannot see: the plant's q
through MasrArm.fk for the final pose, and the board's own log of completed
actions (`EmulatedBoard.executed`) for exactly-once.

A reset mid-plan: the board persists `m = 1` while it has actions, so after a
reset it refuses MV/ROT UNHOMED. The host does not re-home on its own (a joint
that was turning when the board reset has a stale angle, so resuming would
put the arm silently wrong): the run stops with one line that says so and
sends the e-stop. A reset at rest keeps d and every angle, and the rest of
the plan runs.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import armbridge.link.transport as transport
from armbridge.emulator import EmulatedBoard
from armbridge.errors import ArmbridgeError
from armbridge.executor.client import BoardClient
from armbridge.executor.masr import board_ramps, masr_commands, planned_time
from armbridge.executor import estop as executor_estop
from armbridge.executor.run import RunFailed, run_plan
from armbridge.executor.summary import Summary
from armbridge.geometry import wrap_angle
from armbridge.planning.command import resolve_goal_ik
from armbridge.planning.masr.environment import load_environment
from armbridge.planning.masr.plan_file import load_masr_plan, save_masr_plan
from armbridge.planning.masr.rrt_star import plan as plan_rrt
from plan_runs import lockstep_ports, ports, wave_plan  # noqa: F401 - the fixture
from test_emulator import Lockstep
from test_recording import read

ARMBRIDGE = str(Path(sys.executable).parent / "armbridge")
# (iterations, planner seed) per environment: small, seeded, each solved.
PLANS = {"E1": (200, 0), "E2": (100, 0), "E3": (200, 1)}
TIME_TOL = 0.10     # the issue: executed within 10 % of the planned time


def plan_file(name: str, tmp_path: Path) -> Path:
    """MASR-RRT* in environment `name` with the shipped IK-NN, written as a plan file."""
    env = load_environment(name)
    goal_ik, ik = resolve_goal_ik(env)
    assert ik.startswith("IK-NN"), ik                     # the shipped network, not the DLS fallback
    iterations, seed = PLANS[name]
    result = plan_rrt(env, iterations=iterations, goal_ik=goal_ik, seed=seed)
    assert result.path is not None, f"no path in {name}"
    return save_masr_plan(env, result.path, tmp_path / f"{name}.json",
                          {"tool": "tests", "iterations": iterations, "seed": seed})


def true_errors(mp, q) -> tuple[float, float]:
    """(dp m, dphi rad) of the MA pose of the true q against the plan's goal."""
    pose = mp.arm.fk(np.asarray(q, float))
    goal = np.asarray(mp.env.goal_pose, float)
    return float(np.hypot(*(pose[:2] - goal[:2]))), float(abs(wrap_angle(pose[2] - goal[2])))


def assert_each_action_once(emu, commands) -> None:
    """The board's own log: every command exactly once, in order, with the arguments sent."""
    assert [wid for _, wid, _ in emu.executed] == list(range(len(commands))), emu.executed
    assert [tuple(args) for _, _, args in emu.executed] == [tuple(a) for _, a in commands]


def assert_like_with_like(s, mp, emu) -> None:
    """The summary compares the plan with the same actions executed; the setup (HOME, the joints to
    the plan's start, the MV to its start d) is reported apart, and d's figures are in mm, not mrad."""
    setup = len(masr_commands(mp, home=True)[1]) - len(mp.steps())
    assert s.setup_steps == setup == 2 + mp.arm.n
    done_s = [ms / 1000.0 for ms, _, _ in emu.executed]                   # the board's own DONE times
    assert s.planned_duration_s == pytest.approx(planned_time(mp)) and planned_time(mp) > mp.total_time
    assert s.measured_duration_s == pytest.approx(done_s[-1] - done_s[setup - 1], abs=0.011)
    assert s.measured_duration_s == pytest.approx(s.masr["executed_s"])
    assert 0.99 <= s.measured_duration_s / s.planned_duration_s <= 1.0 + TIME_TOL
    assert 0 < s.setup_duration_s <= done_s[setup - 1] + 0.011
    # tracking: the plan's own actions only (the setup's turns are up to 1.7 rad off the plan's path)
    run_s = s.measured_duration_s + 0.1
    assert all(0 < tr.samples <= run_s * 50 for tr in s.tracking_plan.values())   # 50 Hz telemetry
    assert all(0 < tr.samples <= run_s * 50 for tr in s.tracking_setpoint.values())
    assert max(tr.max for name, tr in s.tracking_plan.items() if name != "d") < 0.05
    assert s.joint_units == {**{f"theta_{j}": "rad" for j in range(1, mp.arm.n + 1)}, "d": "m"}
    table = render(s.table())
    assert re.search(r"tracking d \(rms / max\) .*set point [\d.]+ / [\d.]+; plan [\d.]+ / [\d.]+ mm", table)
    assert re.search(r"tracking theta_1 \(rms / max\) .*mrad", table) and "mrad" not in _row(table, "tracking d")
    assert re.search(rf"setup before the plan \(apart\) .*{setup} actions, {s.setup_duration_s:.3f} s", table)
    assert re.search(rf"duration planned / measured .*{s.planned_duration_s:.3f} s / {s.measured_duration_s:.3f} s",
                     table)


def assert_dead_reckoning_reported(s, emu) -> None:
    """The summary's dead reckoning is the board's own (the magnet it re-anchored at last, the wheel's travel
    since) and, with no slip beyond the model, the bound holds the truth."""
    m, loc, cfg = s.masr, emu.board.loc, emu.cfg
    assert m["last_magnet"] == loc.mag == emu.hal.hall_log[-1][1]
    travel = loc.travel * loc.q                                   # the board's: since its last re-anchor
    # it re-anchors at the edge, w before the magnet (d := r_j - w on the way it came), and stops past it
    assert abs(travel - m["dead_reckoning_mm"]) <= cfg.HALL_WINDOW_MM + 1.5
    assert m["slip_bound"] == cfg.SLIP_MAX
    assert m["d_bound_mm"] == pytest.approx(loc.err() + (cfg.STOP_TOL_MM if m["dead_reckoning_mm"] > 0 else 0.0),
                                            abs=cfg.SLIP_MAX * (cfg.HALL_WINDOW_MM + 1.5))
    assert abs(emu.plant.d * 1000.0 - loc.d()) <= m["d_bound_mm"]   # the truth, within the board's bound


def render(table) -> str:
    from rich.console import Console

    console = Console(width=240, record=True, file=open(os.devnull, "w"))
    console.print(table)
    return console.export_text()


def _row(table: str, start: str) -> str:
    return next(ln for ln in table.splitlines() if start in ln)


def one_error_line(proc) -> str:
    err = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith("error: "), proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr
    return err[0]


# ---------------------------------------------------------------- the planned time


def test_trapezoid_time_is_the_ramped_profile():
    from armbridge.plans.masr import trapezoid_time
    v, a = 0.1, 0.8                                   # the MA: 100 mm/s, 800 mm/s^2
    assert trapezoid_time(0.0, v, a) == 0.0
    assert trapezoid_time(0.3, v, a) == pytest.approx(0.3 / v + v / a)     # reaches v: v / a over |x| / v
    assert trapezoid_time(-0.3, v, a) == trapezoid_time(0.3, v, a)
    x = 0.5 * v * v / a                               # never reaches v: a triangle, 2 sqrt(x / a)
    assert trapezoid_time(x, v, a) == pytest.approx(2.0 * np.sqrt(x / a))
    edge = v * v / a                                  # the two meet where the ramps just reach v
    assert trapezoid_time(edge, v, a) == pytest.approx(2.0 * np.sqrt(edge / a))
    assert trapezoid_time(0.3, v, 0.0) == pytest.approx(0.3 / v)           # no ramp: eq. (8)'s |x| / v


def test_planned_time_adds_each_steps_ramps_to_tau(tmp_path):
    mp = load_masr_plan(plan_file(sorted(PLANS)[0], tmp_path))
    a_d, a_th = board_ramps()
    assert (a_d, a_th) == (0.8, 3.0)                 # firmware/masr_ma/config.py LOCO_ACCEL_MM_S2, ROT_ACCEL_MRAD_S2
    arm = mp.arm
    extra = 0.0
    for st in mp.steps():
        x, v, a = ((st["d_to"] - st["d_from"], arm.ma_speed, a_d) if st["op"] == "move"
                   else (st["theta_to"] - st["theta_from"], arm.joint_speed, a_th))
        x = abs(x)
        extra += v / a if x >= v * v / a else 2.0 * np.sqrt(x / a) - x / v
    assert planned_time(mp) == pytest.approx(mp.total_time + extra)
    assert planned_time(mp) > mp.total_time


# ---------------------------------------------------------------- full plans


@pytest.mark.parametrize("name", sorted(PLANS))
def test_a_full_plan_reaches_the_goal_within_the_time(name, tmp_path, ports):  # noqa: F811
    path = plan_file(name, tmp_path)
    mp = load_masr_plan(path)
    rrd = tmp_path / f"{name}.rrd"
    s = run_plan(path, f"emu:masr_ma?speed=0&seed={len(name) + ord(name[1])}", rrd, progress=False, home=True)
    emu = ports[0].emulator
    assert s.completed and s.final_state == "IDLE" and emu.crash is None, s
    _, commands = masr_commands(mp, home=True)
    assert_each_action_once(emu, commands)
    # the truth: the plant's q through fk, within the goal's e_p and e_phi
    dp, dphi = true_errors(mp, emu.plant.q)
    assert dp <= mp.env.e_p and dphi <= mp.env.e_phi, (dp, np.degrees(dphi))
    # executed time (from the end of the setup to the last DONE) within 10 % of the plan timed with
    # the board's ramps; eq. (7)'s tau, without them, is less
    m = s.masr
    assert m["tau_s"] == pytest.approx(mp.total_time) and m["planned_s"] == pytest.approx(planned_time(mp))
    assert 0.99 <= m["time_ratio"] <= 1.0 + TIME_TOL, m
    assert m["tau_ratio"] > m["time_ratio"]
    # the summary is the board's own estimate: close to the truth, but not the truth
    assert m["dp_mm"] <= mp.env.e_p * 1000.0 and m["dphi_deg"] <= np.degrees(mp.env.e_phi)
    assert_like_with_like(s, mp, emu)
    assert_dead_reckoning_reported(s, emu)
    # the recording: the arm and the MA over time, the obstacles, the MA's series
    data = read(rrd)
    n = s.telemetry_samples
    for entity in ("/arm/links", "/arm/tip", "/joints/d/q", "/ma/speed", "/ma/link", "/ma/d_link"):
        assert data[entity]["rows"] == n, entity
    strips = data["/world/obstacles"]["columns"]["LineStrips2D:strips"][0]
    assert len(strips) == len(mp.env.obstacles)
    assert np.allclose(np.asarray(strips[0])[:len(mp.env.obstacles[0])], mp.env.obstacles[0], atol=1e-6)
    tip = np.asarray(data["/arm/tip"]["columns"]["Points2D:positions"][-1][0])   # the MA, last sample
    assert np.hypot(*(tip - np.asarray(mp.env.goal_pose[:2]))) <= mp.env.e_p
    speed = np.asarray(data["/ma/speed"]["columns"]["Scalars:scalars"], float).ravel()
    # 100 mm/s, the plan's speed; the speed loop overshoots it by 12 % at the ramp's end (measured on
    # the encoder's rate: 0.112 for every session number tried but one; the next issue's control work)
    assert 0.095 <= np.max(np.abs(speed)) <= 0.115
    links = {int(x) for x in np.asarray(data["/ma/link"]["columns"]["Scalars:scalars"]).ravel()}
    assert links <= set(range(1, mp.arm.n + 1)) and len(links) >= 2


# ---------------------------------------------------------------- a wheel slip after the last magnet


def line_plan(tmp_path: Path) -> Path:
    """Onto joint 2, turn it, then 150 mm along link 2 to the goal: the last leg passes no magnet."""
    from dataclasses import replace

    env0 = load_environment("E2")
    q0, q1 = np.array([0, 0, 0, 0, 0, 0.1]), np.array([0, 0.3, 0, 0, 0, 0.35])
    env = replace(env0, name="line", obstacles=[], start=q0, goal_pose=np.asarray(env0.arm.fk(q1)), goal_q=q1)
    return save_masr_plan(env, np.array([q0, q1]), tmp_path / "line.json", {"tool": "tests"})


def test_a_slip_after_the_last_magnet_is_reported_as_dead_reckoning(tmp_path):
    """Between its last magnet and its stop the MA knows d from its wheel alone: a slip there is seen by
    nothing the board senses (the board reports its bound under the 1 % slip model, and the run completes).
    The summary says so: the distance the final d rests on dead reckoning, since which magnet, and the bound
    that holds only within the slip model. The truth (the plant) shows the bound holding without the burst
    and broken by it, and the summary the same either way: it never claims what no magnet checked."""
    path = line_plan(tmp_path)
    url = "emu:masr_ma?speed=0&seed=3"
    with lockstep_ports() as opened:                       # lockstep: the burst lands where it is timed
        clean = run_plan(path, url, tmp_path / "a.rrd", progress=False, home=True, session=7)
        emu = opened[0].emulator
        assert clean.completed and abs(emu.plant.d * 1000.0 - emu.board.loc.d()) <= clean.masr["d_bound_mm"]
        assert_dead_reckoning_reported(clean, emu)
        last_start = emu.executed[-2][0] / 1000.0         # the final MV begins where the ROT ends
        burst = f"&slip={last_start + 0.25:.3f}:0.5:0.3"   # 30 % for 0.5 s on the last leg: ~15 mm short
        slipped = run_plan(path, url + burst, tmp_path / "b.rrd", progress=False, home=True, session=7)
        emu = opened[1].emulator
    m = slipped.masr
    assert slipped.completed and emu.board.loc.known                       # the board saw nothing
    assert [k for _, k, _ in emu.hal.faults_applied] == ["slip", "slip"]
    assert emu.hal.hall_log[-1][0] < last_start                            # no magnet after the burst
    off = abs(emu.plant.d * 1000.0 - emu.board.loc.d())
    assert off > 10.0 and off > m["d_bound_mm"]                            # the truth: outside the model's bound
    assert (m["last_magnet"], round(m["dead_reckoning_mm"]), m["slip_bound"]) == (2, 150, 0.01)
    assert m["d_bound_mm"] == clean.masr["d_bound_mm"] == pytest.approx(1.5 + 0.05 + 1.5 + 0.5)
    table = render(slipped.table())
    assert re.search(r"MA d at the end: dead reckoning .*150 mm since magnet 2: within 3\.55 mm if the wheel "
                     r"slipped <= 1 % \(a slip there is not seen\)", table)


def test_a_slip_before_a_magnet_faults_at_it():
    """The same slip on a move that a joint action follows: the ROT re-anchors on its magnet first, and the
    magnet is not where the wheel says: a MAGNET fault before the joint turns (the MA is off its magnet),
    ahead of the MA (the estimate passes it with no edge: MISSED) or behind it (the edge comes too early:
    SPURIOUS)."""
    from test_emulator_ma import Ma

    from armbridge.emulator.faults import Faults

    for joint, reason in ((3, "MAGNET:MISSED"), (2, "MAGNET:SPURIOUS")):
        probe = Ma(seed=4)
        probe.done("HOME", 1)
        probe.done("MV", 2, 200)
        t0 = probe.emu.now()
        ma = Ma(seed=4, faults=Faults(slip=((t0 + 0.3, 0.5, 0.3),)))     # the same run, the burst after magnet 2
        ma.done("HOME", 1)
        ma.done("MV", 2, 200)
        ma.done("MV", 3, 350)                                    # the board cannot tell: done, 15 mm short
        assert ma.emu.plant.d * 1000.0 < 340 and ma.stat()[2] == "IDLE"
        theta = ma.q[joint - 1]
        _, ev = ma.act("ROT", 4, joint, 300)
        assert ev[2][1] == "FAULT" and ma.stat()[6] == reason, (joint, ev, ma.stat())
        assert ma.q[joint - 1] == theta and not ma.emu.hal.outputs_enabled      # never turned off its magnet


# ---------------------------------------------------------------- link faults and resets


def test_link_faults_every_action_once_in_order(tmp_path, ports):  # noqa: F811
    path = plan_file("E2", tmp_path)
    mp = load_masr_plan(path)
    url = "emu:masr_ma?speed=0&seed=7&drop=0.003&corrupt=0.003&dup=0.003"
    s = run_plan(path, url, tmp_path / "faults.rrd", progress=False, home=True)
    emu = ports[0].emulator
    assert s.completed and s.final_state == "IDLE", s
    assert_each_action_once(emu, masr_commands(mp, home=True)[1])
    c = emu.counters
    assert c["rx"]["drop"] > 0 and c["rx"]["corrupt"] > 0 and c["tx"]["dup"] > 0
    assert s.line_errors > 0 and s.waypoints_retransmitted + s.resyncs > 0
    dp, dphi = true_errors(mp, emu.plant.q)
    assert dp <= mp.env.e_p and dphi <= mp.env.e_phi


def test_a_reset_at_rest_keeps_the_position_and_the_plan_resumes(tmp_path):
    """Half the plan, the board at rest, a reset; the same session resyncs and runs the rest."""
    mp = load_masr_plan(plan_file("E2", tmp_path))
    plan, commands = masr_commands(mp, home=True)
    durs = [max(1, int(round(d * 1000))) for d in plan.durations]
    half = int(plan.provenance["masr_plan"]["setup"]) + 5
    port = transport.open_port("emu:masr_ma?speed=0&seed=4&drop=0.005&corrupt=0.005")
    try:
        emu = port.emulator
        client = BoardClient(port, plan.robot)
        client.connect()
        client.execute(durs[:half], [], commands=commands[:half])
        client.drain(0.3)                                       # at rest: the board saved m = 0
        board = emu.board
        d0, th0 = board.loc.d(), list(board.theta)
        emu.reset()
        client.drain(1.0, until=lambda: len(emu.boots) == 2 and emu.board is not None)
        assert emu.board is not board and not emu.board.unhomed
        assert emu.board.loc.d() == pytest.approx(d0, abs=1e-3)   # the persisted record, um
        assert emu.board.theta == pytest.approx(th0, abs=1e-3)
        client.execute(durs[half:], [], commands=commands[half:])
        assert client.stats.resyncs >= 1
    finally:
        port.close()
    assert_each_action_once(emu, commands)
    dp, dphi = true_errors(mp, emu.plant.q)
    assert dp <= mp.env.e_p and dphi <= mp.env.e_phi


def test_a_reset_mid_move_stops_the_run_with_one_clear_line(tmp_path, ports):  # noqa: F811
    path = plan_file("E2", tmp_path)
    mp = load_masr_plan(path)
    _, commands = masr_commands(mp, home=True)
    with pytest.raises(RunFailed) as err:
        run_plan(path, "emu:masr_ma?speed=0&seed=2&reset_at=25", tmp_path / "r.rrd", progress=False, home=True)
    msg = str(err.value)
    assert "UNHOMED" in msg and "reset while it moved" in msg and "e-stop sent and confirmed" in msg and "\n" not in msg
    emu = ports[0].emulator
    reset_ms = emu.resets[0] * 1000.0
    done = [wid for _, wid, _ in emu.executed]
    assert done == list(range(len(done))) and 0 < len(done) < len(commands)      # a prefix, each once
    assert [tuple(a) for _, _, a in emu.executed] == [tuple(a) for _, a in commands[:len(done)]]
    assert all(ms < reset_ms for ms, _, _ in emu.executed)                       # nothing ran after the reset
    assert emu.board.unhomed and emu.state == "ESTOP"
    assert err.value.summary.resyncs >= 1 and err.value.summary.estop_confirmed


# ---------------------------------------------------------------- e-stop, watchdog


def test_estop_mid_plan_switches_the_motors_off_within_one_period(tmp_path):
    mp = load_masr_plan(plan_file("E2", tmp_path))
    plan, commands = masr_commands(mp, home=True)
    durs = [max(1, int(round(d * 1000))) for d in plan.durations]
    setup = int(plan.provenance["masr_plan"]["setup"])
    from armbridge.emulator.url import open_lockstep_port

    # lockstep in the host's thread: the board does not run on while the callback sends the byte (over the
    # threaded pty it could, up to a lead and a period: 0.06 s against the 0.01 s asserted below)
    port = open_lockstep_port("emu:masr_ma?speed=0&seed=9")
    sent: list[float] = []
    try:
        emu = port.emulator

        def on_telemetry(t, m) -> None:    # mid-plan, while the MA drives
            if not sent and client.done_index >= setup + 2 and abs(emu.plant.v) > 0.05:
                sent.append(emu.now())     # before the byte: the board cannot read it earlier
                client.estop()

        client = BoardClient(port, plan.robot, on_telemetry=on_telemetry)
        client.connect()
        with pytest.raises(ArmbridgeError, match="e-stop latched"):
            client.execute(durs, [], commands=commands)
        client.drain(0.5)
    finally:
        port.close()
    hal = emu.hal
    period = emu.cfg.PERIOD_MS / 1000.0
    (t_byte,) = hal.estop_byte_at
    assert sent and 0.0 <= t_byte - sent[0] <= 0.01
    assert 0.0 <= hal.outputs_off_at[-1] - t_byte <= period
    assert all(u == 0.0 for t, u in list(hal.loco_log) + list(hal.rot_log) if t >= t_byte + period)
    assert emu.state == "ESTOP" and not hal.outputs_enabled and emu.plant.v == 0.0
    n_done = len(emu.executed)
    assert setup + 2 <= n_done < len(commands) and all(ms <= t_byte * 1000 for ms, _, _ in emu.executed)


def _estop_during_a_reset(boot_ms: float):
    """The board resets as the host sends the e-stop (the reset cuts the byte from the wire, and
    the board boots unlatched after `boot_ms`): (emulator, summary, board time the host waited)."""
    from armbridge.emulator.lockstep import lockstep_port

    emu = EmulatedBoard("masr_ma", speed=0, seed=3, boot_ms=boot_ms)
    port = lockstep_port(emu, "emu:masr_ma?speed=0&seed=3")  # the host's waits in sim time, to the read
    try:
        client = BoardClient(port, None)
        client.connect()
        summary = Summary(plan="p", port=port.url, rrd=None, robot="masr", waypoints_total=1)
        emu.schedule_reset(emu.now())
        t0 = client.now()
        executor_estop.fail_run(client, summary, None, ArmbridgeError("the board refused MV"))
        waited = client.now() - t0
    finally:
        port.close()
    return emu, summary, waited


def test_an_e_stop_the_board_never_takes_in_is_reported_as_not_confirmed():
    """A board still booting when the wait ends (a boot longer than ESTOP_CONFIRM_S): no ESTOP
    comes back. The host waits ESTOP_CONFIRM_S of board time for it, no longer (no HELLO
    meanwhile), and the run's one line says the stop was not confirmed."""
    emu, summary, waited = _estop_during_a_reset(boot_ms=1000.0)
    assert emu.resets and emu.hal.estop_byte_at == [] and emu.state != "ESTOP"    # the truth: never taken in
    assert summary.estop_sent and not summary.estop_confirmed and summary.final_state != "ESTOP"
    assert summary.error == ("the board refused MV; e-stop sent, not confirmed by the board within 500 ms "
                             "(check the arm; the next run needs --clear)")
    # no longer than its wait and one read (arq.READ_WAIT_S) past it: over the threaded pty the board's
    # thread could run up to a lead and a period past the host's last read, 0.06 s, whatever it asserted
    assert executor_estop.ESTOP_CONFIRM_S <= waited <= executor_estop.ESTOP_CONFIRM_S + 0.011


def test_an_e_stop_lost_in_a_boot_is_sent_again_at_the_boot_and_confirmed():
    """The byte went into a board that was resetting (lost in the hardware, docs/protocol.md §2):
    its BOOT says IDLE, the host sends the byte again at once, and the board reports ESTOP
    within the wait."""
    emu, summary, waited = _estop_during_a_reset(boot_ms=250.0)
    assert len(emu.resets) == 1 and len(emu.hal.estop_byte_at) == 1 and emu.estop_byte_at[0] > emu.boots[-1]
    assert emu.state == "ESTOP" and summary.estop_confirmed and summary.final_state == "ESTOP"
    assert waited < executor_estop.ESTOP_CONFIRM_S


def test_the_watchdog_stops_the_ma_when_the_host_falls_silent(tmp_path):
    mp = load_masr_plan(plan_file("E2", tmp_path))
    _, commands = masr_commands(mp, home=True)
    emu = EmulatedBoard("masr_ma", speed=0, seed=5)
    h = Lockstep(emu, keepalive=False)
    h.wait("BOOT")
    assert h.hello(1)[1] == "OK"
    for wid, (verb, args) in enumerate(commands[:10]):         # the setup and a few of the plan's actions
        assert h.request(verb, wid, *args)[1] == "OK"
    last = emu.now()                                          # then nothing more from the host
    wdog = emu.cfg.WDOG_MS / 1000.0
    period = emu.cfg.PERIOD_MS / 1000.0
    assert emu.hal.loco_log[-1][1] != 0.0 or emu.hal.rot_log[-1][1] != 0.0      # a motor was driven
    ev = h.wait("EV", lambda a: a[1] == "WDOG", max_s=wdog + 1.0)
    t_wdog = int(ev[2][0]) / 1000.0                           # the board's clock is the sim's here
    assert wdog - period <= t_wdog - last <= wdog + 2 * period      # from the last line the board took in
    done = len(emu.executed)
    emu.run_for(1.0)
    # zero effort on both motors from the latch on (link.py's ZERO: the worm holds the joints)
    assert all(u == 0.0 for t, u in list(emu.hal.loco_log) + list(emu.hal.rot_log) if t >= t_wdog + period)
    assert emu.state == "WDOG" and emu.plant.v == 0.0 and emu.plant.om == 0.0
    assert len(emu.executed) == done < 10 and [wid for _, wid, _ in emu.executed] == list(range(done))
    assert all(ms <= t_wdog * 1000 for ms, _, _ in emu.executed)


# ---------------------------------------------------------------- bad plans


def _broken(tmp_path: Path, kind: str) -> Path:
    good = plan_file("E2", tmp_path)
    doc = json.loads(good.read_text())
    out = tmp_path / f"{kind}.json"
    if kind == "d_out_of_range":
        doc["waypoints"][1]["q"][-1] = 0.95                   # the arm is 0.8 m long
        out.write_text(json.dumps(doc))
    else:
        text = good.read_text()
        out.write_text(text[: len(text) // 2])                # cut short: not JSON
    return out


@pytest.mark.parametrize("kind, words", [("d_out_of_range", "waypoint 1, q[5] (d) = 0.95 m is outside [0, 0.8]"),
                                         ("corrupted", "not valid JSON")])
def test_a_bad_plan_is_one_clear_line_and_nothing_is_sent(kind, words, tmp_path, ports):  # noqa: F811
    bad = _broken(tmp_path, kind)
    with pytest.raises(ArmbridgeError, match=re.escape(words)) as err:
        run_plan(bad, "emu:masr_ma?speed=0", tmp_path / "bad.rrd", progress=False, home=True)
    assert not isinstance(err.value, RunFailed) and ports == []      # no port was even opened
    proc = subprocess.run([ARMBRIDGE, "run", str(bad), "--port", "emu:masr_ma?speed=0", "--home",
                           "--rrd", str(tmp_path / "cli.rrd")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and words in one_error_line(proc) and str(bad) in proc.stderr
    assert not (tmp_path / "cli.rrd").exists()


def test_a_plan_for_another_robot_is_refused_by_the_handshake(tmp_path, ports):  # noqa: F811
    from armbridge.plans.format import save_plan

    other = save_plan(wave_plan(20), tmp_path / "arm3r.json")            # the 3R arm's plan on the MA
    with pytest.raises(RunFailed, match="the board runs firmware 'masr_ma'.*the plan is for robot 'arm3r'"):
        run_plan(other, "emu:masr_ma?speed=0", tmp_path / "o.rrd", progress=False)
    emu = ports[0].emulator
    assert emu.executed == [] and np.all(emu.plant.q == 0.0)                     # nothing ran, nothing moved
    assert all(u == 0.0 for _, u in list(emu.hal.loco_log) + list(emu.hal.rot_log))
    proc = subprocess.run([ARMBRIDGE, "run", str(other), "--port", "emu:masr_ma?speed=0",
                           "--rrd", str(tmp_path / "cli.rrd")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "the plan is for robot 'arm3r'" in one_error_line(proc)


# ---------------------------------------------------------------- the demo


def test_the_masr_demo_plans_and_runs_on_the_emulated_ma(tmp_path):
    rrd = tmp_path / "demo.rrd"
    proc = subprocess.run([ARMBRIDGE, "demo", "--robot", "masr", "--port", "emu:masr_ma?speed=0", "--rrd", str(rrd)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = proc.stdout
    assert "MASR-RRT* in E1" in out and "completed" in out
    dp, dphi = (float(x) for x in re.search(r"MA pose error at the end.*?([\d.]+) mm / ([\d.]+) deg", out).groups())
    assert dp <= 8.0 and dphi <= 4.0
    executed, planned_ramped, tau = (float(x) for x in re.search(
        r"action time \(run / planned / tau\).*?([\d.]+) s / ([\d.]+) s / ([\d.]+) s", out).groups())
    assert tau < planned_ramped <= executed <= (1.0 + TIME_TOL) * planned_ramped
    # the run's own duration row compares the same: the plan's actions, the setup apart, d in mm
    planned, measured = (float(x) for x in re.search(
        r"duration planned / measured.*?([\d.]+) s / ([\d.]+) s", out).groups())
    assert planned == pytest.approx(planned_ramped, abs=0.01) and measured == pytest.approx(executed, abs=0.01)
    assert re.search(r"setup before the plan \(apart\).*7 actions, [\d.]+ s", out)
    d_row = out[out.index("tracking d (rms / max)"):out.index("MA pose error")]     # may wrap in 80 columns
    assert d_row.rstrip(" │\n").endswith("mm") and "mrad" not in d_row
    assert read(rrd)["/world/obstacles"]["static_rows"] == 1


# ---------------------------------------------------------------- the benchmark


def test_bench_masr_exec_quick(tmp_path):
    out = tmp_path / "bench.json"
    proc = subprocess.run([ARMBRIDGE, "bench", "masr-exec", "--quick", "--json", str(out)],
                          capture_output=True, text=True, timeout=600, env={**os.environ, "COLUMNS": "200"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "paper, Table II (E1)" in proc.stdout and "trapezoid ramp alone" in proc.stdout
    r = json.loads(out.read_text())
    assert r["paper_table_ii"] == {"environment": "E1", "planned_s": 46.16, "executed_mean_s": 48.78,
                                   "executed_std_s": 1.81, "dp_mean_mm": 11.0, "dp_std_mm": 3.1,
                                   "dphi_mean_deg": 1.2, "dphi_std_deg": 0.8}
    s = r["random"]["summary"]
    assert s["runs"] == s["completed"] == 3 and "fixed" not in r
    assert s["at_goal"] == 1.0 and s["log_exactly_once"]                   # the plant's truth, the board's log
    for run in r["random"]["runs"]:
        assert 0.99 <= run["time_ratio"] < 1.25 and run["executed_s"] > 0
        assert run["loc"]["max_over_bound"] <= 1.0                          # loc.py's bound holds
        assert run["loc"]["after_magnet_max_mm"] <= 1.0     # re-anchored where the edge fires (was 1.5: the window)
    for kind in ("MV onto a joint", "ROT"):
        o = s["overhead"][kind]
        assert o["actions"] > 0 and o["per_action_s"] >= o["ramp_per_action_s"] > 0   # a ramp is the least it adds


def test_bench_masr_exec_runs_e1_on_boards_of_hidden_truth(tmp_path):
    out = tmp_path / "bench.json"
    proc = subprocess.run([ARMBRIDGE, "bench", "masr-exec", "--quick", "--environments", "0", "--plants", "1",
                           "--calibrated", "--json", str(out)], capture_output=True, text=True, timeout=600,
                          env={**os.environ, "COLUMNS": "200"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "E1, 1 random plants" in proc.stdout and "final error" in proc.stdout
    r = json.loads(out.read_text())
    (run,) = r["e1_random_plants"]["runs"]
    assert "error" not in run, run
    assert run["plant"] == "random" and run["seed"] == 0 and run["environment"] == "E1"
    assert run["log_exactly_once"] and run["executed_s"] > 0 and run["loc"]["max_over_bound"] <= 1.0
    assert r["random"]["summary"] == {"runs": 0, "completed": 0}
    assert r["e1_random_plants"]["summary"]["dp_mm"]["max"] == run["dp_mm"]
    # --calibrated: the same board calibrated (calibrate/masr.py), then the same plans on it
    assert "E1, 1 random plants, calibrated" in proc.stdout and "single actions, 1 random plants" in proc.stdout
    (cal,) = r["calibrations"]["runs"]
    assert "error" not in cal and [v for v, _ in cal["settings"]] == ["MAG"] * 5 + ["WHEEL"]
    (crun,) = r["e1_calibrated"]["runs"]
    assert "error" not in crun and crun["calibrated"] and not run["calibrated"] and crun["log_exactly_once"]
    assert crun["loc"]["after_magnet_mean_mm"] < run["loc"]["after_magnet_mean_mm"]    # the anchors moved onto the truth
    assert crun["loc"]["after_magnet_max_mm"] <= 0.8
    singles = r["singles_calibrated"]["runs"]
    assert len(singles) == len(r["singles_random_plants"]["runs"]) == 3 and all("error" not in x for x in singles)
