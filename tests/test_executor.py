"""The executor against the emulated ESP32 board over a real pty (docs/protocol.md §6-§9).

The emulator runs the real firmware in this process in lockstep (`speed=0`,
coupled to the host: its thread runs at most HOST_LEAD_S of sim time past the
host's latest read), so no outcome depends on the machine's speed: paced at 2x,
a host starved of the CPU on a busy machine let the board run dry or its
watchdog fire. The client's timers run on the emulator's clock (`Port.clock`),
and every time checked is board time, never the wall clock. The checks use the board's own log
of completed waypoints (`EmulatedBoard.executed`: board ms, id and the targets
the firmware executed, from its completion hook, before any link fault) as the
ground truth for exactly-once, in-order execution with the values the host sent.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import armbridge.link.transport as transport
from armbridge.emulator.plant import PlantParams
from armbridge.errors import ArmbridgeError
from armbridge.executor.client import BoardClient
from armbridge.executor.stream import Stream
from armbridge.link.boardclock import BoardClock
from armbridge.executor.run import Summary, run_plan
from armbridge.executor.tracking import plan_error
from armbridge.link.protocol import to_milli
from armbridge.plans.format import make_plan, save_plan
from armbridge.robots import ARM3R, PlanarChain
from plan_runs import MID, sent_values, wave_plan

SPEED = 0  # lockstep (see the module docstring)


def executed_ids(port) -> list[int]:
    return [wid for _, wid, _ in port.emulator.executed]


def executed_values(port) -> list[tuple[int, ...]]:
    """The targets (mrad) of every waypoint the board completed, from its own log."""
    return [values for _, _, values in port.emulator.executed]


def tracking_bound(peak_v: float, period_s: float) -> float:
    """Worst |set point - measured| (rad) the emulated servo may show on a plan whose
    joint speeds stay below peak_v, from the plant's numbers (PlantParams):

    * The feed-forward kff = 1/v_servo makes u produce the planned speed, but the
      servo reaches it through a first-order lag tau: a joint that changes speed
      by dv falls behind by at most dv * tau (the steady ramp error of a lag; the
      feedback only shrinks it). Over a plan starting at rest dv <= peak_v.
    * The acceleration limit a_max adds at most dv^2 / (2 a_max).
    * Telemetry samples q at the start of a control tick and the set point after
      the tick advanced it: one period of motion, peak_v * T. The outputs are held
      for a period (zero-order hold): another peak_v * T.
    * Potentiometer noise (4 sigma) and one ADC quantum (span / 4095).
    """
    p = PlantParams()
    span = math.pi + 2 * p.stop_margin
    quantum = span / ((1 << p.adc_bits) - 1)
    return peak_v * p.tau + peak_v**2 / (2 * p.a_max) + 2 * peak_v * period_s + 4 * p.sigma + quantum


# ---------------------------------------------------------------- pure parts

def test_board_clock_unwraps_and_survives_a_restart():
    c = BoardClock()
    assert c(1000) == 1.0
    assert c(999) == pytest.approx(0.999)  # a T line stamped at tick start, after an event: tolerated
    c = BoardClock()
    c((1 << 30) - 10)
    assert c(20) == pytest.approx(((1 << 30) + 20) / 1000)  # wrapped at 2**30 ms
    c = BoardClock()
    c(50_000)
    t = c(300)  # the board restarted its clock (reset on real hardware)
    assert t >= 50.0 and c(400) == pytest.approx(t + 0.1)


def test_waypoint_ids_wrap_at_65536():
    s = Stream([10], [[0, 0, 0]])
    # Plan index for a board id, searched among the indices in flight.
    assert s.index_of(5, 0, 100) == 5
    assert s.index_of(3, 65530, 65540) == 65539  # id 3 is index 65539 = 65536 + 3
    assert s.index_of(65535, 65530, 65540) == 65535
    assert s.index_of(9, 65530, 65540) is None  # not in flight
    assert s.index_of(7, 10, 5) is None
    # A second plan of the session: its ids follow on from the first's.
    s2 = Stream([10], [[0, 0, 0]], base=65530)
    assert s2.wid(0) == 65530 and s2.wid(10) == 4 and s2.index_of(4, 0, 20) == 10


def test_plan_error_follows_the_linear_path():
    plan = make_plan(ARM3R, [MID, MID + 0.1, MID + 0.2], [0.1, 0.1, 0.1])
    # Samples on the plan's own path in segments 1 and 2 (anchored at 10.0 and 10.1 s).
    t = np.array([10.0, 10.05, 10.1, 10.15, 10.25])
    seg = np.array([1, 1, 2, 2, 2])
    want = np.array([MID, MID + 0.05, MID + 0.1, MID + 0.15, MID + 0.2])
    err = plan_error(plan, t, want, seg, {1: 10.0, 2: 10.1})
    assert err.shape == (5, 3) and np.abs(err).max() < 1e-12
    # Segment 0 (from wherever the arm was) and segments with no known start are skipped.
    assert plan_error(plan, t, want, np.array([0, 0, 3, 2, 2]), {1: 10.0}).shape == (0, 3)
    # Segments before `first` (a MASR run's setup, ahead of the plan's own steps) are left out.
    assert plan_error(plan, t, want, seg, {1: 10.0, 2: 10.1}, first=2).shape == (3, 3)


# ---------------------------------------------------------------- on the emulator

@pytest.mark.hil
def test_200_waypoints_run_exactly_once_in_order_and_track(tmp_path, ports):
    from rerun.chunk import RrdReader

    plan = wave_plan(200)
    path = save_plan(plan, tmp_path / "wave.json")
    rrd = tmp_path / "wave.rrd"
    s = run_plan(path, f"emu:esp32?speed={SPEED}&seed=3", rrd, rate_hz=50, progress=False)
    port = ports[0]
    emu = port.emulator

    assert s.completed, s
    assert executed_ids(port) == list(range(200))
    assert executed_values(port) == sent_values(plan)
    assert (s.waypoints_done, s.waypoints_sent, s.waypoints_acked) == (200, 200, 200)
    assert s.resyncs == 0 and s.final_state == "IDLE"
    # Board time: the plan's 10 s (no SLOW stretching here; the board never waits for the
    # host, which keeps its queue filled).
    assert s.slow_events == 0
    assert s.measured_duration_s == pytest.approx(s.planned_duration_s, rel=0.05)
    # The board's own log agrees: first to last completion spans the plan's 9.95 s.
    ms = [t for t, _, _ in emu.executed]
    assert (ms[-1] - ms[0]) / 1000 == pytest.approx(plan.total_duration - plan.durations[0], rel=0.05)

    # Tracking, from telemetry while RUN (see tracking_bound for the derivation).
    assert emu.cfg.PID_KFF[0] == pytest.approx(1 / PlantParams().v_servo)  # the premise of the bound
    peak_v = 0.4 * math.pi * 0.5
    bound = tracking_bound(peak_v, emu.period_ms / 1000)  # ~0.039 rad
    assert 0.03 < bound < 0.05
    for name in ARM3R.joint_names:
        sp, pl = s.tracking_setpoint[name], s.tracking_plan[name]
        assert sp.samples > 400 and pl.samples > 400
        assert sp.max <= bound and sp.rms <= bound / 2, (name, sp, bound)
        # Against the plan's own path the anchor adds up to one control period of motion.
        assert pl.max <= bound + peak_v * emu.period_ms / 1000, (name, pl)

    # The recording holds every telemetry series, the arm, the plan and the events.
    assert rrd.is_file()
    rows: dict[str, int] = {}
    texts: list[str] = []
    for chunk in RrdReader(rrd).stream():
        if chunk.is_static:
            rows.setdefault(chunk.entity_path + " (static)", 0)
            rows[chunk.entity_path + " (static)"] += chunk.num_rows
            continue
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
        assert "board_time" in chunk.timeline_names
        rb = chunk.to_record_batch()
        if chunk.entity_path == "/events":
            texts += [x for row in rb.column("TextLog:text").to_pylist() for x in row]
    for name in ARM3R.joint_names:
        for series in ("q", "target", "error", "effort"):
            assert rows.get(f"/joints/{name}/{series}") == s.telemetry_samples, (name, series, rows)
    for entity in ("/arm/links", "/arm/target", "/arm/tip"):
        assert rows.get(entity) == s.telemetry_samples
    assert rows.get("/board/done", 0) > 0
    for entity in ("/plan/path", "/plan/waypoints", "/trace/tip"):
        assert rows.get(entity + " (static)") == 1
    dones = [x for x in texts if x.startswith("DONE ")]
    starts = [x for x in texts if x.startswith("START ")]
    # A clean link loses no event. One DONE per waypoint (each lasts 5 control ticks);
    # START only for a waypoint that starts from rest: the first one.
    assert len(dones) == 200 and starts == ["START 0"]
    assert dones[-1].split()[1] == "199" and "state RUN" in texts


@pytest.mark.hil
def test_link_faults_and_a_reset_every_waypoint_once_in_order(tmp_path, ports):
    """1% of bytes dropped, 1% with a bit flipped, 1% doubled, both directions (about
    two lines in three damaged), and a board reset mid-plan."""
    plan = wave_plan(200)
    url = f"emu:esp32?speed={SPEED}&drop=0.01&corrupt=0.01&dup=0.01&seed=11&reset_at=10"
    s = run_plan(plan, url, tmp_path / "faults.rrd", progress=False)
    port = ports[0]
    emu = port.emulator
    ids = executed_ids(port)
    assert ids == list(range(200)), ids  # exactly once, in order, across the reset
    assert executed_values(port) == sent_values(plan)  # and with the values the host sent
    assert s.completed and s.waypoints_done == 200 and s.waypoints_acked >= 190
    assert emu.counters["resets"] == 1 and s.resyncs >= 1
    reset_ms = emu.resets[0] * 1000
    before = [wid for ms, wid, _ in emu.executed if ms < reset_ms]
    assert 0 < len(before) < 200  # the reset fell mid-plan
    c = emu.counters
    assert c["rx"]["corrupt"] > 0 and c["rx"]["drop"] > 0 and c["tx"]["dup"] > 0
    assert s.waypoints_retransmitted > 0 and s.line_errors > 0


@pytest.mark.hil
def test_a_reset_early_in_a_second_plan_of_the_session():
    """Waypoint ids run on across the plans of one session: after a reset that
    falls before the second plan completes anything, the board's persisted
    `done` names the first plan's last waypoint, and the client resumes the
    second plan from its start, running nothing twice."""
    plan = wave_plan(30, dt=0.05)
    port = transport.open_port(f"emu:esp32?speed={SPEED}")
    try:
        emu = port.emulator
        client = BoardClient(port, ARM3R)
        client.connect()
        q = [to_milli(row) for row in plan.q]
        durations = [int(d * 1000) for d in plan.durations]
        client.execute(durations, q)
        emu.schedule_reset(emu.now() + 0.01)
        client.execute(durations, q)
        assert emu.counters["resets"] == 1 and client.stats.resyncs >= 1
        assert executed_ids(port) == list(range(60))
        assert executed_values(port) == 2 * sent_values(plan)
    finally:
        port.close()


@pytest.mark.hil
def test_ctrl_c_sends_estop_and_keeps_the_recording(tmp_path, ports, monkeypatch):
    from rerun.chunk import RrdReader

    import armbridge.telemetry.recording as recording

    real = recording.Recording.telemetry
    seen = {"run": 0}

    def interrupt_after_some_motion(self, t, q, target, effort, done=None, **kw):
        real(self, t, q, target, effort, done, **kw)
        if done is not None and done >= 20 and not seen.get("fired"):
            seen["fired"] = True  # Ctrl-C once
            raise KeyboardInterrupt

    monkeypatch.setattr(recording.Recording, "telemetry", interrupt_after_some_motion)
    rrd = tmp_path / "stopped.rrd"
    s = run_plan(wave_plan(200), f"emu:esp32?speed={SPEED}", rrd, progress=False)
    emu = ports[0].emulator
    assert s.stopped_by_user and s.estop_sent and not s.completed
    assert emu.estop_byte_at, "the e-stop byte reached the board"
    assert emu.state == "ESTOP"
    ids = executed_ids(ports[0])
    assert ids == list(range(len(ids))) and 20 <= len(ids) < 60
    texts = []
    for chunk in RrdReader(rrd).stream():
        if chunk.entity_path in ("/errors", "/events"):
            texts += [x for row in chunk.to_record_batch().column("TextLog:text").to_pylist() for x in row]
    assert "stopped by SIGINT, e-stop sent" in texts and "ESTOP" in texts
    seen["run"] = s.telemetry_samples
    assert seen["run"] > 0


@pytest.mark.hil
def test_long_segments_keep_the_watchdog_fed(tmp_path, ports):
    """Two 2.5 s segments: nothing to send for longer than the 1 s watchdog, so PING keeps it alive."""
    plan = make_plan(ARM3R, [MID + [0.5, -0.5, 0.5], MID], [2.5, 2.5])
    s = run_plan(plan, f"emu:esp32?speed={SPEED}", tmp_path / "slow.rrd", progress=False)
    assert s.completed and executed_ids(ports[0]) == [0, 1]
    assert ports[0].emulator.state == "IDLE"


@pytest.mark.hil
def test_handshake_refuses_a_robot_that_differs_from_the_board(tmp_path, ports):
    narrow = PlanarChain(
        name="arm3r", link_lengths=ARM3R.link_lengths, q_min=ARM3R.q_min, q_max=ARM3R.q_max,
        v_max=np.array([3.0, 3.0, 2.0]), joint_names=ARM3R.joint_names,
    )
    plan = make_plan(narrow, [MID, MID + 0.1], 0.5)
    with pytest.raises(ArmbridgeError, match=r"joint 3 \(wrist\) vmax: board 3000 mrad/s, robot 2000 mrad/s"):
        run_plan(plan, f"emu:esp32?speed={SPEED}", tmp_path / "x.rrd", progress=False)
    assert executed_ids(ports[0]) == [] and ports[0].emulator.state == "IDLE"

    other = PlanarChain(
        name="arm2r", link_lengths=[0.2, 0.1], q_min=[-1, -1], q_max=[1, 1], v_max=[1, 1], joint_names=("a", "b"),
    )
    with pytest.raises(ArmbridgeError, match="the board runs firmware 'arm3r' 0.1.0, the plan is for robot 'arm2r'"):
        run_plan(make_plan(other, [[0, 0]], 0.5), f"emu:esp32?speed={SPEED}", tmp_path / "y.rrd", progress=False)


@pytest.mark.hil
def test_power_cycle_mid_plan_is_detected(ports):
    """The board comes back without its session memory: the host cannot know where
    the plan stands and must stop, not replay it."""
    port = transport.open_port(f"emu:esp32?speed={SPEED}")
    ports.append(port)
    emu = port.emulator
    client = BoardClient(port, ARM3R)
    client.connect()
    plan = wave_plan(100)
    fired = []

    def power_cycle(done: int) -> None:
        if done >= 10 and not fired:
            fired.append(done)
            emu.reset()
            assert emu.run_until(lambda: emu.board is None, 1.0)  # lockstep: the reset comes at the next tick
            emu.persist.save(b"")  # RTC memory lost: a power cycle, not a reset

    with pytest.raises(ArmbridgeError, match="power-cycled"):
        client.execute([50] * plan.k, [to_milli(r) for r in plan.q], on_progress=power_cycle)
    ids = executed_ids(port)
    assert fired and ids == list(range(len(ids))) and len(ids) < 100


def test_summary_json_is_plain():
    s = Summary(plan="p.json", port="emu:esp32", rrd=None, robot="arm3r", waypoints_total=3)
    d = s.to_dict()
    assert d["planned_duration_s"] is None and d["completed"] is False
    import json

    json.dumps(d, allow_nan=False)


@pytest.mark.hil
def test_run_command_prints_the_table_and_writes_json(tmp_path, ports):
    import json

    import typer
    from typer.testing import CliRunner

    from armbridge.executor.command import run_cmd

    app = typer.Typer()
    app.command("run")(run_cmd)
    app.command("other")(lambda: None)  # two commands: `run` is a subcommand, as in armbridge
    path = save_plan(wave_plan(30), tmp_path / "short.json")
    out = tmp_path / "out" / "summary.json"
    r = CliRunner().invoke(app, ["run", str(path), "--port", f"emu:esp32?speed={SPEED}", "--rrd",
                                 str(tmp_path / "s.rrd"), "--rate", "25", "--json", str(out), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "waypoints done / total" in r.output and "30 / 30" in r.output
    d = json.loads(out.read_text())
    assert d["completed"] and d["waypoints_done"] == 30 and d["rrd"] == str(tmp_path / "s.rrd")
    assert set(d["tracking_setpoint"]) == {"shoulder", "elbow", "wrist"}
    assert executed_ids(ports[0]) == list(range(30))


@pytest.mark.hil
def test_silent_board_is_resynchronised(ports):
    """A reset whose reboot takes 3 s of board time: no BOOT line, no answer, only
    silence, until the board is back; then HELLO with the same session resumes."""
    import serial

    from armbridge.emulator.board import EmulatedBoard

    # The reboot lasts 3 s: longer than the host's 1 s silence timeout (both on the board's clock).
    emu = EmulatedBoard("esp32", speed=SPEED, boot_ms=3000).start()
    emu.couple()  # this host reads through transport.Port, which keeps the lockstep board beside it
    port = transport.Port(serial.Serial(emu.port, 115200, timeout=0.1), "emu:esp32", emulator=emu, clock=emu.now)
    ports.append(port)
    reasons = []
    client = BoardClient(port, ARM3R, on_error=lambda t, text: reasons.append(text))
    client.connect()
    plan = wave_plan(60)

    def reset_once(done: int) -> None:
        if done == 20 and not emu.resets:
            emu.reset()

    client.execute([50] * plan.k, [to_milli(r) for r in plan.q], on_progress=reset_once)
    assert executed_ids(port) == list(range(60))
    assert executed_values(port) == sent_values(plan)
    assert client.stats.resyncs == 1
    assert any(r.startswith("resync: the board was silent") for r in reasons), reasons
    # The retransmission timer backs off while the board is away: no flood of lines.
    assert client.stats.timeouts < 40, client.stats


@pytest.mark.hil
def test_a_stalled_joint_latches_fault_and_stops_the_run(tmp_path, ports):
    """The shoulder is seized from the start; as the plan moves it 0.4 rad away, the
    board's following-error check (350 mrad for 300 ms) latches FAULT and the run
    stops with an error that says so (no e-stop needed: the board is stopped)."""
    with pytest.raises(ArmbridgeError, match=r"the board stopped: FAULT latched, joint 1 \(shoulder\): "
                                             r"following error \d+ mrad"):
        run_plan(wave_plan(200), f"emu:esp32?speed={SPEED}&stall=1@0", tmp_path / "f.rrd", progress=False)
    emu = ports[0].emulator
    assert emu.state == "FAULT" and not emu.estop_byte_at
    ids = executed_ids(ports[0])
    assert ids == list(range(len(ids))) and 0 < len(ids) < 200
    assert (tmp_path / "f.rrd").is_file()
