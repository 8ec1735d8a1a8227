"""The host's Modbus RTU path (link/modbus.py, executor/modbus_client.py) against a real
peer: pymodbus's own server on a paced pty serving docs/modbus.md's register map from
a Python model of the pump board (tests/modbus_peer.py); and, once the pump firmware
runs in simavr, against the .elf (skipped with the reason until then; a failure under
ARMBRIDGE_REQUIRE_HIL=1).
"""
from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from pymodbus.pdu.register_message import ReadHoldingRegistersRequest

from armbridge.errors import ArmbridgeError
from armbridge.link.modbus import ModbusError, parse_modbus_url, t35_s, to_i16, to_u16
from armbridge.link.transport import PortError, open_port
from armbridge.plans.format import make_plan
from armbridge.robots.catalog import get_robot
from cli_procs import ARMBRIDGE
from modbus_peer import NONE, QSIZE, Peer, PumpModel
from require import missing
from rtu_raw import crc16, inputs, rtu

ADDR = 3


@pytest.fixture
def peer():
    with Peer(PumpModel(), addr=ADDR) as p:
        yield p


@pytest.fixture
def port(peer):
    with open_port(f"modbus:{peer.port_name}?addr={ADDR}") as p:
        yield p


def soft3_plan(k: int = 6, dt: float = 0.4):
    t = np.arange(1, k + 1) / k
    q = np.outer(t, [0.4, 0.8, 0.9])  # inside soft3's 0..30, 0..55, 0..60 degrees
    return make_plan(get_robot("soft3"), q, dt, {"tool": "armbridge tests", "shape": "ramp"})


# ---------------------------------------------------------------------- urls and values
def test_url_parameters() -> None:
    assert parse_modbus_url("modbus:/dev/ttyUSB0?addr=7") == (
        "/dev/ttyUSB0", {"addr": 7, "baud": 115200, "timeout": 0.25, "retries": 2})
    inner, p = parse_modbus_url("modbus:emu:arduino_pump?speed=0&addr=2&timeout=500&seed=3")
    assert inner == "emu:arduino_pump?speed=0&seed=3" and p["addr"] == 2 and p["timeout"] == 0.5
    for bad, what in (("modbus:", "names no port"), ("modbus:/dev/x?addr=0", "addr=0"),
                      ("modbus:/dev/x?addr=two", "not an integer"), ("modbus:/dev/x?retries=99", "retries=99")):
        with pytest.raises(ArmbridgeError, match=what):
            parse_modbus_url(bad)


def test_bad_port_is_one_usage_error() -> None:
    with pytest.raises(PortError, match="no such device") as e:
        open_port("modbus:/dev/does-not-exist?addr=1")
    assert e.value.usage
    with pytest.raises(PortError, match="addr=300") as e:
        open_port("modbus:/dev/null?addr=300")
    assert e.value.usage


def test_signed_registers_and_gap() -> None:
    assert to_u16(-1) == 0xFFFF and to_u16(-32768) == 0x8000 and to_u16(1047) == 1047
    assert to_i16(0xFF9C) == -100 and to_i16(32767) == 32767
    with pytest.raises(ArmbridgeError):
        to_u16(70000)
    assert t35_s(115200) == 0.00175 and abs(t35_s(9600) - 0.00401) < 1e-6


# ---------------------------------------------------------------------- reads, writes, CRC, exceptions
def test_reads_and_writes(peer, port) -> None:
    m = port.master
    ident = m.read_input(32, 14)
    name = b"".join(bytes([w >> 8, w & 0xFF]) for w in ident[:8]).rstrip(b"\0")
    assert name == b"arduino_pump" and ident[11:14] == [2, 3, QSIZE]
    assert m.read_holding(15, 9) == [0, 0, 0, 524, 960, 1047, 500, 500, 500]
    m.write_register(13, 90)  # DBAND joint 2, FC6
    m.write_registers(3, [1500, 2500, 3500])  # kp, FC16
    assert m.read_holding(3, 3) == [1500, 2500, 3500] and peer.model.hold[13] == 90
    m.write_registers(15, [-20, -30, -40])  # signed limits travel as two's complement
    assert [to_i16(v) for v in m.read_holding(15, 3)] == [-20, -30, -40]
    assert m.read_input(14, 1) == [NONE] and m.read_input(15, 1) == [QSIZE]


def test_request_frames_are_rtu(peer, port) -> None:
    """What goes on the wire: address, PDU, CRC-16/MODBUS low byte first (the spec's example)."""
    port.master.addr = 1
    peer.requests.clear()
    with pytest.raises(ModbusError):  # nobody at address 1: no answer, and nothing retried
        port.master.request(ReadHoldingRegistersRequest(address=0, count=10), retries=0)
    assert b"".join(peer.requests) == bytes.fromhex("01030000000AC5CD")


def test_damaged_reply_is_retried(peer, port) -> None:
    m = port.master
    peer.corrupt_replies = 1
    assert m.read_holding(21, 3) == [500, 500, 500]
    assert m.stats.bad_replies == 1 and m.stats.retries == 1
    peer.corrupt_replies = 1
    with pytest.raises(ModbusError, match="damaged reply") as e:
        m.request(ReadHoldingRegistersRequest(address=21, count=1), retries=0)
    assert e.value.code is None


@pytest.mark.parametrize("case,code", [("address", 2), ("value", 3), ("latched", 4), ("busy", 6)])
def test_exceptions(peer, port, case: str, code: int) -> None:
    m = port.master
    with pytest.raises(ModbusError, match=f"exception {code:02d}") as e:
        if case == "address":
            m.read_input(20, 1)  # 20..31 are not mapped
        elif case == "value":
            m.write_register(12, 1001)  # dead band above 1000 mrad
        elif case == "latched":
            m.write_register(36, 4)  # ESTOP
            m.write_registers(100, [1, 100, 10, 10, 10])
        else:
            for i in range(QSIZE + 2):  # the first runs (60 s), the next QSIZE fill the queue
                m.write_registers(100, [i, 60000, 10, 10, 10])
    assert e.value.code == code


# ---------------------------------------------------------------------- plans
def test_plan_runs_over_the_window(peer, tmp_path) -> None:
    from armbridge.executor.run import run_plan

    plan = soft3_plan()
    queued: list[list[int]] = []
    model = peer.model
    real = model.write_window

    def spy(regs):
        ex = real(regs)
        if ex is None:
            queued.append(list(regs))
        return ex

    model.write_window = spy  # type: ignore[method-assign]
    summary = run_plan(plan, f"modbus:{peer.port_name}?addr={ADDR}", tmp_path / "run.rrd", rate_hz=50,
                       progress=False)
    assert summary.waypoints_done == plan.k and summary.final_state == "IDLE"
    assert summary.fw == "arduino_pump" and summary.telemetry_samples > 10
    # every waypoint queued exactly once, in order, with its duration and angles
    want = [[i, 400, *(int(round(v * 1000)) for v in row)] for i, row in enumerate(plan.q)]
    assert queued == want
    assert np.allclose(model.q, plan.q[-1] * 1000, atol=1)
    assert (tmp_path / "run.rrd").stat().st_size > 0


def test_lost_window_reply_runs_once(peer) -> None:
    """A window write whose reply is lost is checked against the queued id, not rewritten."""
    from armbridge.executor.session import open_session

    plan = soft3_plan(k=4, dt=0.5)
    model = peer.model
    real = model.write_window

    def lose_first_reply(regs):
        if model.window_writes == 0:
            peer.drop_replies = 1  # the reply to this write, sent after it is taken
        return real(regs)

    model.write_window = lose_first_reply  # type: ignore[method-assign]
    with open_session(f"modbus:{peer.port_name}?addr={ADDR}", plan.robot) as c:
        c.execute([100] * 4, [[int(round(v * 1000)) for v in row] for row in plan.q])
        assert c.done_index == 3 and c.stats.timeouts == 1
    assert peer.model.window_writes == 4 and peer.model.done == 3


def test_estop_and_clear(peer) -> None:
    from armbridge.executor.session import open_session

    events = []
    with open_session(f"modbus:{peer.port_name}?addr={ADDR}", None, latched="allow",
                      on_event=lambda t, ev: events.append(ev.kind)) as c:
        c.estop()
        assert c.stat()[0] == "ESTOP"
        c.command("CLR")
        assert c.stat()[0] == "IDLE"
        assert not c.can("PEN", 0)  # no pen over Modbus: VERB, as a board without one
    assert events == ["ESTOP", "CLEAR"] and peer.model.commands == [4, 3]


def test_run_refuses_a_latched_board(peer, tmp_path) -> None:
    from armbridge.executor.run import RunFailed, run_plan

    peer.model.write_holding(36, 4)
    with pytest.raises(RunFailed, match="latched in ESTOP"):
        run_plan(soft3_plan(), f"modbus:{peer.port_name}?addr={ADDR}", tmp_path / "x.rrd", progress=False)
    assert peer.model.window_writes == 0


# ---------------------------------------------------------------------- the console
def test_board_info_and_state_cli(peer) -> None:
    url = f"modbus:{peer.port_name}?addr={ADDR}"
    res = subprocess.run([ARMBRIDGE, "board", "info", "--port", url, "--json", "-"], capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 0, res.stderr
    d = json.loads(res.stdout)
    assert d["fw"] == "arduino_pump" and d["protocol"] == 2 and d["joints"] == 3 and d["queue"] == QSIZE
    assert [j["max_mrad"] for j in d["limits"]] == [524, 960, 1047]
    res = subprocess.run([ARMBRIDGE, "board", "state", "--port", url, "--json", "-"], capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["state"] == "IDLE"
    peer.drop_replies = 10 ** 6  # a board that has gone quiet
    res = subprocess.run([ARMBRIDGE, "board", "state", "--port", url], capture_output=True, text=True, timeout=60)
    assert res.returncode == 1 and f"device {ADDR} did not answer" in res.stderr and "Traceback" not in res.stderr


def test_bench_round_trip(peer) -> None:
    from armbridge.bench.modbus import modbus_round_trip, wire_ms

    peer.model.hold[0:3] = [7, 8, 9]
    r = modbus_round_trip(f"modbus:{peer.port_name}?addr={ADDR}", n=10)
    assert r["n"] == 10 and r["retries"] == 0 and r["baud"] == 115200
    for key in ("read_one", "write_setpoints"):
        assert 0 < r[key]["min_ms"] <= r[key]["median_ms"] <= r[key]["p95_ms"] <= r[key]["max_ms"]
    assert r["wire_read_ms"] == pytest.approx(wire_ms(8, 7)) and 4.9 < r["wire_read_ms"] < 5.0
    # the set points written are those the board had: nothing moved
    assert peer.model.hold[0:3] == [0, 0, 0] and peer.model.queue == []


# ---------------------------------------------------------------------- the firmware in simavr
def test_against_the_elf_in_simavr(tmp_path) -> None:
    """pymodbus-framed requests (our master) against the real pump firmware in simavr."""
    try:
        from armbridge.emulator.registry import board_spec

        spec = board_spec("arduino_pump")
    except (ImportError, ArmbridgeError, KeyError) as exc:
        missing(f"the arduino_pump board is not in the emulator registry yet ({exc})")
    from armbridge.resources import firmware_dir

    elf = firmware_dir() / "arduino_pump" / "build" / "arduino_pump.elf"
    if not elf.exists():
        missing(f"the pump firmware is not built ({elf}; make -C firmware/arduino_pump)")
    from armbridge.executor.session import open_session

    plan = soft3_plan(k=3, dt=0.8)
    with open_session("modbus:emu:arduino_pump?speed=0&addr=5", plan.robot, rate_hz=20) as c:
        assert c.info is not None and c.info.fw == spec.identity and c.info.n == 3
        c.execute([500] * 3, [[int(round(v * 1000)) for v in row] for row in plan.q])
        assert c.done_index == 2
        with pytest.raises(ModbusError, match="exception 02"):
            c.master.read_input(20, 1)


def test_elf_loses_no_reply_while_its_control_loop_runs() -> None:
    """Set-point writes against the .elf in simavr: each request's bytes keep the time of
    their receive interrupt, so a frame is never split by a long pass of the main loop
    (before: 19 of 100 writes lost their reply and were retried)."""
    from armbridge.bench.modbus import modbus_round_trip
    from armbridge.resources import firmware_dir

    if not (firmware_dir() / "arduino_pump" / "Makefile").is_file():
        missing("the pump firmware is missing")
    r = modbus_round_trip("modbus:emu:arduino_pump?addr=1&speed=0", 100)
    assert r["retries"] == 0 and r["timeouts"] == 0, r


# ---------------------------------------------------------------------- the first write after a reset
def _elf_board():
    """The .elf in simavr in lockstep, or a skip with the reason."""
    from armbridge.resources import firmware_dir

    if not (firmware_dir() / "arduino_pump" / "Makefile").is_file():
        missing("the pump firmware is missing")
    from armbridge.emulator import EmulatedBoard

    try:
        return EmulatedBoard("arduino_pump", speed=0)
    except ArmbridgeError as exc:
        missing(f"the pump board does not run in simavr here ({exc})")


@pytest.fixture
def reset_in_modbus():
    """The probe of issue 21: HELLO, MODBUS 1, 0.4 s (the EEPROM takes the address), a
    reset: the board boots speaking Modbus with its outputs closed (no HELLO yet)."""
    from test_emulator import Lockstep

    emu = _elf_board()
    try:
        h = Lockstep(emu)
        h.wait("BOOT")
        assert h.hello(5)[1] == "OK" and h.request("MODBUS", 1)[1] == "OK"
        emu.advance(0.4)
        emu.reset()
        emu.advance(0.5)
        emu.read_output()
        yield emu
    finally:
        emu.stop()


def test_the_first_window_write_after_a_reset_runs(reset_in_modbus) -> None:
    """docs/modbus.md: the first write answered without an exception opens the outputs as
    HELLO does. Before: opening held the arm where it was and flushed the queue, so the
    waypoint just acknowledged (input 19 read 777) never ran (done 0xFFFF, free 32)."""
    emu = reset_in_modbus
    frame = bytes.fromhex("01 10 00 64 00 05 0a 03 09 01 90 00 64 00 00 00 00 de 0e")   # W 777 400 100 0 0
    assert frame[-2:] == crc16(frame[:-2])
    emu.inject(frame)
    emu.advance(0.03)
    assert emu.read_output() == bytes.fromhex("01 10 00 64 00 05 41 d5")
    assert inputs(emu, 19, 1) == [777]
    emu.advance(1.0)
    r = inputs(emu, 0, 20)
    assert r[14] == 777 and r[15] == 32 and r[12] == 0   # done, the queue empty again, IDLE
    assert r[3] == 100   # the set point reached the waypoint's target


def test_the_first_set_point_write_after_a_reset_runs(reset_in_modbus) -> None:
    """The same for an FC6 set point (register 0): a waypoint at vmax with the reserved id."""
    emu = reset_in_modbus
    req = bytes([1, 6, 0, 0, 0, 120])
    assert rtu(emu, req) == req + crc16(req)   # FC6 echoes the request
    emu.advance(1.0)
    r = inputs(emu, 0, 20)
    assert r[3] == 120 and r[15] == 32 and r[12] == 0


def test_a_run_over_modbus_after_a_reset_runs_its_first_waypoint(tmp_path, monkeypatch) -> None:
    """`armbridge run` over modbus: after such a reset: every waypoint runs, the first too
    (before: "completed", 4/4 done, while waypoint 0 never ran)."""
    import armbridge.link.transport as transport
    from armbridge.executor.modbus_client import ModbusClient
    from armbridge.executor.run import run_plan

    _elf_board().stop()   # skips with the reason where simavr cannot run the .elf
    real_open = transport.open_port

    def open_then_reset(url, *a, **kw):
        port = real_open(url, *a, **kw)
        if not str(url).startswith("modbus:"):
            return port   # the emulator's own port, opened inside the modbus: one
        emu = port.emulator
        t0 = emu.now()
        while emu.now() < t0 + 0.4:   # the EEPROM takes the Modbus address meanwhile
            port.master.read_input(12, 1)
        emu.reset()
        return port

    set_points: list[np.ndarray] = []
    real_poll = ModbusClient.poll

    def poll(self):
        msg = real_poll(self)
        set_points.append(msg.target.copy())
        return msg

    monkeypatch.setattr(transport, "open_port", open_then_reset)
    monkeypatch.setattr(ModbusClient, "poll", poll)
    q = np.array([[0.3, 0.3, 0.3], [0.1, 0.1, 0.1], [0.2, 0.2, 0.2], [0.1, 0.1, 0.1]])
    plan = make_plan(get_robot("soft3"), q, 1.0, {"tool": "armbridge tests", "shape": "steps"})
    summary = run_plan(plan, "modbus:emu:arduino_pump?addr=1&speed=0", tmp_path / "run.rrd", progress=False,
                       timeout=120)
    assert summary.completed and summary.waypoints_done == 4
    # waypoint 0 ran: the set point went past 0.2 rad, the highest of the others (polled at 50 Hz)
    assert max(sp[0] for sp in set_points) > 0.28
