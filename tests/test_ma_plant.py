"""The MASR actuator's plant (emulator/ma_plant.py): its pure step functions
and MaPlant, seeded and deterministic."""
from __future__ import annotations

import math
import types

import numpy as np
import pytest

from armbridge.emulator import plant as servo
from armbridge.emulator.ma_plant import (MaParams, MaPlant, backlash, counts, drive_step, engaged, ground_step,
                                         hall_step, ma_plant, slip_step)
from armbridge.errors import ArmbridgeError
from armbridge.robots import get_robot

P = MaParams()
ARM = get_robot("masr5")
R = tuple(float(x) for x in ARM.r)          # 0, 0.2, 0.4, 0.6, 0.7 m
W = 0.002                                    # hall window used below (m)
H = P.hall_hyst_mm / 1000.0

CFG = types.SimpleNamespace(
    FW_NAME="masr_ma", LINK_LENGTHS_MM=(200, 200, 200, 100, 100), LIMITS=((-873, 873),) * 5 + ((0, 800),),
    VMAX=(280,) * 5 + (100,), WHEEL_MM_PER_COUNT=0.1, GEAR_MRAD_PER_COUNT=0.5, HALL_WINDOW_MM=2.0,
    BACKLASH_MRAD=6.0)


def plant(seed: int = 0, q0=None, params: MaParams | None = None) -> MaPlant:
    return ma_plant(CFG, params, q0, seed)


def q0_at(d: float) -> np.ndarray:
    return np.r_[np.zeros(5), d]


# ---------------------------------------------------------------- drives

def test_drive_step_is_the_servo_plants_model():
    rng = np.random.default_rng(4)
    for _ in range(200):
        x, v, u = rng.normal(), rng.normal() * 0.2, rng.uniform(-1.5, 1.5)
        dt = rng.uniform(1e-4, 2e-3)
        stalled = bool(rng.random() < 0.2)
        pp = servo.PlantParams(v_servo=P.v_full, tau=P.tau, a_max=P.a_max)
        qs, vs = servo.step(np.array([x]), np.array([v]), np.array([u]), dt, pp, np.array([-np.inf]),
                            np.array([np.inf]), np.array([stalled]))
        xm, vm = drive_step(x, v, u, dt, P.v_full, P.tau, P.a_max, stalled)
        assert xm == pytest.approx(float(qs[0]), abs=1e-15) and vm == pytest.approx(float(vs[0]), abs=1e-15)


def test_full_effort_reaches_v_full_within_the_acceleration_limit():
    s, v, dt = 0.0, 0.0, 0.001
    vs = []
    for _ in range(1000):
        s, v = drive_step(s, v, 1.0, dt, P.v_full, P.tau, P.a_max)
        vs.append(v)
    assert vs[-1] == pytest.approx(P.v_full, rel=1e-6)
    assert np.max(np.diff(np.r_[0.0, vs])) <= P.a_max * dt + 1e-15
    assert 0.1 < P.v_full < 0.15   # a bit above the firmware's 100 mm/s


# ---------------------------------------------------------------- slip

def test_slip_stays_within_its_bound_with_the_stated_statistics():
    rng = np.random.default_rng(11)
    dt, k = 0.001, 200_000
    x = np.empty(k)
    s = 0.0
    for i in range(k):
        s = slip_step(s, float(rng.standard_normal()), dt, P)
        x[i] = s
    assert np.all(np.abs(x) <= P.slip_bound)
    assert abs(x.mean()) < 0.001
    assert 0.6 * P.slip_sigma < x.std() <= P.slip_sigma * 1.05       # clipping only narrows it
    lag = int(P.slip_tau / dt)
    rho = np.corrcoef(x[:-lag], x[lag:])[0, 1]
    assert rho == pytest.approx(math.exp(-1.0), abs=0.12)          # correlation time slip_tau


def test_ground_truth_advances_by_the_wheel_travel_times_one_plus_slip():
    p = plant(seed=3)
    p.set_loco(1.0)
    for _ in range(50):
        s0, d0 = p.s, p.d
        p.advance(0.1)
        ratio = (p.d - d0) / (p.s - s0)
        assert 1 - P.slip_bound - 1e-12 <= ratio <= 1 + P.slip_bound + 1e-12
        if p.d > 0.79:
            break
    assert abs(p.d - p.s) <= P.slip_bound * p.s


def test_slip_burst_takes_the_fraction_of_the_travel():
    p = plant(seed=1)
    p.burst(0.5, 0.3, 0.4)
    p.set_loco(1.0)
    p.advance_to(0.5)
    s0, d0 = p.s, p.d
    p.advance_to(0.8)
    assert (p.d - d0) == pytest.approx(0.6 * (p.s - s0), rel=1e-9)
    p.advance(0.01)
    assert [(k, v) for _, k, v in p.faults_applied] == [("slip", 0.4), ("slip", 0.0)]


def test_ground_step_stops_at_the_hard_ends():
    assert ground_step(0.001, -0.005, 0.0, 0.8) == (0.0, pytest.approx(-0.001), True)
    d, ds, end = ground_step(0.799, 0.004, 0.0, 0.8)
    assert (d, end) == (0.8, True) and ds == pytest.approx(0.001)


def test_hard_ends_stop_the_ma_and_its_wheel():
    p = plant(q0=q0_at(0.03))
    p.set_loco(-1.0)
    p.advance(1.0)
    assert p.d == 0.0 and p.v == 0.0
    c = p.wheel_count()
    p.advance(0.5)
    assert p.wheel_count() == c and p.d == 0.0
    p = plant(q0=q0_at(0.78))
    p.set_loco(1.0)
    p.advance(1.0)
    assert p.d == pytest.approx(0.8) and p.v == 0.0


# ---------------------------------------------------------------- encoders

def test_encoder_quantum():
    q = 0.0001
    assert counts([0.0, 0.99e-4, 1e-4, 2.5e-4, -0.5e-4], q).tolist() == [0, 0, 1, 2, -1]
    p = plant(seed=2)
    p.set_loco(0.5)
    for _ in range(100):
        p.advance(0.003)
        assert p.wheel_count() == math.floor(p.s / q + 1e-9)
    assert p.wheel_count() > 0


# ---------------------------------------------------------------- hall sensor

def sweep(ds, d0, d1, present=(True,) * 5):
    level, _ = hall_step(False, d0, R, W, H, present)
    ups, downs = [], []
    for d in np.arange(d0, d1, ds):
        new, k = hall_step(level, float(d), R, W, H, present)
        if k >= 0:
            ups.append((k, float(d)))
        if level and not new:
            downs.append(float(d))
        level = new
    return ups, downs


def test_hall_fires_within_its_window_with_hysteresis():
    ds = 1e-5
    ups, downs = sweep(ds, 0.1, 0.45)
    assert [k for k, _ in ups] == [1, 2]
    assert ups[0][1] == pytest.approx(R[1] - W, abs=ds)            # forward: the window's near edge
    assert downs[0] == pytest.approx(R[1] + W + H, abs=ds)         # off only past the hysteresis
    ups, downs = sweep(-ds, 0.45, 0.1)
    assert [k for k, _ in ups] == [2, 1]
    assert ups[0][1] == pytest.approx(R[2] + W, abs=ds)            # backward: the far edge
    assert downs[0] == pytest.approx(R[2] - W - H, abs=ds)
    # inside the hysteresis band the level keeps what it was
    band = R[1] + W + 0.5 * H
    assert hall_step(True, band, R, W, H, (True,) * 5) == (True, -1)
    assert hall_step(False, band, R, W, H, (True,) * 5) == (False, -1)


def test_a_missed_magnet_never_fires():
    ups, _ = sweep(1e-5, 0.1, 0.65, present=(True, True, False, True, True))
    assert [k for k, _ in ups] == [1, 3]


def test_the_plant_latches_the_wheel_count_at_each_rising_edge():
    p = plant(seed=5)
    assert p.level   # at the base, on joint 1's magnet
    p.miss(3)
    p.set_loco(1.0)
    p.advance(7.0)
    joints = [j for _, j, _, _ in p.edges]
    assert joints == [2, 4, 5]
    for _, j, c, d in p.edges:
        assert R[j - 1] - W <= d <= R[j - 1] - W + P.v_full * P.max_dt * (1 + P.slip_bound)
    assert p.pop_edges() == [c for _, _, c, _ in p.edges]
    assert p.pop_edges() == []


# ---------------------------------------------------------------- worm, backlash, engagement

def test_backlash_takes_up_the_play_before_the_joint_turns():
    half = 0.003
    th, g = 0.0, 0.0
    th, g, ref = backlash(th, g, 0.002, half, -1, 1, False)
    assert (th, g, ref) == (0.0, 0.002, 0.0)          # inside the play: the joint holds
    th, g, ref = backlash(th, g, 0.004, half, -1, 1, False)
    assert th == pytest.approx(0.003) and g == half    # past it: 1:1
    th, g, ref = backlash(th, g, -0.005, half, -1, 1, False)
    assert th == pytest.approx(0.003) and g == pytest.approx(-0.002)   # reversal: the play first
    th, g, ref = backlash(th, g, -0.003, half, -1, 1, False)
    assert th == pytest.approx(0.001) and g == -half
    # seized or at its stop: the joint refuses what goes past the play
    assert backlash(0.0, half, 0.01, half, -1, 1, True) == (0.0, half, pytest.approx(0.01))
    th, g, ref = backlash(0.995, half, 0.01, half, -1, 1.0, False)
    assert th == 1.0 and ref == pytest.approx(0.005)


def test_engagement_only_on_the_joint():
    tol = P.engage_mm / 1000.0
    assert engaged(0.4, R, tol) == 2
    assert engaged(0.4 + tol - 1e-9, R, tol) == 2
    assert engaged(0.4 + tol + 1e-6, R, tol) == -1
    assert engaged(0.5, R, tol) == -1


def test_the_worm_turns_only_the_joint_the_ma_stands_on():
    p = plant(seed=7, q0=q0_at(0.4 + 0.010))        # 10 mm past joint 3: not engaged
    p.set_rot(1.0)
    p.advance(1.0)
    assert p.gear_count() > 500 and np.all(p.q[:5] == 0.0)
    p = plant(seed=7, q0=q0_at(0.4 + 0.001))
    g0 = p.gap[2]
    p.set_rot(1.0)
    p.advance(1.0)
    turned = p.w - (p.half - g0)                    # the worm's travel less the play it took up
    assert p.q[2] == pytest.approx(turned, abs=1e-12)
    assert np.count_nonzero(p.q[:5]) == 1
    p.off()
    p.advance(0.3)                                  # the drive coasts down through its lag ...
    th = p.q[2]
    p.advance(2.0)                                  # ... then the worm holds the joint
    assert p.q[2] == th and p.om == 0.0
    assert abs(p.gear_count() - math.floor(p.w / 0.0005 + 1e-9)) == 0


def test_the_current_sense_reads_the_load_only_while_the_worm_drives_the_gear():
    """rot_load: about 0 while the worm turns in its play or off a joint, mesh_load plus the
    joint's friction (capped at the effort) once it drives the gear; the noise a function
    of the seed and the time alone (a reading does not change the next)."""
    params = MaParams(backlash_mrad=20.0, mesh_load=0.03, joint_friction=0.02, sense_noise=0.002)
    p = plant(seed=3, q0=q0_at(0.4 + 0.001), params=params)
    p.gap[2] = -p.halves[2]                          # the far end of the play from +
    p.set_rot(0.5)
    seen = []
    while p.q[2] == 0.0:
        p.advance(0.001)
        seen.append(p.rot_load())
    assert len(seen) > 20 and max(abs(x) for x in seen[:-2]) < 0.01    # crossing 20 mrad: nothing driven
    p.advance(0.05)
    loads = [p.rot_load() for _ in range(3)]
    assert loads[0] == loads[1] == loads[2]          # one instant, one reading
    assert abs(loads[0] - 0.05) < 0.01               # mesh 0.03 + friction 0.02
    p.set_rot(0.02)                                  # an effort below the load: the worm stalls on it
    p.advance(0.2)
    assert abs(p.rot_load() - 0.02) < 0.01
    p.set_rot(-0.5)                                  # back: into the play again
    p.advance(0.01)
    assert abs(p.rot_load()) < 0.01
    off = plant(seed=3, q0=q0_at(0.4 + 0.010), params=params)          # off the joint
    off.set_rot(1.0)
    off.advance(0.3)
    assert abs(off.rot_load()) < 0.01
    again = plant(seed=3, q0=q0_at(0.4 + 0.001), params=params)
    again.advance(0.123)
    p2 = plant(seed=3, q0=q0_at(0.4 + 0.001), params=params)
    p2.advance(0.123)
    p2.rot_load()
    assert again.rot_load() == p2.rot_load()


def test_a_seized_joint_stops_the_worm_once_the_play_is_taken_up():
    p = plant(seed=8, q0=q0_at(0.2))
    p.stall(1, 0.0)                                 # joint 2 seized
    p.set_rot(1.0)
    p.advance(0.5)
    assert p.q[1] == 0.0 and p.om == 0.0
    c = p.gear_count()
    p.advance(0.5)
    assert p.gear_count() == c
    assert [(k, v) for _, k, v in p.faults_applied] == [("stall", 2)]


def test_a_stalled_wheel_keeps_the_ma_where_it_is():
    p = plant(q0=q0_at(0.3))
    p.stall(5, 0.2)
    p.set_loco(1.0)
    p.advance(0.2)
    d = p.d
    p.advance(1.0)
    assert p.d == d and p.v == 0.0
    with pytest.raises(ArmbridgeError, match="coordinates 1..6"):
        p.stall(6, 0.0)


def test_joint_hard_stops():
    p = plant(q0=np.r_[0.0, 0.0, 0.0, 0.87, 0.0, 0.6])
    p.set_rot(1.0)
    p.advance(2.0)
    assert p.q[3] == pytest.approx(0.873 + P.stop_margin) and p.om == 0.0


# ---------------------------------------------------------------- the rest

def test_gripper_travels():
    p = plant()
    p.set_grip(True)
    p.advance(P.grip_s / 2)
    assert p.grip_pos == pytest.approx(0.5, abs=0.01)
    p.advance(P.grip_s)
    assert p.grip_pos == 1.0
    p.off()
    assert p.grip_open


def test_pose_is_the_arms():
    q0 = np.r_[0.3, -0.2, 0.1, 0.0, 0.4, 0.5]
    p = plant(q0=q0)
    np.testing.assert_allclose(p.points(), ARM.joint_points(q0))
    np.testing.assert_allclose(p.ma_point(), ARM.ma_point(q0))


def test_seeded_and_deterministic():
    def run(seed):
        p = plant(seed=seed)
        p.set_loco(1.0)
        p.set_rot(0.5)
        p.advance(2.5)
        return p.q.tolist(), p.wheel_count(), p.edges, p.gap

    assert run(3) == run(3)
    assert run(3) != run(4)


def test_factory_reads_the_firmware_config():
    p = plant()
    assert p.n == 6 and p.length == pytest.approx(0.8) and p.window == pytest.approx(0.002)
    assert p.half == pytest.approx(0.003) and p.wheel_q == pytest.approx(1e-4)
    bad = types.SimpleNamespace(**{k: v for k, v in vars(CFG).items() if k != "HALL_WINDOW_MM"})
    with pytest.raises(ArmbridgeError, match="lacks HALL_WINDOW_MM"):
        ma_plant(bad, None, None, 0)
    with pytest.raises(ArmbridgeError, match="takes MaParams"):
        ma_plant(CFG, servo.PlantParams(), None, 0)  # type: ignore[arg-type]
    with pytest.raises(ArmbridgeError, match="6 values"):
        ma_plant(CFG, None, (0.0, 0.0), 0)
    with pytest.raises(ArmbridgeError, match="joints 1..5"):
        p.miss(6)
