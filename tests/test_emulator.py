"""Emulator pieces (plant, paced UART, SimHal, fault parsing) and the emulated
board in lockstep (no pty: bytes go in with inject() and come out with
read_output()), spoken to in protocol v2 by the host codec."""
import math
import sys

import numpy as np
import pytest

from armbridge.emulator.board import EmulatedBoard
from armbridge.emulator.faults import Faults, parse_delay, parse_lanes, parse_rate, parse_seconds, parse_stall
from armbridge.emulator.plant import PlantParams, ServoPlant, step
from armbridge.emulator.runner import load_firmware
from armbridge.emulator.simhal import PersistentMemory, SimClock, SimHal, ticks_diff
from armbridge.emulator.uart import LinkFaults, PacedUart
from armbridge.errors import ArmbridgeError
from armbridge.resources import firmware_dir
from plan_runs import crashing_firmware
from emu_host import Codec, is_reply

BT = 1.0 / 11520.0  # one byte at 115200 8N1


# ---------------------------------------------------------------- plant

def plant(**kw):
    return ServoPlant([0.0, -3.142, -1.571], [3.142, 0.0, 1.571], PlantParams(**kw), q0=[1.0, -1.0, 0.0])


def test_step_is_pure():
    q, v, u = np.zeros(3), np.zeros(3), np.ones(3)
    lo, hi = np.full(3, -1.0), np.full(3, 1.0)
    q2, v2 = step(q, v, u, 0.001, PlantParams(), lo, hi)
    assert np.all(q == 0) and np.all(v == 0)
    assert np.all(v2 > 0) and np.all(q2 > 0)


def test_step_response_acceleration_limit_then_lag():
    p = ServoPlant([-10.0] * 3, [10.0] * 3, q0=[0.0] * 3)
    p.drive([1.0, 1.0, 1.0])
    p.advance(0.010)
    # 166 rad/s^2 asked by the lag at rest, 60 allowed: v = 60 * t
    assert p.v == pytest.approx([0.6] * 3, abs=1e-6)
    p.advance(0.5)
    assert p.v == pytest.approx([5.0] * 3, rel=1e-3)


def test_step_response_first_order_lag():
    p = plant(a_max=1e9)
    p.drive([1.0, 0.0, -0.5])
    p.advance(0.030)  # one time constant
    assert p.v == pytest.approx([5.0 * (1 - math.exp(-1)), 0.0, -2.5 * (1 - math.exp(-1))], rel=2e-3)


def test_effort_is_clipped_and_off_lets_velocity_decay():
    p = plant()
    p.drive([3.0, -3.0, 0.0])
    assert list(p.u) == [1.0, -1.0, 0.0]
    p.advance(0.2)
    p.off()
    assert not p.driven
    p.advance(0.3)
    assert np.all(np.abs(p.v) < 1e-3)
    q = p.q.copy()
    p.advance(0.1)
    assert np.allclose(p.q, q, atol=1e-4)


def test_hard_stops_beyond_the_limits():
    p = plant()
    p.drive([-1.0, 1.0, 1.0])
    p.advance(2.0)
    assert p.q == pytest.approx([-0.05, 0.05, 1.571 + 0.05])
    assert np.all(p.v == 0)


def test_stall_from_time():
    p = plant()
    p.stall(1, 0.1)
    p.drive([1.0, 1.0, 1.0])
    p.advance(0.1)
    q1 = p.q.copy()
    p.advance(0.2)
    assert p.q[1] == pytest.approx(q1[1], abs=1e-9) and p.v[1] == 0
    assert p.q[0] > q1[0] + 0.5 and p.q[2] > q1[2] + 0.5


def test_potentiometer_noise_and_quantisation():
    p = plant()
    m = np.array([p.measure() for _ in range(4000)])
    assert np.all(np.abs(m.mean(axis=0) - p.q) < 2e-4)
    assert np.all((m.std(axis=0) > 0.0007) & (m.std(axis=0) < 0.0014))
    codes = (m - p.lo_stop) / p.quantum
    assert np.allclose(codes, np.rint(codes), atol=1e-6)
    assert p.quantum == pytest.approx((np.array([3.142, 3.142, 3.142]) + 0.1) / 4095)
    a, b = plant(), plant()
    assert np.array_equal(a.measure(), b.measure())  # seeded


# ---------------------------------------------------------------- paced UART

@pytest.mark.parametrize("lane", ["rx", "tx"])
def test_uart_pacing(lane):
    u = PacedUart()
    push, pop = (u.host_write, u.firmware_read) if lane == "rx" else (u.firmware_write, u.host_read)
    data = bytes(range(200))
    push(data, 1.0)
    assert pop(1.0 + 0.5 * BT) == b""
    assert pop(1.0 + 100 * BT + 1e-9) == data[:100]
    assert pop(1.0 + 200 * BT - 1e-9) == data[100:199]
    assert pop(1.0 + 200 * BT + 1e-9) == data[199:]
    # a byte that arrives while the line is busy waits for it
    push(b"ab", 2.0)
    push(b"c", 2.0)
    assert pop(2.0 + 3 * BT - 1e-9) == b"ab"
    assert pop(2.0 + 3 * BT + 1e-9) == b"c"


def test_uart_n_bytes_take_n_over_11520_seconds():
    u = PacedUart()
    u.host_write(b"x" * 11520, 0.0)
    assert len(u.firmware_read(0.5 + 1e-9)) == 5760
    assert len(u.firmware_read(1.0 - 1e-6)) == 5759
    assert len(u.firmware_read(1.0 + 1e-9)) == 1


DATA = bytes(range(0x20, 0x7F)) * 4


def run_lane(faults, data=DATA, seed=0, lanes=("rx", "tx")):
    u = PacedUart(faults=faults, seed=seed, lanes=lanes)
    u.host_write(data, 0.0)
    u.firmware_write(data, 0.0)
    return u, u.firmware_read(10.0), u.host_read(10.0)


def test_uart_no_faults_at_rate_zero():
    u, rx, tx = run_lane(LinkFaults(0.0, 0.0, 0.0, 0.0, 50.0))
    assert rx == DATA and tx == DATA
    for lane in ("rx", "tx"):
        assert u.counters[lane] == {"bytes": len(DATA), "drop": 0, "corrupt": 0, "dup": 0, "delay": 0}


def test_uart_drop_all():
    u, rx, tx = run_lane(LinkFaults(drop=1.0))
    assert rx == b"" and tx == b""
    assert u.counters["rx"]["drop"] == u.counters["tx"]["drop"] == len(DATA)


def test_uart_corrupt_flips_exactly_one_bit():
    u, rx, tx = run_lane(LinkFaults(corrupt=1.0))
    for got in (rx, tx):
        assert len(got) == len(DATA)
        assert all(bin(a ^ b).count("1") == 1 for a, b in zip(got, DATA))
        assert 0x98 not in got  # no single-bit error of a printable byte or LF is the e-stop byte
    assert u.counters["rx"]["corrupt"] == len(DATA)
    flipped = {(a ^ b).bit_length() - 1 for a, b in zip(rx, DATA)}
    assert flipped == set(range(8))


def test_uart_duplicate_all():
    u, rx, tx = run_lane(LinkFaults(dup=1.0))
    assert rx == tx == bytes(b for b in DATA for _ in range(2))
    assert u.counters["tx"]["dup"] == len(DATA)


def test_uart_delay_all():
    u = PacedUart(faults=LinkFaults(delay=1.0, delay_ms=50.0))
    u.host_write(b"abc", 1.0)
    assert u.firmware_read(1.05) == b""
    assert u.firmware_read(1.05 + 3 * BT + 1e-9) == b"abc"
    assert u.counters["rx"]["delay"] == 3


def test_uart_faults_only_on_chosen_lane_and_seeded():
    u, rx, tx = run_lane(LinkFaults(drop=0.3), lanes=("tx",))
    assert rx == DATA and len(tx) < len(DATA)
    assert u.counters["rx"]["drop"] == 0 and u.counters["tx"]["drop"] == len(DATA) - len(tx)
    assert run_lane(LinkFaults(drop=0.3), seed=1)[2] == run_lane(LinkFaults(drop=0.3), seed=1)[2]
    assert run_lane(LinkFaults(drop=0.3), seed=1)[2] != run_lane(LinkFaults(drop=0.3), seed=2)[2]


def test_link_fault_validation():
    with pytest.raises(ValueError, match="drop"):
        LinkFaults(drop=1.5)
    with pytest.raises(ArmbridgeError, match=r"corrupt.*\[0, 1\]"):
        Faults(corrupt=-0.1)
    with pytest.raises(ArmbridgeError, match=r"--dup.*\[0, 1\]"):
        parse_rate("--dup", "2")
    with pytest.raises(ArmbridgeError, match=r"--drop"):
        parse_rate("--drop", "nan")
    assert parse_delay("0.1:50") == (0.1, 50.0)
    with pytest.raises(ArmbridgeError, match="RATE:MS"):
        parse_delay("0.1")
    assert parse_stall("2@1.5") == (2, 1.5)
    with pytest.raises(ArmbridgeError):
        parse_stall("0@1")
    assert parse_lanes("rx, tx") == ("rx", "tx") and parse_lanes("tx") == ("tx",)
    with pytest.raises(ArmbridgeError, match=r"--lanes.*'up'.*rx.*tx"):
        parse_lanes("rx,up", "--lanes")
    with pytest.raises(ArmbridgeError, match="unknown lane"):
        Faults(lanes=("sideways",))
    assert parse_seconds("2.5", "--reset-at") == 2.5
    with pytest.raises(ArmbridgeError, match=r"--reset-at -1 must be >= 0"):
        parse_seconds("-1", "--reset-at")


def test_faults_describe_themselves():
    assert Faults().describe() == "none"
    f = Faults(drop=0.01, delay=0.1, delay_ms=20, lanes=("rx",), reset_at=(2.0,), stall=((2, 1.5),))
    assert f.describe() == "drop 0.01, delay 0.1 x 20 ms, on rx, reset at 2 s, joint 2 stalls at 1.5 s"


# ---------------------------------------------------------------- SimHal

def make_hal(offset_ms=0):
    clock = SimClock()
    return SimHal(clock, plant(), PacedUart(), PersistentMemory(), tick_offset_ms=offset_ms), clock


def test_ticks_diff_wraps():
    assert ticks_diff(0, (1 << 30) - 1) == 1
    assert ticks_diff((1 << 30) - 1, 0) == -1
    assert ticks_diff(5, 3) == 2
    assert ticks_diff(100, (1 << 30) - 100) == 200


def test_simhal_ticks_wrap_like_micropython():
    hal, clock = make_hal(offset_ms=(1 << 30) - 5)
    a_ms, a_us = hal.ticks_ms(), hal.ticks_us()
    assert a_ms == (1 << 30) - 5
    clock.advance_us(10_000)
    b_ms, b_us = hal.ticks_ms(), hal.ticks_us()
    assert b_ms == 5 and hal.ticks_diff(b_ms, a_ms) == 10
    assert 0 <= b_us < (1 << 30) and hal.ticks_diff(b_us, a_us) == 10_000
    assert hal.ticks_add(a_ms, 10) == b_ms


def test_simhal_outputs_uart_and_persist():
    hal, clock = make_hal()
    out = [0.0] * 3
    hal.read_positions(out)
    assert out == pytest.approx([1.0, -1.0, 0.0], abs=0.005)
    clock.advance_us(1000)
    hal.write_outputs([0.5, 0.0, -0.5])
    assert hal.outputs_enabled and hal.outputs_on_at == [0.001]
    clock.advance_us(1000)
    hal.outputs_off()
    hal.outputs_off()
    assert hal.outputs_off_at == [0.002] and not hal.plant.driven
    assert hal.efforts[-1] == (0.001, (0.5, 0.0, -0.5))
    hal.write_outputs([2.0, 0.0, 0.0])
    assert hal.saturation_violations == 1
    assert hal.uart_read() is None
    hal.uart.host_write(b"A\x98", clock.t)
    clock.advance_us(1000)
    assert hal.uart_read() == b"A\x98"
    assert hal.estop_byte_at == [pytest.approx(0.002 + 2 * BT)]
    hal.save_persist(b"AB1 7 3")
    assert hal.load_persist() == b"AB1 7 3"
    with pytest.raises(ValueError):
        hal.save_persist(b"x" * 4096)


# ---------------------------------------------------------------- emulated board, lockstep

class Lockstep:
    """A minimal v2 host over inject()/read_output() (tests/emu_host.py frames the lines)."""

    def __init__(self, emu, keepalive=True):
        self.emu = emu
        self.codec = Codec()
        self.lines = []
        self.raw = b""
        self.keepalive = keepalive  # PING every 0.25 s while waiting (the watchdog wants a live host)
        self._sent_at = 0.0

    @property
    def seq(self):
        return self.codec.seq

    def _put(self, line):
        self.emu.inject(line)
        self._sent_at = self.emu.now()
        return self.codec.seq

    def send(self, verb, *args):
        return self._put(self.codec.line(verb, *args))

    def hello(self, session, max_s=1.0):
        return self._reply(self._put(self.codec.hello(session)), max_s)

    def pump(self):
        data = self.emu.read_output()
        self.raw += data
        self.lines += self.codec.feed(data)

    def find(self, verb, pred=lambda a: True):
        if self.keepalive and self.emu.now() - self._sent_at > 0.25:
            self.send("PING")
        self.pump()
        return next((l for l in self.lines if l[1] == verb and pred(l[2])), None)

    def wait(self, verb, pred=lambda a: True, max_s=5.0):
        found = []

        def check():
            line = self.find(verb, pred)
            if line is not None:
                found.append(line)
            return bool(found)

        assert self.emu.run_until(check, max_s), f"no {verb} within {max_s} s: {self.lines[-5:]}"
        return found[0]

    def request(self, verb, *args, max_s=1.0):
        return self._reply(self.send(verb, *args), max_s)

    def _reply(self, seq, max_s):
        found = []

        def check():
            self.pump()
            found[:] = [l for l in self.lines if is_reply(l, seq)][:1]
            return bool(found)

        assert self.emu.run_until(check, max_s), f"no reply to {seq}: {self.lines[-5:]}"
        return found[0]


@pytest.fixture
def emu():
    e = EmulatedBoard("esp32", speed=0)
    yield e
    e.stop()


def test_unknown_device():
    with pytest.raises(ArmbridgeError, match="esp32"):
        EmulatedBoard("esp99", speed=0)


def test_firmware_modules_are_private(emu):
    names = set(emu.modules)
    assert {"arm", "proto", "config"} <= names and emu.interpreter == "cpython"
    for name in names:
        assert name not in sys.modules
    other = EmulatedBoard("esp32", speed=0)
    for name in names:
        assert other.modules[name] is not emu.modules[name]
    assert emu.board.__class__.__module__ == "arm"
    assert emu.board.cfg is emu.cfg
    # the firmware's own imports resolve inside its namespace
    assert all(m is emu.modules[k] for k, m in vars(emu.modules["arm"]).items()
               if isinstance(m, type(sys)) and k in names)
    before = dict(emu.modules)
    emu.reset()
    emu.run_for(0.3)  # a reset boots fresh modules
    assert all(emu.modules[k] is not before[k] for k in names)


def test_boot_hello_and_waypoints(emu):
    h = Lockstep(emu)
    assert h.wait("BOOT")[2] == ["arm3r", "0.1.0", "2", "IDLE"]
    ok = h.hello(4242)
    assert ok[1] == "OK" and ok[2][2:6] == ["arm3r", "0.1.0", "2", "3"]
    targets = [(2000, -1000, 500), (1000, -2000, -500), (1571, -1571, 0)]
    for i, q in enumerate(targets):
        assert h.request("W", 10 + i, 400, *q)[1] == "OK"
    h.wait("EV", lambda a: a[1] == "DONE" and a[2] == "10")
    assert emu.positions() == pytest.approx(np.array(targets[0]) / 1000, abs=0.03)
    h.wait("EV", lambda a: a[1] == "DONE" and a[2] == "12")
    h.wait("T", lambda a: int(a[0]) > int(h.find("EV", lambda a: a[1] == "DONE" and a[2] == "12")[2][0]) + 300)
    assert emu.positions() == pytest.approx(np.array(targets[2]) / 1000, abs=0.01)
    # the board's log holds what it executed: ids and the values the W lines carried
    assert [(i, v) for _, i, v in emu.executed] == [(10 + i, q) for i, q in enumerate(targets)]
    tel = [l for l in h.lines if l[1] == "T"]
    assert len(tel) > 10 and tel[-1][2][1] == "IDLE"
    assert emu.hal.saturation_violations == 0


def test_reset_mid_motion(emu):
    h = Lockstep(emu)
    h.hello(77)
    h.request("W", 1, 200, 2000, -1000, 500)
    h.request("W", 2, 2000, 500, -2500, -1000)
    h.wait("EV", lambda a: a[1] == "DONE" and a[2] == "1")
    h.wait("EV", lambda a: a[1] == "DONE" and a[2] == "1")  # waypoint 2 starts in this tick
    emu.reset()
    emu.step(1)
    assert emu.state == "RESET" and not emu.hal.outputs_enabled
    assert emu.outputs_off_at[-1] == pytest.approx(emu.resets[-1])
    mark = len(h.raw)
    # the reset may cut a line on the wire: BOOT can arrive glued to its start
    assert emu.run_until(lambda: h.pump() or b" BOOT arm3r 0.1.0 2 IDLE*" in h.raw[mark:], 1.0)
    assert emu.boots[-1] - emu.resets[-1] == pytest.approx(0.25, abs=0.002)
    assert emu.board is not None and emu.state == "IDLE"
    hello = h.hello(77)
    assert hello[2][-3:] == ["1", "-", "IDLE"]  # done survives the reset in persistent memory
    assert [(i, v) for _, i, v in emu.executed] == [(1, (2000, -1000, 500))]


def test_scheduled_reset_from_faults():
    e = EmulatedBoard("esp32", speed=0, faults=Faults(reset_at=(0.3,)))
    e.run_for(0.29)
    assert len(e.boots) == 1
    e.run_for(0.3)
    assert len(e.boots) == 2 and e.resets == [pytest.approx(0.3, abs=0.001)]


def fill_queue(h):
    h.hello(5)
    qsize = int(h.request("STAT")[2][1]) + 0  # FREE of the STAT reply
    for i in range(qsize + 1):
        h.request("W", i, 2000, 1571 + (300 if i % 2 == 0 else -300), -1571, 0)
    return qsize


def test_estop_latency_with_full_queue(emu):
    h = Lockstep(emu)
    qsize = fill_queue(h)
    st = h.request("STAT")
    assert st[2][1] == "0" and st[2][2] == "RUN" and qsize == 32
    assert emu.hal.outputs_enabled
    emu.run_for(0.05)
    emu.inject(b"\x98")
    h.wait("EV", lambda a: a[1] == "ESTOP")
    assert len(emu.estop_byte_at) == 1
    latency = emu.outputs_off_at[-1] - emu.estop_byte_at[-1]
    assert 0 <= latency <= 0.010
    n_eff = len(emu.hal.efforts)
    emu.run_for(0.5)
    assert emu.state == "ESTOP" and not emu.hal.outputs_enabled
    assert len(emu.hal.efforts) == n_eff  # nothing written while latched
    assert h.request("W", 99, 100, 1571, -1571, 0)[2][1:3] == ["9", "LATCHED"]
    h.request("CLR")
    emu.run_for(0.05)
    assert emu.state == "IDLE" and emu.hal.outputs_enabled


def test_estop_mid_line(emu):
    h = Lockstep(emu)
    h.hello(5)
    h.request("W", 1, 3000, 2500, -1571, 0)
    line = h.codec.line("W", 2, 100, 0, -1571, 0)
    emu.inject(line[:8] + b"\x98" + line[8:])
    h.wait("EV", lambda a: a[1] == "ESTOP")
    emu.run_for(0.1)
    assert emu.state == "ESTOP"
    assert emu.outputs_off_at[-1] - emu.estop_byte_at[-1] <= 0.010
    assert not any(l[1] == "ER" for l in h.lines)  # the rest of the line was dropped silently


def test_watchdog_stops_a_silent_host(emu):
    h = Lockstep(emu, keepalive=False)
    h.hello(9)
    for i in range(5):
        h.request("W", i, 1000, 1571 + 400 * (-1) ** i, -1571, 0)
    t0 = emu.now()
    ev = h.wait("EV", lambda a: a[1] == "WDOG", max_s=2.0)
    assert ev is not None and emu.state == "WDOG"
    assert 0.95 <= emu.now() - t0 <= 1.1
    emu.run_for(0.3)  # let the lag bleed off
    q = emu.positions()
    emu.run_for(0.5)
    assert emu.positions() == pytest.approx(q, abs=0.002)
    assert all(e == (0.0, 0.0, 0.0) for _, e in list(emu.hal.efforts)[-40:])


def test_stalled_joint_latches_fault():
    e = EmulatedBoard("esp32", speed=0, faults=Faults(stall=((2, 0.2),)))
    h = Lockstep(e)
    h.hello(3)
    h.request("W", 1, 1500, 2500, -500, 1000)
    ev = h.wait("EV", lambda a: a[1] == "FAULT", max_s=3.0)
    assert ev[2][2] == "2" and e.state == "FAULT" and not e.hal.outputs_enabled


def test_single_bit_errors_never_estop():
    e = EmulatedBoard("esp32", speed=0, faults=Faults(corrupt=1.0, lanes=("rx",)))
    h = Lockstep(e)
    for _ in range(30):
        h.send("PING")
        e.run_for(0.02)
    h.pump()
    assert e.estop_byte_at == [] and e.state == "IDLE"
    assert e.counters["rx"]["corrupt"] == e.counters["rx"]["bytes"] > 300
    assert not any(l[1] == "OK" for l in h.lines)
    assert any(l[1] == "ER" for l in h.lines)


def test_board_runs_across_the_tick_wrap():
    e = EmulatedBoard("esp32", speed=0, tick_offset_ms=(1 << 30) - 300)
    h = Lockstep(e)
    h.hello(1)
    h.request("W", 1, 600, 2000, -1571, 0)
    ev = h.wait("EV", lambda a: a[1] == "DONE")
    assert int(ev[2][0]) < 1000  # board time wrapped
    tel = [int(l[2][0]) for l in h.lines if l[1] == "T"]
    assert max(tel) > (1 << 30) - 300 and min(tel) < 1000


def test_load_firmware_restores_sys_path_and_modules():
    path = list(sys.path)
    sys.modules["proto"] = marker = type(sys)("proto")
    try:
        e = EmulatedBoard("esp32", speed=0)
        assert sys.modules["proto"] is marker
        assert e.modules["proto"] is not marker
    finally:
        del sys.modules["proto"]
    assert sys.path == path
    with pytest.raises(ArmbridgeError, match="missing"):
        load_firmware([firmware_dir() / "nowhere"], ("arm",))


@pytest.mark.parametrize("args, words", [
    (["esp99"], ["esp99", "esp32"]),
    (["esp32", "--drop", "1.5"], ["--drop", "[0, 1]"]),
    (["esp32", "--corrupt", "-0.1"], ["--corrupt", "[0, 1]"]),
    (["esp32", "--delay", "0.5"], ["--delay", "RATE:MS"]),
    (["esp32", "--stall", "x"], ["--stall"]),
    (["esp32", "--lanes", "rx,up"], ["--lanes", "'up'"]),
    (["esp32", "--reset-at", "-1"], ["--reset-at", ">= 0"]),
    (["esp32", "--interpreter", "pypy"], ["--interpreter", "cpython, micropython"]),
])
def test_cli_refuses_bad_arguments(args, words):
    from armbridge.emulator.command import emulate_cmd
    from armbridge.errors import ArmbridgeError
    import typer
    from typer.testing import CliRunner

    app = typer.Typer()
    app.command()(emulate_cmd)
    result = CliRunner().invoke(app, args)
    assert isinstance(result.exception, ArmbridgeError), result.output
    for w in words:
        assert w in str(result.exception)


def test_firmware_exception_stops_the_board_until_reset(tmp_path):
    crashing_firmware(tmp_path)
    e = EmulatedBoard("esp32", speed=0, firmware_root=tmp_path)
    with pytest.raises(RuntimeError, match="boom"):
        e.step(1)
    assert e.state == "CRASHED" and "boom" in e.crash
    e.reset()
    e.run_for(0.255)
    assert e.state == "IDLE" and len(e.boots) == 2
