"""The paper's servo rig (issue 10 §4): the firmware's PCA9685 driver and servo
calibration against the emulated registers on the simulated I2C bus, the
positional servo plant's step function, and the rig end to end on the
emulated board (`--servos pca9685`)."""
from __future__ import annotations

import errno
import math

import numpy as np
import pytest

from armbridge.emulator import EmulatedBoard
from armbridge.emulator import pca9685 as R
from armbridge.emulator.i2c import SimI2C
from armbridge.emulator.pca9685 import Pca9685Model
from armbridge.emulator.registry import board_spec, rig_spec
from armbridge.emulator.runner import load_firmware
from armbridge.emulator.servo_plant import PEN_PARAMS, PenServo, PositionalPlant, ServoParams, step
from armbridge.emulator.simhal import SimClock
from armbridge.errors import ArmbridgeError
from armbridge.resources import firmware_dir
from emu_host import done_ev
from test_emulator import Lockstep

FW = load_firmware([firmware_dir() / "esp32"], ("pca9685", "servos"))
drv_mod, servos_mod = FW["pca9685"], FW["servos"]
ADDR = 0x40


class Chip:
    """A PCA9685 model on a bus, with a clock the driver's busy-waits advance."""

    def __init__(self, wait=True) -> None:
        self.clock = SimClock()
        self.model = Pca9685Model(now=lambda: self.clock.t)
        self.bus = SimI2C(400_000)
        self.bus.attach(ADDR, self.model)
        sleep = self.clock.advance_us if wait else (lambda us: None)
        self.drv = drv_mod.Pca9685(self.bus, ADDR, 50, sleep_us=sleep)

    def led(self, ch):
        return self.bus.readfrom_mem(ADDR, R.LED0_ON_L + 4 * ch, 4)


# ---------------------------------------------------------------- driver vs registers

def test_init_sets_the_prescale_for_50_hz_in_sleep_and_wakes_with_every_channel_off():
    c = Chip()
    want = round(25e6 / (4096 * 50)) - 1
    assert c.model.prescale == c.drv.prescale == want == 121
    assert c.model.period_s == pytest.approx(4096 * 122 / 25e6)         # 19.988 ms
    assert c.drv.period_us == pytest.approx(c.model.period_s * 1e6)
    assert c.model.prescale_blocked == 0 and c.model.restart_early == 0
    assert c.bus.readfrom_mem(ADDR, R.MODE1, 1)[0] == R.AI | R.ALLCALL   # awake, auto-increment
    assert c.bus.readfrom_mem(ADDR, R.MODE2, 1)[0] == R.OUTDRV
    assert c.clock.us == 500 and c.model.frame0 == pytest.approx(500e-6)  # waited for the oscillator
    assert all(c.model.pulse_us(ch) is None for ch in range(16))
    assert drv_mod.prescale_for(60) == round(25e6 / (4096 * 60)) - 1 == 101
    assert drv_mod.prescale_for(5000) == 3 and drv_mod.prescale_for(10) == 255   # the chip's range


def test_pulse_counts_and_full_off():
    c = Chip()
    per_count = c.model.period_s * 1e6 / 4096                            # 4.88 us
    for ch, us in ((0, 500.0), (3, 1500.0), (15, 2500.0)):
        c.drv.pulse_us(ch, us)
        on_l, on_h, off_l, off_h = c.led(ch)
        assert (on_l, on_h) == (0, 0) and (off_h & 0x10) == 0
        assert (off_h << 8 | off_l) == round(us / per_count)
        assert abs(c.model.pulse_us(ch) - us) <= per_count / 2
    c.drv.off(3)
    assert c.led(3)[3] & 0x10 and c.model.pulse_us(3) is None
    assert c.model.pulse_us(0) is not None
    c.drv.all_off()
    assert all(c.model.pulse_us(ch) is None for ch in range(16))
    assert c.bus.readfrom_mem(ADDR, R.ALL_LED_ON_L, 4) == b"\0\0\0\0"      # write-only


def test_sleep_wake_restarts_the_running_channels_after_500_us():
    c = Chip()
    c.drv.pulse_us(2, 1200)
    width = c.model.pulse_us(2)
    c.drv.sleep()
    assert c.model.pulse_us(2) is None
    assert c.bus.readfrom_mem(ADDR, R.MODE1, 1)[0] & R.RESTART            # the chip set RESTART
    t0 = c.clock.us
    c.drv.wake()
    assert c.clock.us - t0 == 500 and c.model.restart_early == 0
    assert c.model.pulse_us(2) == width and not c.bus.readfrom_mem(ADDR, R.MODE1, 1)[0] & R.RESTART
    # a driver that does not wait writes RESTART too early: the chip ignores it
    bad = Chip(wait=False)
    bad.drv.pulse_us(2, 1200)
    bad.drv.sleep()
    bad.drv.wake()
    assert bad.model.restart_early == 1 and bad.model.pulse_us(2) is None


def test_prescale_is_writable_only_in_sleep_and_set_freq_does_it_right():
    c = Chip()
    c.bus.writeto_mem(ADDR, R.PRE_SCALE, b"\x40")                         # awake: blocked
    assert c.model.prescale == 121 and c.model.prescale_blocked == 1
    c.drv.pulse_us(0, 1500)
    c.drv.set_freq(60)
    assert c.model.prescale == 101 and c.model.prescale_blocked == 1
    assert c.model.pulse_us(0) == pytest.approx(307 * c.model.period_s * 1e6 / 4096)  # kept, restarted


def test_auto_increment_writes_and_reads():
    c = Chip()
    regs = bytes([0, 0, 0x33, 0x01, 0, 0, 0x00, 0x02])                    # channels 0 and 1
    c.bus.writeto_mem(ADDR, R.LED0_ON_L, regs)
    assert c.bus.readfrom_mem(ADDR, R.LED0_ON_L, 8) == regs
    c.bus.writeto_mem(ADDR, R.MODE1, bytes([R.ALLCALL]))                  # AI off
    c.bus.writeto_mem(ADDR, R.LED0_ON_L + 8, bytes([1, 2, 3, 4]))         # every byte to LED2_ON_L
    assert c.bus.readfrom_mem(ADDR, R.LED0_ON_L + 8, 4) == bytes([4, 4, 4, 4])
    c.bus.writeto_mem(ADDR, R.MODE1, bytes([R.AI | R.ALLCALL]))
    assert c.bus.readfrom_mem(ADDR, R.LED0_ON_L + 8, 4) == bytes([4, 0, 0, 0x10])
    # past LED15_OFF_H the pointer rolls over to MODE1
    assert c.bus.readfrom_mem(ADDR, R.LED15_OFF_H, 2) == bytes([0x10, R.AI | R.ALLCALL])


def test_a_wrong_address_is_enodev_like_micropython():
    c = Chip()
    assert c.bus.scan() == [ADDR]
    with pytest.raises(OSError) as exc:
        drv_mod.Pca9685(c.bus, 0x41, 50, sleep_us=c.clock.advance_us)
    assert exc.value.errno == errno.ENODEV


def test_the_servo_bank_writes_three_channels_in_one_transfer_and_skips_repeats():
    c = Chip()
    cfg = _cfg()
    bank = servos_mod.ServoBank(c.drv, cfg)
    n0 = c.bus.transfers
    bank.write([1.571, -1.571, 0.0])
    assert c.bus.transfers - n0 == 1 + 1                                  # the joints, and the pen (drives on)
    per_count = c.model.period_s * 1e6 / 4096
    for ch in (0, 1, 2):                                                  # mid-range: 1500 us
        assert abs(c.model.pulse_us(ch) - 1500) <= per_count / 2
    n1 = c.bus.transfers
    bank.write([1.571, -1.571, 0.0])
    assert c.bus.transfers == n1
    bank.off()
    assert all(c.model.pulse_us(ch) is None for ch in (0, 1, 2, 3))
    bank.write([1.571, -1.571, 0.0])
    assert c.model.pulse_us(3) == pytest.approx(cfg.PEN_UP_US, abs=2.5)   # the pen where it was


# ---------------------------------------------------------------- calibration

def _cfg():
    return load_firmware([firmware_dir() / "esp32"], ("config",))["config"]


def test_calibration_round_trip_and_clipping():
    s = servos_mod.Servo(500, -785, 2500, 3927)
    for q in np.linspace(-0.7, 3.8, 19):
        assert s.angle(s.pulse(q)) == pytest.approx(q, abs=1e-9)
    assert s.pulse(-2.0) == 500 and s.pulse(5.0) == 2500
    s.set(1000, 0, 2000, 2356)                                            # pulse 1000 at 0, 2000 at 2.356
    assert s.pulse(0.0) == 1000 and s.pulse(2.356) == pytest.approx(2000)
    with pytest.raises(ValueError):
        s.set(1500, 0, 1500, 1000)
    # through the chip: angle -> pulse -> counts -> the pulse on the pin -> angle
    c = Chip()
    per_count = c.model.period_s * 1e6 / 4096
    for q in (0.1, 1.0, 2.9):
        c.drv.pulse_us(0, s.pulse(q))
        assert abs(s.angle(c.model.pulse_us(0)) - q) <= per_count / 2 / s.us_per_rad + 1e-12


# ---------------------------------------------------------------- the plant

P = ServoParams()
K = 4.712 / 2000                       # rad per us of the 270-degree servo
DB = P.deadband_us * K                 # dead band, rad


def _step(q, target, dt=0.001, driven=True, stalled=None):
    n = len(q)
    return step(np.array(q, float), np.array(target, float), np.full(n, driven), dt, np.full(n, P.tau),
                np.full(n, P.w_max), np.full(n, DB), np.full(n, -10.0), np.full(n, 10.0), stalled)


def test_step_is_pure_and_rate_limited():
    q, t = np.array([0.0]), np.array([2.0])
    out = step(q, t, np.array([True]), 0.001, np.array([P.tau]), np.array([P.w_max]), np.array([DB]),
               np.array([-1.0]), np.array([3.0]))
    assert q[0] == 0.0 and t[0] == 2.0
    assert out[0] == pytest.approx(P.w_max * 0.001)                       # a big error: top speed


def test_step_first_order_lag_then_dead_band():
    q, e0 = [0.0], 0.1                                                    # 0.1 rad: 0.1/tau = 2.5 rad/s < w_max
    for k in range(1, 41):
        q = _step(q, [e0])
        assert e0 - q[0] == pytest.approx(e0 * math.exp(-k * 0.001 / P.tau), rel=1e-9)
    for _ in range(2000):
        q = _step(q, [e0])
    assert e0 - DB - 1e-3 * DB < q[0] < e0 - DB * (1 - 0.03)              # parks at the dead band's edge
    assert _step([0.0], [0.9 * DB])[0] == 0.0                             # inside it: no move


def test_limp_stalled_and_hard_stops():
    assert _step([0.3], [2.0], driven=False)[0] == 0.3
    assert _step([0.3], [2.0], stalled=np.array([True]))[0] == 0.3
    pl = PositionalPlant([0.0], [1.0], [(500, -0.5, 2500, 4.2)])
    pl.set_pulses([2500.0], 0.0)
    pl.advance(2.0)
    assert pl.q[0] == pytest.approx(1.0 + P.stop_margin)                  # the arm's stop, before the servo's end
    pl.set_pulses([np.nan], pl.t)                                         # full off
    pl.advance(0.5)
    assert pl.q[0] == pytest.approx(1.05) and not pl.driven.any()
    pl.set_pulses([3000.0], pl.t)                                         # not a servo signal: limp
    assert not pl.driven.any()


def test_pulses_act_from_their_frame_and_the_pen_crosses_over():
    pl = PositionalPlant([0.0], [3.0], [(500, -0.785, 2500, 3.927)],
                         pen=PenServo(up_us=1200, down_us=1700))
    pl.set_pulses([1500.0, 1700.0], 0.010)                                # from the next PWM period
    pl.advance(0.010)
    assert pl.q[0] == 1.5 and pl.pen_down is False
    pl.advance(0.2)
    assert pl.pen_down is True and len(pl.pen_changes) == 1
    t_down = pl.pen_changes[0][0]
    travel = (1700 - 1200) / 2000 * math.pi / 2                           # half the up->down travel, rad
    assert 0.010 + travel / PEN_PARAMS.w_max < t_down < 0.010 + 0.150    # within PEN_SETTLE_MS
    assert pl.q[0] == pytest.approx(1.571, abs=DB + 1e-3)


def test_measurement_noise_and_adc_quantum():
    pl = PositionalPlant([0.0, -3.142], [3.142, 0.0], [(500, -0.785, 2500, 3.927)] * 2, seed=3)
    m = np.array([pl.measure() for _ in range(200)])
    codes = (m - pl.lo_stop) / pl.quantum
    assert np.allclose(codes, np.rint(codes))
    assert np.abs(m - pl.q).max() < 5 * P.sigma + pl.quantum.max()


# ---------------------------------------------------------------- the rig end to end

@pytest.fixture
def rig():
    e = EmulatedBoard(rig_spec(board_spec("esp32"), "pca9685"), speed=0)
    yield e
    e.stop()


def _tolerance(emu) -> np.ndarray:
    """How far a settled joint may sit from its set point: half a PCA9685 count
    (pulse rounding) plus the servo's dead band, both through its pulse->angle map."""
    k = np.array([abs((m[3] - m[1]) / (m[2] - m[0])) for m in emu.plant.mappings])
    count_us = emu.hal.pca.period_s * 1e6 / 4096
    return k * (count_us / 2 + emu.plant.p.deadband_us) + 1e-9


def test_a_w_plan_on_the_pca_rig_reaches_its_targets(rig):
    h = Lockstep(rig)
    assert h.wait("BOOT")[2][3] == "IDLE"
    assert rig.hal.POSITIONAL and rig.interpreter == "cpython"
    h.hello(11)
    q0 = rig.positions().copy()
    targets = [(2000, -1000, 500), (1000, -2000, -500), (1571, -1100, 300)]
    for i, q in enumerate(targets):
        assert h.request("W", 10 + i, 400, *q)[1] == "OK"
    h.wait("EV", done_ev(12))
    rig.run_for(0.5)
    err = rig.positions() - np.array(targets[-1]) / 1000
    tol = _tolerance(rig)
    assert np.all(np.abs(err) <= tol), (err, tol)                         # about 12.8 mrad
    assert np.abs(rig.positions() - q0).max() > 0.4                      # it did move
    assert [i for _, i, _ in rig.executed] == [10, 11, 12]
    assert len(rig.hal.efforts) == 0 and len(rig.hal.positions) > 100     # set points, never efforts
    assert rig.hal.pca.restart_early == 0 and rig.hal.pca.prescale_blocked == 0
    # e-stop: every channel full off, the servos limp where they are
    rig.inject(bytes([0x98]))
    rig.step(2)
    assert rig.state == "ESTOP" and rig.hal.outputs_off_at
    assert all(rig.hal.pca.pulse_us(ch) is None for ch in range(16)) and not rig.plant.driven.any()
    here = rig.positions().copy()
    rig.run_for(0.5)
    assert np.array_equal(rig.positions(), here)


def test_cal_moves_the_joint_by_the_calibration_change(rig):
    h = Lockstep(rig)
    h.hello(12)
    assert h.request("W", 1, 300, 1571, -1571, 0)[1] == "OK"
    h.wait("EV", done_ev(1))
    rig.run_for(0.4)
    before = rig.positions().copy()
    assert h.request("CAL", 1, 500, -685, 2500, 4027)[1] == "OK"        # the board now thinks 500 us is -685
    rig.run_for(0.6)
    moved = rig.positions() - before
    assert moved[0] == pytest.approx(-0.100, abs=2 * _tolerance(rig)[0])
    assert np.abs(moved[1:]).max() <= 2 * _tolerance(rig)[1:].max()
    assert rig.hal.calibrations[-1][1:] == (0, 500, -685, 2500, 4027)


def test_pen_on_the_pca_rig_moves_the_pen_servo_channel(rig):
    h = Lockstep(rig)
    h.hello(13)
    assert rig.hal.has_pen and rig.plant.pen_down is False
    assert h.request("PEN", 1)[1] == "OK"
    h.wait("EV", lambda a: a[1] == "PEN")
    t_cmd = rig.hal.pen_log[-1][0]
    t_down = rig.hal.pen_changes[-1][0]
    assert rig.hal.pen_changes[-1][1] is True and t_cmd < t_down < t_cmd + rig.cfg.PEN_SETTLE_MS / 1000
    assert rig.hal.pen_down_at(t_down + 1e-3) and not rig.hal.pen_down_at(t_cmd)
    assert rig.hal.pca.pulse_us(rig.cfg.PEN_CHANNEL) == pytest.approx(rig.cfg.PEN_DOWN_US, abs=2.5)


def test_the_rig_is_named_by_url_and_cli_and_bad_rigs_are_one_error():
    from armbridge.emulator.url import parse_emu_url
    import typer
    from typer.testing import CliRunner
    from armbridge.emulator.command import emulate_cmd

    spec, kw = parse_emu_url("emu:esp32?servos=pca9685&speed=0")
    assert spec.rig == "pca9685" and kw == {"speed": 0.0}
    assert parse_emu_url("emu:esp32?servos=effort") == ("esp32", {})
    with pytest.raises(ArmbridgeError, match="servos.*'bogus'.*effort, pca9685"):
        parse_emu_url("emu:esp32?servos=bogus")
    spec, kw = parse_emu_url("emu:esp32?servos=pca9685&interpreter=micropython")
    assert spec.rig == "pca9685" and kw == {"interpreter": "micropython"}
    assert spec.interpreters == ("cpython", "micropython")   # the bridge carries its I2C bus
    app = typer.Typer()
    app.command()(emulate_cmd)
    for args, words in ((["esp32", "--servos", "bogus"], ["'bogus'", "effort, pca9685"]),
                        (["esp32", "--servos", "pca9685", "--interpreter", "simavr"], ["simavr", "cpython, micropython"])):
        result = CliRunner().invoke(app, args)
        assert isinstance(result.exception, ArmbridgeError), result.output
        assert "\n" not in str(result.exception)
        for w in words:
            assert w in str(result.exception)


# ---------------------------------------------------------------- under the real MicroPython

SCENARIO = '''
def scenario(config, pca9685, servos):
    class Bus:                      # records every transfer; reads return what was written
        def __init__(self):
            self.regs = bytearray(256)
            self.log = []

        def writeto_mem(self, addr, reg, buf):
            self.log.append([addr, reg, list(buf)])
            for i in range(len(buf)):
                self.regs[(reg + i) & 0xFF] = buf[i]

        def readfrom_mem(self, addr, reg, n):
            return bytes(self.regs[reg:reg + n])

    bus = Bus()
    waits = []
    pca = pca9685.Pca9685(bus, config.PCA9685_ADDR, config.SERVO_FREQ_HZ, sleep_us=waits.append)
    bank = servos.ServoBank(pca, config)
    for k in range(60):
        bank.write([0.05 + 0.051 * k, -3.1 + 0.05 * k, -1.55 + 0.052 * k])
    bank.pen(True)
    bank.set_calibration(0, 600, 0, 2400, 3000)
    bank.write([1.0, -1.0, 0.0])
    bank.off()
    bank.write([1.0, -1.0, 0.0])
    return {"log": bus.log, "waits": waits, "prescale": pca.prescale}
'''


def test_driver_and_servo_bank_write_the_same_bytes_under_micropython():
    """The firmware's pca9685.py and servos.py under the MicroPython WebAssembly
    interpreter (32-bit floats there, as on the chip) send the same transfers as
    under CPython, which the register tests above check against the chip."""
    import json
    import shutil
    import subprocess
    from pathlib import Path

    from require import missing

    root = Path(__file__).resolve().parents[1]
    pkg = root / "node_modules" / "@micropython" / "micropython-webassembly-pyscript" / "micropython.mjs"
    node = shutil.which("node")
    if node is None or not pkg.is_file():
        missing("node and the npm package @micropython/micropython-webassembly-pyscript (make setup)")
    ns: dict = {}
    exec(SCENARIO, ns)
    fw = load_firmware([firmware_dir() / "esp32"], ("config", "pca9685", "servos"))
    want = json.loads(json.dumps(ns["scenario"](fw["config"], fw["pca9685"], fw["servos"])))
    script = (SCENARIO + "\nimport json, config, pca9685, servos\n"
              "with open('/io/out.json', 'w') as f:\n    json.dump(scenario(config, pca9685, servos), f)\n")
    proc = subprocess.run([node, str(root / "tests" / "mpy" / "run_script.mjs"), str(root)], input=script,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout)
    assert got["prescale"] == want["prescale"] == 121 and got["waits"] == want["waits"] == [500]
    assert len(want["log"]) > 60
    assert got["log"] == want["log"]


def test_the_rig_runs_at_the_configs_pwm_frequency(tmp_path):
    """SERVO_FREQ_HZ (docs/drawing.md "Calibration"): at 200 Hz the chip's prescale, frame and
    count (1.22 us) follow, the servos see the pulses every 5 ms frame, and a joint settles
    within half the finer count plus its dead band."""
    import shutil

    root = tmp_path / "fw"
    shutil.copytree(firmware_dir(), root)
    cfg = root / "esp32" / "config.py"
    text = cfg.read_text()
    assert "\nSERVO_FREQ_HZ = 50\n" in text
    cfg.write_text(text.replace("\nSERVO_FREQ_HZ = 50\n", "\nSERVO_FREQ_HZ = 200\n"))
    e = EmulatedBoard(rig_spec(board_spec("esp32"), "pca9685"), speed=0, firmware_root=root)
    try:
        assert e.cfg.SERVO_FREQ_HZ == 200
        assert e.hal.pca.prescale == 30 and e.hal.pca.period_s == pytest.approx(31 * 4096 / 25e6)
        assert e.hal.pca.next_frame(e.now() + 1e-4) - e.now() <= e.hal.pca.period_s + 1e-9
        h = Lockstep(e)
        h.hello(13)
        target = (1900, -1300, 400)
        assert h.request("W", 1, 400, *target)[1] == "OK"
        h.wait("EV", done_ev(1))
        e.run_for(0.5)
        tol = _tolerance(e)
        assert tol.max() < 0.009                     # 0.61 us + 3 us against 2.44 + 3 at 50 Hz
        assert np.all(np.abs(e.positions() - np.array(target) / 1000) <= tol)
        count_us = e.hal.pca.period_s * 1e6 / 4096
        for ch, j in zip(e.cfg.SERVO_CHANNELS, range(3)):
            want = e.hal.servos.servos[j].pulse(target[j] / 1000)
            assert abs(e.hal.pca.pulse_us(ch) - want) <= count_us / 2 + 1e-9
    finally:
        e.stop()


def test_the_servos_lead_runs_ahead_along_the_velocity_within_the_limits(rig):
    """SERVO_LEAD_MS: the positional set point is sent that far ahead along the set point's
    velocity (the servos' own lag), never past the joint's limits in force."""
    b = rig.board
    lead = rig.cfg.SERVO_LEAD_MS / 1000.0
    assert lead > 0
    b.traj.vel = [1000.0, -2000.0, 0.0]
    out = b._led([1571.0, -1571.0, 0.0])
    assert out == pytest.approx([1.571 + lead * 1.0, -1.571 - lead * 2.0, 0.0])
    b.traj.vel = [3000.0, 3000.0, 3000.0]
    out = b._led([3130.0, -10.0, 1560.0])
    assert out == pytest.approx([3.142, 0.0, 1.571])


def test_a_calibrated_servo_is_led_along_its_velocity_only_beyond_half_its_dband(rig):
    """With DBAND w (the servo's hysteresis, which servos.py leads its pulse by half of), the
    velocity lead is SERVO_LEAD_MS * v less w / 2 toward zero (none while that is less): the
    servo lags by its dead band or its loop's lag, not by both."""
    b = rig.board
    lead = rig.cfg.SERVO_LEAD_MS / 1000.0
    b.cal.set_lead(0, 20)
    b.cal.set_lead(1, 20)
    b.cal.set_lead(2, 20)
    try:
        b.traj.vel = [1000.0, -100.0, 0.0]       # mrad/s: 40 mrad ahead less 10; 4 mrad, within 10
        out = b._led([1571.0, -1571.0, 0.0])
        assert out == pytest.approx([1.571 + lead * 1.0 - 0.010, -1.571, 0.0])
        b.traj.vel = [-1000.0, 0.0, 0.0]
        assert b._led([1571.0, -1571.0, 0.0])[0] == pytest.approx(1.571 - lead * 1.0 + 0.010)
    finally:
        for j in range(3):
            b.cal.set_lead(j, 0)


def test_the_servos_lead_their_pulse_toward_the_side_they_move_to():
    """servos.Servo.led (DBAND on this rig): half the hysteresis width, on the side the pulse last
    moved to by more than SIDE_US; none before it has moved, none with lead 0; clipped to the range."""
    s = servos_mod.Servo(1000, 0, 2000, 1000)
    assert s.led(1500.0) == 1500.0                     # no lead set: the pulse as it is
    s.lead_us = 4.0
    assert s.led(1500.0) == 1500.0                     # not moved yet: no side
    assert s.led(1510.0) == 1514.0                     # moving up: led up
    assert s.led(1510.3) == 1514.3                     # within SIDE_US: the side stays
    assert s.led(1505.0) == 1501.0                     # moving down: led down
    assert s.led(1505.2) == 1501.2
    s.lead_us = 10.0
    assert s.led(2498.0) == 2500.0 and s.led(502.0) == 500.0   # within the servo's range
