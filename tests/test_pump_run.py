"""The soft arm end to end: plans run by the executor on the syringe-pump board's real
.elf in simavr (`emu:arduino_pump`, docs/pump.md "Running a plan"), over the line
protocol and over Modbus (`modbus:emu:arduino_pump`), against the pneumatic plant.

Checked against the board's own records, not the host's: its log of completed
waypoints (EmulatedBoard.executed, from the simavr runner's on_done), the plant's truth
and the T lines (PumpSimHal.track, .telemetry), the motor pins (duty_log, the SimHal
outputs_off_at / estop_byte_at). Every time assertion is on simulated time. The plans
are short: simavr runs about at the wall clock's pace here (speed=0 on a loaded machine).
"""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from require import missing

if shutil.which("avr-gcc") is None or shutil.which("make") is None:
    missing("avr-gcc/make missing: the AVR toolchain (scripts/setup.sh as root installs it)")
if not Path("/usr/include/simavr/sim_avr.h").is_file():
    missing("libsimavr-dev missing (scripts/setup.sh as root installs it)")

from armbridge.executor.client import BoardClient  # noqa: E402
from armbridge.executor.handshake import HELLO_INTERVAL_S  # noqa: E402
from armbridge.executor.run import run_plan  # noqa: E402
from armbridge.executor.tracking import settle_times  # noqa: E402
from armbridge.link import protocol as P  # noqa: E402
from armbridge.link.transport import open_port  # noqa: E402
from armbridge.plans.format import make_plan  # noqa: E402
from armbridge.robots import SOFT3  # noqa: E402
from plan_runs import assert_executed_once_with_values, opened_ports  # noqa: E402
from test_recording import layout, names, read  # noqa: E402

pytestmark = pytest.mark.hil

BAND = 0.070          # config.h DBAND_DEFAULT_MRAD: 4 deg, the paper's band for three joints
COUNT = 1.047 / 511   # one ADC count of a bend sensor (BEND_DEFAULT: 205 -> 0, 716 -> 1047 mrad)
TOL = BAND + COUNT    # the settle tolerance (executor/settle.py): a reading dithers by a count at the edge
POSES = np.array([[0.25, 0.45, 0.50], [0.12, 0.25, 0.30]])   # inside 0-30, 0-55, 0-60 deg


def soft_plan(poses=POSES, move_s=(1.5, 1.0), hold_s=(3.5, 1.5)):
    """The soft arm through `poses`, each reached in move_s and held hold_s (a repeated
    waypoint): a joint-space plan of 2 x len(poses) waypoints for soft3."""
    q = np.repeat(np.asarray(poses, float), 2, axis=0)
    durations = [d for pair in zip(move_s, hold_s) for d in pair]
    return make_plan(SOFT3, q, durations, {"tool": "armbridge tests", "shape": "soft holds"})


def hold_ends(emu, plan) -> list[float]:
    """Board time (s) of the end of each pose's hold: the DONE of its second waypoint."""
    done = {wid: t / 1000.0 for t, wid, _ in emu.executed}
    return [done[2 * k + 1] for k in range(len(plan.q) // 2)]


# ---------------------------------------------------------------- the line protocol

@pytest.fixture(scope="module")
def line_run(tmp_path_factory):
    """One plan on emu:arduino_pump?speed=0 with its summary, the board's records and the .rrd."""
    plan = soft_plan()
    rrd = tmp_path_factory.mktemp("pump") / "run.rrd"
    with opened_ports() as opened:
        summary = run_plan(plan, "emu:arduino_pump?speed=0", rrd, progress=False, timeout=120)
        emu = opened[0].emulator
        yield {"plan": plan, "summary": summary, "emu": emu, "rrd": rrd, "executed": list(emu.executed),
               "track": list(emu.hal.track), "telemetry": list(emu.hal.telemetry)}


def test_each_joint_settles_in_its_dead_band_at_every_waypoint(line_run):
    plan, s, emu = line_run["plan"], line_run["summary"], line_run["emu"]
    assert s.completed and s.final_state == "IDLE", s
    assert s.fw == "arduino_pump" and s.waypoints_done == len(plan.q)
    assert_executed_once_with_values(emu, plan)              # the board's own log, with values
    assert s.settle_tolerance == {n: pytest.approx(TOL) for n in SOFT3.joint_names}
    assert s.settle_tolerance_source == "default"            # the line protocol cannot ask for DBAND
    for name, st in s.settle.items():                        # two moves per joint, both settled in their hold
        assert (st.waypoints, st.unsettled) == (2, 0), (name, st)
        assert 0.0 <= st.mean_s <= st.max_s < 3.5
    track = line_run["track"]
    t = np.array([r[0] for r in track])
    for k, end in enumerate(hold_ends(emu, plan)):
        # The last 0.3 s of each hold: the board's own angles inside the band (to the count a
        # reading dithers by at its edge), the plant's true ones too (the sensor's noise on top).
        rows = [r for r in track if end - 0.3 <= r[0] <= end]
        assert rows, (k, end, t.min(), t.max())
        for _, true, est in rows:
            assert np.all(np.abs(np.asarray(est) - POSES[k]) <= TOL + 1e-9), (k, est)
            assert np.all(np.abs(np.asarray(true) - POSES[k]) <= BAND + 0.01), (k, true)
    assert np.all(np.abs(np.asarray(track[-1][1]) - POSES[-1]) <= BAND + 0.01)   # at rest after the run
    assert s.tracking_setpoint["joint1"].samples > 0 and math.isfinite(s.tracking_plan["joint3"].max)


def test_the_settle_times_agree_with_the_boards_own_records(line_run):
    """The summary's settle times from the host's telemetry and DONE events, and the same
    computed from what the board sent (its T lines as the HAL saw them, its log's DONE
    times): within one telemetry period (20 ms at 50 Hz) of each other."""
    plan, s = line_run["plan"], line_run["summary"]
    track = line_run["track"]
    t = np.array([r[0] for r in track])
    est = np.array([r[2] for r in track])
    done = {i: ms / 1000.0 for i, (ms, _wid, _v) in enumerate(line_run["executed"])}
    ours = settle_times(t, est, plan.q, done, np.full(3, TOL), float(t[-1]))
    for name, st in zip(SOFT3.joint_names, ours):
        assert (st.waypoints, st.unsettled) == (s.settle[name].waypoints, s.settle[name].unsettled)
        assert st.max_s == pytest.approx(s.settle[name].max_s, abs=0.021), name
        assert st.mean_s == pytest.approx(s.settle[name].mean_s, abs=0.021), name


def test_the_recording_holds_the_syringe_positions_and_end_stops(line_run):
    data = read(line_run["rrd"])
    cols = {i: data[f"/pump/syringe{i}"]["columns"]["Scalars:scalars"] for i in (1, 2, 3)}
    n = len(cols[1])
    assert n >= 0.9 * line_run["summary"].telemetry_samples and all(len(c) == n for c in cols.values())
    syringes = np.array([[v[0] for v in cols[i]] for i in (1, 2, 3)]).T
    assert np.all((syringes >= 0.0) & (syringes <= 1.0))
    # The board's own numbers: its T lines' syringe columns (per-mille) as the HAL saw them go out.
    sent = np.array([c[10:13] for _, c in line_run["telemetry"]]) / 1000.0
    assert set(map(tuple, np.round(syringes, 3))) <= set(map(tuple, np.round(sent, 3)))
    assert syringes.max(axis=0).min() > 0.0          # every syringe pushed air in for the first pose
    stops = [v[0] for v in data["/pump/end_stops"]["columns"]["Scalars:scalars"]]
    assert len(stops) == n and set(stops) <= {float(b) for b in range(64)}
    for j in SOFT3.joint_names:
        assert data[f"/joints/{j}/q"]["rows"] > 0 and data[f"/joints/{j}/effort"]["rows"] > 0
    tree = layout(line_run["rrd"])
    flat = str(names(tree))
    assert "syringe positions" in flat and "end stops" in flat


def test_settle_times_of_a_known_trace():
    """settle_times on a hand-made trace: joint 1 reaches 1.0 at t = 1.3 and stays, joint 2
    overshoots back out of the band once; the hold (waypoint 1) extends the window; a
    joint that is never inside by its next move counts as unsettled."""
    t = np.arange(0, 4.0, 0.1)
    q = np.zeros((len(t), 2))
    q[:, 0] = np.clip(t / 1.3, 0, 1.0)
    q[:, 1] = np.where(t < 1.5, 0.97, 1.0)
    q[(t > 1.65) & (t < 1.75), 1] = 1.2                 # one sample at 1.7 outside the band
    plan_q = np.array([[1.0, 1.0], [1.0, 1.0], [0.0, 1.0]])
    done = {0: 1.0, 1: 2.0, 2: 3.0}
    j1, j2 = settle_times(t, q, plan_q, done, np.array([0.05, 0.05]), float(t[-1]))
    # joint 1: waypoint 0 inside from 1.3 (0.95 at 1.2 is not) -> 0.3 s; waypoint 2 (to 0.0) never is.
    assert (j1.waypoints, j1.unsettled) == (2, 1) and j1.max_s == pytest.approx(0.3)
    # joint 2: only waypoint 0 moves it; out at 1.7, inside again from 1.8 -> 0.8 s after DONE.
    assert (j2.waypoints, j2.unsettled) == (1, 0) and j2.mean_s == pytest.approx(0.8)


def test_the_run_waits_for_the_arm_to_stop_not_only_to_enter_its_band():
    """executor/settle.py: `resting` is true once the joints sit inside the dead band; the pump's
    fine settle goes on inside it, and the goal is judged on the last sample, so the run also
    waits until no reading moves more than STILL_RAD over STILL_S (`still`)."""
    from armbridge.executor.settle import STILL_RAD, STILL_S, resting, still

    t = np.arange(0, 2.0, 0.02)
    q = np.c_[np.where(t < 1.0, 1.0 - 0.05 * (1.0 - t), 1.0), np.full(len(t), 0.5)]  # in the band, creeping
    samples = [(float(tt), "IDLE", qq, None, 0) for tt, qq in zip(t, q)]
    band = np.array([0.07, 0.07])
    upto = [s for s in samples if s[0] <= 0.9]
    assert resting(upto, np.array([1.0, 0.5]), band) and not still(upto)
    assert still(samples) and still(samples, STILL_RAD, STILL_S)
    noisy = [(s[0], s[1], s[2] + [0.0, 0.004 * (-1) ** k], None, 0) for k, s in enumerate(samples)]
    assert not still(noisy)        # 8 mrad peak to peak: more than a few counts
    assert not still(samples[:5])  # less than STILL_S of telemetry


# ---------------------------------------------------------------- link faults and resets

def test_exactly_once_under_link_faults_and_a_reset(ports, tmp_path, monkeypatch):
    """A reset 0.4 s (sim time) after the first waypoint's DONE, under 2 % dropped and 2 %
    damaged bytes on the host's lane (lines lost and resent, answers intact so the BOOT
    after the reset is seen): the board's log holds each waypoint once, with its values (the
    first, done before the reset, is not run again). The reset is scheduled from the board's
    own DONE, so it falls between the two DONEs however long the handshake took."""
    from armbridge.emulator.board import EmulatedBoard

    real = EmulatedBoard._on_done

    def on_done(self, wid, targets):
        real(self, wid, targets)
        if len(self.executed) == 1:
            self.schedule_reset(self.clock.t + 0.4)

    monkeypatch.setattr(EmulatedBoard, "_on_done", on_done)
    plan = soft_plan(POSES[:1], (1.0,), (1.5,))
    url = "emu:arduino_pump?speed=0&drop=0.02&corrupt=0.02&lanes=rx&seed=5"
    summary = run_plan(plan, url, tmp_path / "faults.rrd", progress=False, timeout=30)
    emu = ports[0].emulator
    assert summary.completed, summary
    assert emu.counters["resets"] == 1 and summary.resyncs >= 1
    c = emu.counters
    assert c["rx"]["drop"] + c["rx"]["corrupt"] > 0 and summary.waypoints_retransmitted + summary.line_errors > 0, c
    assert_executed_once_with_values(emu, plan)       # across the reset: each waypoint once, the values sent


# ---------------------------------------------------------------- the board's safety paths

@pytest.fixture
def board():
    """A BoardClient session with the emulated pump board; yields (client, emulator)."""
    port = open_port("emu:arduino_pump?speed=0")
    client = BoardClient(port, SOFT3)
    try:
        client.connect()
        yield client, port.emulator
    finally:
        port.close()


def test_a_clean_connect_has_no_line_error_on_either_side(board):
    """A fault-free link connects without one damaged line either way. The HELLO the
    host sends at once reaches the chip while it boots: what arrives before its receiver
    is enabled is lost, and a tail it catches is dropped without ER (link.cpp,
    next_byte); the board's BOOT prompts the HELLO again at once, not 250 ms later. The
    T lines the board sends before HELLO's answer are not read as damaged (their
    columns after the 3n, the pump's four, need HELLO's n)."""
    client, emu = board
    connected_at = emu.clock.t          # at most HOST_LEAD_S past the host's last read
    client.drain(0.3)
    st = client.stats
    assert (st.board_framing_errors, st.host_line_errors, st.board_lines_lost, st.seq_errors) == (0, 0, 0, 0), st
    assert st.boots == 1 and st.retransmissions <= 1 and connected_at < HELLO_INTERVAL_S, (st, connected_at)
    c = emu.counters
    assert not any(c[lane][k] for lane in ("rx", "tx") for k in ("drop", "corrupt", "dup", "delay")), c
    assert c["overruns"] == 0 and emu.runner.stats["lost"] == 0, c   # no byte the chip's FIFO refused


def quiet_for(client, emu, seconds: float) -> None:
    """The host reads but sends nothing for `seconds` of sim time (no keep-alive)."""
    end = emu.clock.t + seconds
    while emu.clock.t < end:
        client.port.read(4096)


def test_bad_commands_are_refused_and_the_firmware_keeps_running(board):
    client, emu = board
    for args, code in ((("DBAND", 4, 50), P.RANGE), (("DBAND", 1, 5000), P.RANGE),
                       (("BEND", 1, 300, 0, 300, 500), P.RANGE), (("W", 1, 500, 600, 0, 0), P.RANGE),
                       (("GAIN", 1, 2), P.ARGS), (("FROB",), P.VERB)):
        ans = client.ask(*args)
        assert isinstance(ans, P.Er) and ans.code == code, (args, ans)
    assert isinstance(client.ask("PING"), P.Ok)
    t0 = emu.clock.t
    seen: list[int] = []
    client.on_telemetry = lambda t, m: seen.append(m.ms)
    client.drain(0.3)
    assert len(seen) >= 5 and emu.clock.t - t0 >= 0.3     # telemetry still flowing
    assert client.stat()[0] == "IDLE" and all(u == 0.0 for u in emu.hal.duties)


def test_estop_turns_the_motors_off_within_one_control_period(board):
    client, emu = board
    client.command("W", 0, 2000, 400, 700, 800)
    client.drain(1.5, until=lambda: any(emu.hal.duties))
    client.drain(0.3)
    assert any(emu.hal.duties), "the motors never ran"
    client.estop()
    client.drain(1.0, until=lambda: client.state == "ESTOP")
    assert client.state == "ESTOP"
    t_byte, t_off = emu.estop_byte_at[-1], emu.outputs_off_at[-1]
    assert 0.0 <= t_off - t_byte <= emu.cfg.PERIOD_MS / 1000.0
    assert emu.hal.duty_log[-1][1] == (0.0, 0.0, 0.0) and emu.hal.duty_log[-1][0] <= t_off + 1e-9
    client.drain(0.3)
    assert emu.hal.duties == (0.0, 0.0, 0.0)
    assert isinstance(ans := client.ask("W", 1, 500, 100, 100, 100), P.Er) and ans.code == P.LATCHED


def test_the_watchdog_latches_and_stops_the_motors(board):
    client, emu = board
    client.command("WDOG", 300)
    client.command("W", 0, 3000, 300, 500, 600)
    client.drain(2.0, until=lambda: any(emu.hal.duties))
    assert any(emu.hal.duties)
    t0 = emu.clock.t
    quiet_for(client, emu, 0.6)
    client.drain(0.5, until=lambda: client.state == "WDOG")
    assert client.state == "WDOG"
    # The last line the board took was just before t0; it fires 300 ms later, at a control tick.
    off = [t for t in emu.outputs_off_at if t >= t0]
    assert off and off[0] - t0 <= 0.3 + 2 * emu.cfg.PERIOD_MS / 1000.0, (off, t0)
    assert emu.hal.duties == (0.0, 0.0, 0.0)


def test_an_end_stop_stops_that_pump(board):
    """BEND makes joint 1 read 400 mrad while it is straight; a waypoint to 0 then pulls its
    syringe back to the retracted end stop: ENDSTOP 1, that pump stops, the others run on."""
    client, emu = board
    events: list[P.Event] = []
    client.on_event = lambda t, ev: events.append(ev)
    client.command("BEND", 1, 205, 400, 716, 1447)
    client.command("W", 0, 300, 0, 300, 300)
    client.drain(2.0, until=lambda: any(ev.kind == "ENDSTOP" for ev in events))
    stop = [ev for ev in events if ev.kind == "ENDSTOP"]
    assert stop and stop[0].args[0] == "1", events
    retracted, _ext = emu.hal.pump.end_stops()
    assert retracted[0] and emu.hal.pump.x[0] <= emu.hal.pump.p.switch_mm
    client.drain(0.2)
    assert emu.hal.duties[0] >= 0.0              # pump 1 is not driven further back
    assert emu.hal.duties[1] > 0.0 or emu.hal.pump.q[1] > 0.2   # pump 2 inflates its joint meanwhile


# ---------------------------------------------------------------- Modbus

def test_the_plan_runs_over_modbus_with_the_same_summary(ports, tmp_path, monkeypatch):
    """The same plan over Modbus against the same .elf. In Modbus mode the board sends no
    lines, so its log (on_done) and the HAL's track stay empty: the plant's truth is read
    at each of the host's polls instead, on the board's clock."""
    from armbridge.executor.modbus_client import ModbusClient

    truth: list[tuple[float, np.ndarray]] = []
    clients: list[ModbusClient] = []
    real_poll = ModbusClient.poll

    def poll(self):
        msg = real_poll(self)
        truth.append((self.board_time, ports[0].emulator.hal.pump.q.copy()))
        clients[:] = [self]
        return msg

    monkeypatch.setattr(ModbusClient, "poll", poll)
    plan = soft_plan()
    summary = run_plan(plan, "modbus:emu:arduino_pump?addr=1&speed=0", tmp_path / "mb.rrd", progress=False,
                       timeout=120)
    assert summary.completed and summary.final_state == "IDLE", summary
    assert summary.waypoints_done == len(plan.q) and summary.fw == "arduino_pump"
    assert summary.settle_tolerance_source == "board"           # holding registers 12..14
    assert summary.settle_tolerance == {n: pytest.approx(TOL) for n in SOFT3.joint_names}
    for name, st in summary.settle.items():
        assert (st.waypoints, st.unsettled) == (2, 0), (name, st)
        assert 0.0 <= st.mean_s <= st.max_s < 3.5
    assert set(summary.to_dict()["settle"]["joint1"]) == {"mean_s", "max_s", "waypoints", "unsettled"}
    done = clients[0].done_times
    for k, pose in enumerate(POSES):
        end = done[2 * k + 1]
        rows = [q for tt, q in truth if end - 0.3 <= tt <= end]
        assert rows and all(np.all(np.abs(q - pose) <= BAND + 0.01) for q in rows), (k, rows and rows[-1])
    data = read(tmp_path / "mb.rrd")
    assert len(data["/pump/syringe1"]["columns"]["Scalars:scalars"]) > 10


# ---------------------------------------------------------------- streaming short waypoints

def stream_plan(n: int = 300, step_s: float = 0.02):
    """`n` waypoints of `step_s` each along a slow sweep inside the soft arm's limits:
    the streaming case (a W line, an OK and a DONE every 20 ms)."""
    s = np.linspace(0.0, 1.0, n)[:, None]
    q = POSES[1] + (POSES[0] - POSES[1]) * 0.5 * (1 - np.cos(2 * np.pi * s))
    return make_plan(SOFT3, q, [step_s] * n, {"tool": "armbridge tests", "shape": "stream"})


@pytest.fixture
def board_lines(monkeypatch):
    """Every line the board writes (bodies, CRC cut), as it wrote them."""
    from armbridge.emulator.simavr_runner import SimavrBoard

    lines: list[str] = []
    real = SimavrBoard._board_byte

    def board_byte(self, b):
        if b == 0x0A:
            lines.append(bytes(self._tx).split(b"*", 1)[0].decode("latin-1"))
        real(self, b)

    monkeypatch.setattr(SimavrBoard, "_board_byte", board_byte)
    return lines


def test_a_clean_stream_loses_no_received_byte(ports, tmp_path, board_lines):
    """300 waypoints of 20 ms on a clean link: once the session is open no line reaches the
    board damaged (its receive ring outlasts the longest main-loop pass: no ER CRC; a
    64-byte ring lost ~1 W line in 10), none is lost in the USART, none is resent, every
    waypoint runs once; and RAM is left at the deepest stack with the 256-byte ring."""
    from armbridge.emulator.pump_hal import pump_timing
    plan = stream_plan()
    summary = run_plan(plan, "emu:arduino_pump?speed=0", tmp_path / "stream.rrd", progress=False, timeout=120)
    emu = ports[0].emulator
    assert summary.completed and summary.waypoints_retransmitted == 0, summary
    opened = next(i for i, ln in enumerate(board_lines) if ln.split()[1:2] == ["OK"] and "arduino_pump" in ln)
    assert [ln for ln in board_lines[opened:] if ln.split()[1:2] == ["ER"]] == []
    assert_executed_once_with_values(emu, plan)
    timing = pump_timing(emu)
    assert timing["uart_bytes_lost"] == 0
    assert timing["free_ram_bytes"] > 512, timing["free_ram_bytes"]   # stack and heap headroom


def test_a_reset_mid_stream_keeps_the_last_done(ports, tmp_path, monkeypatch, board_lines):
    """A reset in the middle of a stream of 20 ms waypoints (DONEs every 20 ms: the EEPROM
    copy of the link record never finishes a slot): the record in .noinit SRAM survives the
    reset, so the HELLO after it answers done = the last DONE the board reported, and the
    plan finishes with every waypoint exactly once."""
    from armbridge.emulator.board import EmulatedBoard

    lines = board_lines
    real_done = EmulatedBoard._on_done

    def on_done(self, wid, targets):
        real_done(self, wid, targets)
        if len(self.executed) == 40:
            self.schedule_reset(self.clock.t + 0.05)

    monkeypatch.setattr(EmulatedBoard, "_on_done", on_done)
    plan = stream_plan(120)
    summary = run_plan(plan, "emu:arduino_pump?speed=0", tmp_path / "reset.rrd", progress=False, timeout=60)
    emu = ports[0].emulator
    assert summary.completed and emu.counters["resets"] == 1 and summary.resyncs >= 1, summary
    boot = [i for i, ln in enumerate(lines) if ln.split()[1:2] == ["BOOT"]][1]   # the reset's
    last_done = [int(f[4]) for f in map(str.split, lines[:boot]) if f[1:2] == ["EV"] and f[3:4] == ["DONE"]][-1]
    assert last_done >= 40
    hello = next(ln.split() for ln in lines[boot:] if ln.split()[1:2] == ["OK"] and "arduino_pump" in ln)
    assert hello[-3] == str(last_done), (hello, last_done)
    assert_executed_once_with_values(emu, plan)
