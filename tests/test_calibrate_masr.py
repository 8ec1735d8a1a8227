"""`armbridge calibrate masr_ma` (calibrate/masr.py; firmware/masr_ma/ma_cal.py): the MA
measured from its own sensors on boards of hidden truth (`plant=random`, lockstep),
judged against that truth; the verbs it sets (MAG, WHEEL), persisted (CALID, cal.txt
across a reset), refused when they do not fit; the relay experiment (RELAY).
docs/masr.md, "Calibration".
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from armbridge.calibrate import masr
from armbridge.calibrate.base import procedure
from armbridge.errors import ArmbridgeError
from armbridge.executor.client import BoardClient
from armbridge.link.transport import open_port

SEEDS = range(12)
CAL = {"rounds": 1, "speed": 40}   # the procedure at one round (its default is two): the tests' time
# Tolerances (the truth against what was found). The centres rest on the wheel's scale, which
# rests on the magnets' known spacing (magnets glued within +-1 mm of r_j: SPREADS) and on the
# far end stop (END, within +-0.5 mm of l): weighed together the scale is off by about
# 0.2 mm / 800 mm, plus the slip's mean over one drive (one round here); the half window is
# local (two edges a few mm apart). Seen over these 12 boards: centre 0.44 mm, bias per board
# 0.26 mm, mean 0.16, worst edge 0.50 (the magnets alone: 0.8, 0.6, 0.3 and 0.8 held).
CENTRE_MM = 0.6          # every magnet 2..n-1 (magnet 1: its upper edge, the only one the MA can reach)
HALF_WINDOW_MM = 0.1
SCALE = 0.002            # the wheel's travel per count, relative (with the slip's mean over the drive)
BIAS_MM = 0.2            # localisation right after a magnet's edge: its mean over the edges of a drive, over the boards
BIAS_BOARD_MM = 0.3      # ... on any one board: the 0.3 mm
BIAS_MAX_MM = 0.7        # ... at the worst edge


class Board:
    """The MA's firmware on the emulator (lockstep), a BoardClient on it."""

    def __init__(self, seed: int) -> None:
        self.port = open_port(f"emu:masr_ma?speed=0&plant=random&seed={seed}")
        self.emu = self.port.emulator
        self.client = BoardClient(self.port, None, on_telemetry=self._tel)
        self.samples: list[tuple[float, float, float, int]] = []  # (t, true d, the board's estimate mm, anchor count)
        self.client.connect()

    def _tel(self, t, m) -> None:
        b, pl = self.emu.board, self.emu.plant
        if b is not None and b.loc.known:
            self.samples.append((pl.t, pl.d * 1000.0, b.loc.at(pl.wheel_count()), b.loc.c_a))

    def close(self) -> None:
        self.port.close()

    def calibrate(self, **kw):
        found = masr.calibrate(self.client, self.emu.cfg, frozenset({"magnets", "wheel"}), **kw)
        for verb, args in found.settings:
            self.client.command(verb, *args)
        return found

    def run(self, *actions) -> None:
        with masr._Actions(self.client) as act:
            for verb, *args in actions:
                act.run(verb, *args)

    def bias(self) -> list[float]:
        """Estimate - truth (mm) at the first telemetry sample after every hall edge since
        the samples were cleared, once the board has anchored on it (bench/masr_exec.py's
        "after magnet")."""
        from armbridge.bench.masr_exec import after_edges

        s = np.asarray(self.samples, float)
        return after_edges(s[:, 0], s[:, 2] - s[:, 1], s[:, 3], self.emu.hal.hall_log)


TURNED: dict[int, list[float]] = {}   # seed -> the true joints 4 and 2 less their ROT targets (mrad)
JOINT_MRAD = 2.5         # ROT_TOL 1 mrad + half a period's worm travel at vmax (1.4 mrad): the current sense


@pytest.fixture(scope="module")
def calibrated():
    """Every seed calibrated once (magnets and wheel), then driven over every magnet both ways."""
    out = []
    for seed in SEEDS:
        b = Board(seed)
        try:
            found = b.calibrate(**CAL)
            b.client.set_rate(50)
            b.run(("HOME",))
            b.samples.clear()
            b.run(("MV", 750), ("ROT", 4, 100), ("ROT", 2, 50), ("MV", 0))   # up over 2-5, down onto 4, 2, 1
            TURNED[seed] = [b.emu.plant.theta[3] * 1000.0 - 100.0, b.emu.plant.theta[1] * 1000.0 - 50.0]
            out.append((seed, b.emu.plant, found, b.bias(), b.emu.hal.faults_applied))
        finally:
            b.close()
    return out


def test_the_procedure_is_registered_with_its_steps():
    steps, fn = procedure("masr_ma")
    assert steps == ("magnets", "wheel", "gains") and fn is masr.calibrate


def test_magnets_and_wheel_found_within_tolerance_of_the_truth(calibrated):
    for seed, pl, found, _, _ in calibrated:
        centre = np.asarray(found.values["magnets"]["centre_mm"])
        half = np.asarray(found.values["magnets"]["half_window_mm"])
        true_c = np.asarray(pl.magnets) * 1000.0
        w = pl.window * 1000.0
        assert np.all(np.abs(centre[1:] - true_c[1:]) <= CENTRE_MM), (seed, centre - true_c)
        assert abs(centre[0] + half[0] - (true_c[0] + w)) <= CENTRE_MM, seed     # magnet 1's upper edge
        assert np.all(np.abs(half[1:] - w) <= HALF_WINDOW_MM), (seed, half - w)
        q = found.values["wheel_nm_per_count"] / 1e6
        assert abs(q / (pl.wheel_q * 1000.0) - 1.0) <= SCALE, (seed, q, pl.wheel_q)
        (wheel,) = [a for v, a in found.settings if v == "WHEEL"]
        assert wheel == (int(round(q * 1e6)),)
        assert [a[0] for v, a in found.settings if v == "MAG"] == [1, 2, 3, 4, 5]


def test_after_calibration_the_board_is_where_it_says_at_every_magnet(calibrated):
    means = []
    for seed, _pl, _found, bias, faults in calibrated:
        assert faults == [] and len(bias) >= 9, (seed, len(bias))
        a = np.abs(bias)
        assert a.mean() <= BIAS_BOARD_MM and a.max() <= BIAS_MAX_MM, (seed, np.round(bias, 3))
        means.append(a.mean())
    assert np.mean(means) <= BIAS_MM, means


def test_uncalibrated_the_same_drive_is_off_by_the_window():
    """The same check before calibration: the config's nominal window and r_j (what
    calibration removes) put the anchor a millimetre or more off."""
    b = Board(1)
    try:
        b.client.set_rate(50)
        b.run(("HOME",))
        b.samples.clear()
        b.run(("MV", 750), ("MV", 30))
        assert np.max(np.abs(b.bias())) > 1.0
    finally:
        b.close()


def test_the_calibration_survives_a_reset_and_ident_names_it():
    b = Board(3)
    try:
        b.calibrate(rounds=1)
        text = b.emu.board.cal_text()
        assert b.client.command("IDENT").payload[1] == "0"                 # set, not saved
        b.client.command("CALID", 4242)
        assert b.client.command("IDENT").payload[1] == "4242"
        b.emu.reset()
        assert b.client.command("IDENT").payload[1] == "4242"
        board = b.emu.board
        assert board.cal_text() == text and any(t.startswith("MAG,3,") for t in text)
        wheel = int(next(t for t in text if t.startswith("WHEEL,")).split(",")[1])
        assert board.loc.q == wheel / 1e6 and board.loc.m[2] == int(text[2].split(",")[2]) / 1000.0
        b.run(("HOME",), ("MV", 420))                                       # it runs on the loaded values
    finally:
        b.close()


@pytest.mark.parametrize("verb,args,detail", [
    ("MAG", (6, 700000, 1500), "joint"),        # d has no magnet
    ("MAG", (3, 410000, 1500), "pos"),          # 10 mm off r_3
    ("MAG", (3, 400000, 0), "win"),
    ("MAG", (3, 400000, 5000), "win"),
    ("WHEEL", (60000,), "nm"),                  # 20 % off the config's
    ("RELAY", (3, 100, 2, 4), "joint"),         # the MA is not on joint 3's magnet
])
def test_bad_values_are_refused_and_the_board_keeps_running(verb, args, detail):
    b = Board(0)
    try:
        b.run(("HOME",))
        before = b.emu.board.cal_text()
        ans = b.client.ask(verb, *args)
        assert ans.name == "RANGE" and list(ans.detail) == [detail], ans
        assert b.emu.board.cal_text() == before
        b.run(("MV", 250))
        assert abs(b.emu.plant.d * 1000.0 - 250) < 5.0
    finally:
        b.close()


def test_a_cal_file_that_does_not_fit_leaves_the_defaults():
    b = Board(0)
    try:
        b.client.command("MAG", 2, 200500, 1400)
        b.client.command("CALID", 9)
        hal = b.emu.hal
        hal.write_file("cal.txt", b"ABC1 9 MAG,2,200500,1400 WHEEL,99999999\n")
        b.emu.reset()
        assert b.client.command("IDENT").payload[1] == "0"
        assert b.emu.board.loc.m[1] == 200.0 and b.emu.board.loc.q == b.emu.cfg.WHEEL_MM_PER_COUNT
    finally:
        b.close()


def test_relay_on_the_speed_loop_and_a_joint_reports_a_cycle_and_returns():
    b = Board(4)
    try:
        found = masr.gains_step(b.client, b.emu.cfg)
        relay = found.values["relay"]
        assert set(relay) == {"1", "2", "3", "4", "5", "6"}
        for j, r in relay.items():
            assert r["period_ms"] > 0 and "ku" in r, (j, r)
        assert found.settings == []                                          # reported, the shipped gains kept
        pl = b.emu.plant
        assert max(abs(x) for x in pl.theta) <= 0.02                         # every joint back near 0
        assert abs(pl.d * 1000.0 - 700.0) < 5.0                              # on joint 5's magnet (the last ROT)
        assert b.client.stat()[0] == "IDLE"
    finally:
        b.close()


def test_the_procedure_refuses_a_narrowed_range():
    b = Board(0)
    try:
        b.run(("HOME",))
        b.client.command("SETLIM", 6, 0, 500, 100)
        with pytest.raises(ArmbridgeError, match="range"):
            masr.calibrate(b.client, b.emu.cfg, frozenset({"magnets"}))
    finally:
        b.close()


def test_relay_on_the_speed_loop_brings_the_ma_back_and_is_refused_while_moving():
    b = Board(2)
    try:
        b.run(("HOME",), ("MV", 100))
        with masr._Actions(b.client) as act:
            period, amp = act.relay(6, 200, 3, 6)
            assert period > 0 and amp > 3
            b.client.command("MV", 7, 300)
            b.client.drain(0.3)
            ans = b.client.ask("RELAY", 6, 200, 3, 6)                        # moving: refused, the move goes on
            assert ans.name == "RANGE"
            b.client.drain(10.0, until=lambda: 7 in act.done)
        board, pl = b.emu.board, b.emu.plant
        assert abs(board.loc.d() - 300) <= 0.5 and abs(pl.d * 1000.0 - 300) < 3.0
        assert b.client.stat()[0] == "IDLE"
        b.client.command("RELAY", 6, 200, 3, 4)
        b.client.drain(5.0, until=lambda: board.act is None)
        assert board.act is None and abs(board.loc.d() - 300) <= board.cfg.STOP_TOL_MM       # back where it was
    finally:
        b.close()


def test_the_shared_flow_calibrates_the_ma_and_writes_the_host_file(tmp_path):
    """calibrate/base.py's calibrate_board with this procedure (its defaults): the settings sent,
    CALID, the host file; --only magnets keeps the wheel out."""
    from armbridge.calibrate.base import calibrate_board

    rep = calibrate_board("emu:masr_ma?speed=0&plant=random&seed=5", "masr_ma", only=["magnets"], cal_dir=tmp_path)
    assert [v for v, _ in rep.settings] == ["MAG"] * 5 and rep.id > 0
    assert rep.found.values["magnets"]["pairs"][1:] == [4, 4, 4, 4]      # two rounds, two pairs a magnet each
    assert Path(rep.path).exists() and Path(rep.path).parent == tmp_path


def test_the_scale_weighs_the_far_stop_beside_the_magnets():
    """fit: magnets off their joints tilt the magnets-only scale; the far stop at l pulls it
    back (weighted least squares, MAGNET_SD_MM against END_SD_MM), and without ends the
    scale is the magnets' alone."""
    r = np.array([0.0, 200.0, 400.0, 600.0, 700.0])
    q_true = 0.0501
    offsets = np.array([0.0, 0.6, 0.5, 0.7, 0.6])              # every magnet glued a little up the arm
    m = r + offsets
    edges = []
    for j, mj in enumerate(m, start=1):
        if j == 1:
            edges.append((1, int(round((mj + 1.5) / q_true)), -1))
            continue
        edges += [(j, int(round((mj - 1.5) / q_true)), 1), (j, int(round((mj + 1.5) / q_true)), -1)]
    alone = masr.fit(edges, r, 0.05)
    both = masr.fit(edges, r, 0.05, ends=[int(round(800.0 / q_true))] * 2, length_mm=800.0)
    assert abs(alone["mm_per_count"] / q_true - 1) > 8e-4            # tilted by the glue
    assert abs(both["mm_per_count"] / q_true - 1) < 3e-4             # the far stop pulls it back
    assert abs(abs(both["end_mm"][0]) - 800.0) < 0.3


def test_a_firmware_without_end_is_calibrated_from_the_magnets_alone():
    class NoEnd:
        def __init__(self, reason):
            self.reason = reason

        def run(self, verb, *args, way=0):
            raise ArmbridgeError(f"the board refused {verb} {' '.join(map(str, args))}: {self.reason}")

    assert masr._end(NoEnd("4 VERB")) is False
    with pytest.raises(ArmbridgeError, match="UNHOMED"):
        masr._end(NoEnd("14 UNHOMED"))


def test_the_joints_land_on_their_angles_whatever_the_worms_play(calibrated):
    """The worms' play is drawn (about 15 mrad, up to 30) and no calibration measures it:
    the current sense finds where each fresh mesh meets its gear (firmware/masr_ma/drive.py
    `contact`), so the true joints end within JOINT_MRAD of what ROT asked, on every board."""
    plays = [max(pl.halves) * 2000.0 for _, pl, _, _, _ in calibrated]
    assert max(plays) > 15.0                      # boards whose play the config's 3 mrad is far from
    for seed, err in TURNED.items():
        assert max(abs(e) for e in err) <= JOINT_MRAD, (seed, err)
