"""The syringe-pump plant's hidden truth (`plant=random`, emulator/truth.py; pump_plant.PumpTruth,
SPREADS, hidden_truth): drawn per joint, repeatable by seed, inside its bounds, neutral when nominal,
and acting on the plant (the pure step function and the sensor); and a random rig runs a short plan
on the pump board's real .elf in simavr, through the executor.
"""
from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest

from armbridge.boards.pump_rig import PumpParams
from armbridge.emulator import pump_plant as PP
from armbridge.emulator.pump_plant import SPREADS, PumpPlant, PumpTruth, hidden_truth, pressure, sensor_mv, step
from armbridge.emulator.truth import table, truth_rng

BEND = [(205, 0, 716, 1047)] * 3
RANGE = np.deg2rad([30.0, 55.0, 60.0])


class Cfg:
    """The pump firmware's constants hidden_truth reads (config.h)."""

    N_JOINTS = 3
    SYRINGE_STROKE_MS = 5000
    DUTY_MIN = 120


def drawn(seed: int) -> PumpTruth:
    return hidden_truth(Cfg, truth_rng(seed))


def test_the_same_seed_draws_the_same_rig_and_seeds_differ():
    assert drawn(7) == drawn(7)
    a, b = drawn(1), drawn(2)
    assert a != b
    for s in SPREADS:
        if s.field != "leak_ml_s" and s.field != "quant_mv":   # clipped at 0: both may be 0
            assert getattr(a, s.field) != getattr(b, s.field), s.field
    # the rig's nominal numbers (what the planner reads) are not drawn
    assert a.rig == b.rig == PumpParams()


def test_every_draw_is_per_joint_inside_its_bounds_and_physical():
    for seed in range(300):
        t = drawn(seed)
        for s in SPREADS:
            v = getattr(t, s.field)
            assert isinstance(v, tuple) and len(v) == 3, (seed, s.field, v)
            assert all(s.lo <= x <= s.hi for x in v), (seed, s.field, v)
        # a joint that straightens below where it opens, and fills before the syringe is empty
        assert all(h < o < f for h, o, f in zip(t.p_hold_kpa, t.p_open_kpa, t.p_full_kpa)), seed
        # the firmware's smallest drive (DUTY_MIN) always moves the motor
        assert max(t.dead_duty) < Cfg.DUTY_MIN / 1000.0, seed
    leaks = np.array([drawn(s).leak_ml_s for s in range(300)]).ravel()
    assert 0.3 < np.mean(leaks == 0.0) < 0.7                  # about half the joints hold tight


def test_every_spread_says_why_and_the_docs_table_has_a_row_each():
    assert all(s.source for s in SPREADS) and all(s.per_joint for s in SPREADS)
    rows = table(SPREADS)
    assert len(rows) == len(SPREADS) and all(r.startswith("| `") for r in rows)
    doc = (Path(__file__).resolve().parents[1] / "docs" / "emulator.md").read_text()
    for r in rows:
        assert r in doc, r


def test_the_nominal_truth_is_the_rig_and_changes_nothing():
    n = PumpTruth.nominal(PumpParams(), 3)
    assert n.leak_ml_s == (0.0,) * 3 and n.gain == (1.0,) * 3 and n.p_open_kpa == (12.0,) * 3
    assert n.switch_mm == PumpParams().switch_mm                    # the rig's scalars read through
    a, b = PumpPlant(RANGE, BEND, PumpParams(), seed=4), PumpPlant(RANGE, BEND, n, seed=4)
    duties = np.random.default_rng(0).uniform(-1, 1, (200, 3))
    for u in duties:
        a.drive(u)
        b.drive(u)
        a.advance_to(a.t + 0.02)
        b.advance_to(b.t + 0.02)
        assert np.array_equal(a.x, b.x) and np.array_equal(a.q, b.q)
        assert np.array_equal(a.sensor_mv(), b.sensor_mv()) and np.array_equal(a.pressure(), b.pressure())
    assert np.array_equal(a.air, np.full(3, PumpParams().v_rest_ml))


def test_the_boards_nominal_plant_is_neutral_and_random_is_hidden_truth():
    from armbridge.emulator.pump_hal import pump_plant
    from armbridge.emulator.registry import board_spec
    from armbridge.emulator.simboard import firmware_config
    from armbridge.resources import firmware_dir

    cfg = firmware_config(board_spec("arduino_pump"), firmware_dir())
    plant = pump_plant(cfg, None, None, 0)
    assert plant.p == PumpTruth.nominal(PumpParams(), 3)
    truth = hidden_truth(cfg, truth_rng(5))
    assert pump_plant(cfg, truth, None, 0).p is truth


def held(t: PumpTruth, seconds: float, u0: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """Pressure and bend after pushing each syringe at u0 for 2 s, then `seconds` closed: the pure
    step function."""
    x, v = np.full(3, 2.0), np.zeros(3)
    th, op, air = np.zeros(3), np.zeros(3, bool), np.full(3, t.v_rest_ml)
    dt = 0.001
    for k in range(int((2.0 + seconds) / dt)):
        u = np.full(3, u0 if k * dt < 2.0 else 0.0)
        x, v, th, op, air = step(x, v, th, op, air, u, dt, t, RANGE)
    return pressure(x, th, t, air), th


def test_a_drawn_leak_lowers_the_pressure_of_a_closed_syringe():
    tight = PumpTruth.nominal(PumpParams(), 3)
    leaky = dataclasses.replace(tight, leak_ml_s=(0.0, 0.15, 0.15))
    p0, th0 = held(tight, 0.5)
    p_tight, th_tight = held(tight, 10.0)
    p_leak, th_leak = held(leaky, 10.0)
    assert np.allclose(p_tight, p0, atol=1e-9) and np.allclose(th_tight, th0, atol=1e-6)   # tight: it holds
    assert p_leak[0] == pytest.approx(p_tight[0])
    assert np.all(p_leak[1:] < p_tight[1:] - 0.5) and np.all(th_leak[1:] < th_tight[1:] - 0.01)


def test_the_drawn_curve_motor_and_sensor_act():
    nom = PumpTruth.nominal(PumpParams(), 3)
    # a stiffer joint (higher p_full) bends less at the same push
    stiff = dataclasses.replace(nom, p_full_kpa=(30.0, 34.0, 26.0))
    _, th_nom = held(nom, 1.0, 0.5)
    _, th = held(stiff, 1.0, 0.5)
    assert th[1] < th_nom[1] - 0.02 and th[2] > th_nom[2] + 0.02 and th[0] == pytest.approx(th_nom[0])
    # a duty the nominal motor moves at, below a drawn dead duty: no motion
    sticky = dataclasses.replace(nom, dead_duty=(0.05, 0.09, 0.05))
    assert list(PP.motor_speed(np.full(3, 0.08), sticky) > 0) == [True, False, True]
    # the sensor reads offset + gain theta through the firmware's line
    off = dataclasses.replace(nom, offset_mrad=(10.0, 0.0, 0.0), gain=(1.0, 1.05, 1.0))
    theta = np.array([0.3, 0.6, 0.3])
    d = sensor_mv(theta, BEND, off) - sensor_mv(theta, BEND, nom)
    per_rad = (716 - 205) / 1.047 * 5000 / 1023
    assert d == pytest.approx([0.010 * per_rad, 0.03 * per_rad, 0.0], abs=0.01)
    # and its output steps by quant_mv
    coarse = dataclasses.replace(nom, quant_mv=(5.0, 0.0, 0.0), sigma_mv=(0.0, 0.0, 0.0))
    plant = PumpPlant(RANGE, BEND, coarse, seed=1)
    plant.q = np.array([0.3, 0.3, 0.3])
    mv = plant.sensor_mv()
    assert mv[0] / 5.0 == pytest.approx(round(mv[0] / 5.0)) and mv[1] == pytest.approx(sensor_mv(plant.q, BEND)[1])


# ---------------------------------------------------------------- a random rig in simavr

def needs_simavr() -> None:
    from require import missing

    if shutil.which("avr-gcc") is None or shutil.which("make") is None:
        missing("avr-gcc/make missing: the AVR toolchain (scripts/setup.sh as root installs it)")
    if not Path("/usr/include/simavr/sim_avr.h").is_file():
        missing("libsimavr-dev missing (scripts/setup.sh as root installs it)")


@pytest.mark.hil
def test_a_random_rig_boots_in_simavr_and_runs_a_plan(tmp_path):
    """One pose reached and held on `emu:arduino_pump?plant=random&seed=3`: the executor's summary,
    the board's own log and the plant's truth (what the drawn sensor error lets the firmware see)."""
    needs_simavr()
    from armbridge.executor.run import run_plan
    from armbridge.plans.format import make_plan
    from armbridge.robots import SOFT3
    from plan_runs import assert_executed_once_with_values, opened_ports

    pose = np.array([0.20, 0.40, 0.45])
    plan = make_plan(SOFT3, np.array([pose, pose]), [1.5, 2.0], {"tool": "armbridge tests", "shape": "random rig"})
    with opened_ports() as opened:
        s = run_plan(plan, "emu:arduino_pump?speed=0&plant=random&seed=3", tmp_path / "r.rrd", progress=False,
                     timeout=90)
        emu = opened[0].emulator
        truth = emu.hal.pump.p
        assert truth == drawn(3) and truth != PumpTruth.nominal(PumpParams(), 3)
        assert s.completed and s.final_state == "IDLE" and s.fw == "arduino_pump", s
        assert_executed_once_with_values(emu, plan)
        t_end, true_q, est_q = emu.hal.track[-1]
        # the board holds what it reads inside its band (+ a count); the joint itself is where the
        # drawn sensor error puts that reading
        gain, off = np.asarray(truth.gain), np.asarray(truth.offset_mrad) / 1000.0
        band = 0.070 + 1.047 / 511
        assert np.all(np.abs(np.asarray(est_q) - pose) <= band + 0.01), est_q
        seen = off + gain * np.asarray(true_q)
        assert np.all(np.abs(seen - np.asarray(est_q)) <= 0.01), (seen, est_q)
        # the firmware's settle (config.h SETTLE_RESEEK_MRAD) holds its reading far inside the band: over
        # the last 0.5 s, within the re-seek band and a count or two of noise
        reseek = emu.cfg.SETTLE_RESEEK_MRAD / 1000.0
        last = np.array([est for t, _, est in emu.hal.track if t >= t_end - 0.5])
        assert len(last) and np.all(np.abs(np.median(last, axis=0) - pose) <= reseek + 0.004), last
