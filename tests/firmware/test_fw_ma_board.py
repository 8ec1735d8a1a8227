"""The MASR actuator's board (firmware/masr_ma/ma.py) on the fake MA
(tests/firmware/fwma.py): actions, ranges, UNHOMED, persistence, telemetry."""

import ma
import protodef as P
from fwma import FakeMaHal, done_ids, load_config, new_board, run_until
from fwutil import Host, events, replies, run

CFG = load_config(WDOG_MS=10000000)


def _homed(**kw):
    board, hal, host = new_board(CFG, **kw)
    ans = host.answer(2, "HOME", 100)
    assert ans[1] == "OK", ans
    run_until(board, hal, lambda: not board.unhomed and not board.busy(), 30000)
    hal.take()
    return board, hal, host


def _until_done(board, hal, wid, ms_max):
    seen = []

    def each():
        seen.extend(done_ids(hal.take()))
    run_until(board, hal, lambda: wid in seen, ms_max, each)
    return seen


def test_boot_unhomed_refuses_mv_and_rot_until_home():
    board, hal, host = new_board(CFG)
    assert board.unhomed
    assert host.answer(2, "MV", 1, 100)[2][:3] == ["2", str(P.UNHOMED), "UNHOMED"]
    assert host.answer(3, "ROT", 2, 2, 100)[2][2] == "UNHOMED"
    assert host.answer(4, "GRIP", 3, 1)[1] == "OK"          # the gripper needs no d
    assert host.answer(5, "HOME", 4)[1] == "OK"
    assert host.answer(6, "MV", 5, 100)[1] == "OK"           # a HOME is ahead of it
    _until_done(board, hal, 5, 6000)
    assert not board.unhomed
    assert abs(hal.d - 100.0) <= CFG.STOP_TOL_MM + CFG.HALL_WINDOW_MM + 0.1


def test_home_from_mid_arm_at_the_base_stop():
    board, hal, host = new_board(CFG, d=330.0)
    assert host.answer(2, "HOME", 9)[1] == "OK"
    _until_done(board, hal, 9, 20000)
    assert hal.d == 0.0 and board.loc.d() == 0.0 and board.loc.jd() == 1
    assert not board.unhomed and hal.u_loco == 0.0


def test_end_pushes_onto_the_far_stop_and_reports_its_count():
    board, hal, host = _homed()
    hal.length += 0.4                    # this arm's end cap sits 0.4 mm beyond l
    assert host.answer(3, "END", 7)[1] == "OK"
    lines = []

    def each():
        lines.extend(hal.take())
    run_until(board, hal, lambda: 7 in done_ids(lines), 30000, each)
    ev = events(lines, "ENDSTOP")
    assert len(ev) == 1 and ev[0][1] == str(board.n), ev
    assert int(ev[0][2]) == hal.wheel_count() - board.loc.c_home     # the count from home, at the stop
    assert hal.d == hal.length and hal.u_loco == 0.0
    assert abs(board.loc.d() - hal.length) <= board.loc.err()        # the estimate kept, not re-zeroed


def test_end_needs_a_known_d_and_faults_past_a_missing_stop():
    board, hal, host = new_board(CFG)
    assert host.answer(2, "END", 1)[2][2] == "UNHOMED"
    board, hal, host = _homed()
    hal.length += 3 * CFG.END_APPROACH_MM + 20.0   # no stop where l says
    assert host.answer(3, "END", 8)[1] == "OK"
    lines = []

    def each():
        lines.extend(hal.take())
    run_until(board, hal, lambda: board.state == "FAULT", 40000, each)
    assert board.link.reason == "END:MISSED" and events(lines, "FAULT")[0][:2] == ["FAULT", str(board.n)]
    assert hal.u_loco == 0.0 and not events(lines, "ENDSTOP")


def test_mv_reaches_d_with_a_ramp():
    board, hal, host = _homed()
    assert host.answer(3, "MV", 1, 350)[1] == "OK"
    speeds = []
    seen = []

    def each():
        seen.extend(done_ids(hal.take()))
        speeds.append(hal.v)
    run_until(board, hal, lambda: 1 in seen, 8000, each)
    assert abs(hal.d - 350.0) <= 4.05, hal.d       # the bound loc.py derives
    assert abs(board.loc.d() - 350.0) <= CFG.STOP_TOL_MM
    top = max(speeds)
    assert 99.0 <= top <= 110.0, top                 # 100 mm/s, the speed loop (a transient over it)
    cruise = speeds[1000:2500]                       # 100..250 mm: at speed
    mean = sum(cruise) / len(cruise)
    assert abs(mean - 100.0) < 1.0 and min(cruise) > 97.0, (mean, min(cruise))
    # ramped start and stop: no step in the speed of more than the ramp allows
    # (LOCO_ACCEL_MM_S2 plus the loop's correction), and it starts and ends at rest
    steps = [abs(speeds[i + 1] - speeds[i]) for i in range(len(speeds) - 1)]
    assert max(steps) < 1.5, max(steps)              # mm/s per ms
    assert abs(speeds[-1]) < 5.0
    assert hal.u_loco == 0.0


def test_rot_drives_to_the_joint_then_turns_it():
    board, hal, host = _homed()
    assert host.answer(3, "ROT", 7, 3, -250)[1] == "OK"
    log = []

    def each():
        log.append((hal.d, hal.theta[2], hal.mesh))
    seen = []

    def each2():
        each()
        seen.extend(done_ids(hal.take()))
    run_until(board, hal, lambda: 7 in seen, 12000, each2)
    # the joint did not turn before the MA was on it
    for d, th, mesh in log:
        if abs(th) > 0.01:
            assert abs(d - 400.0) <= 3.0, d
    assert abs(hal.d - 400.0) <= 3.0
    assert abs(hal.theta[2] - (-250.0)) <= CFG.BACKLASH_MRAD / 2 + CFG.ROT_TOL_MRAD + 0.2, hal.theta
    assert abs(board.theta[2] - (-250.0)) <= CFG.ROT_TOL_MRAD
    assert hal.theta[0] == 0.0 and hal.theta[1] == 0.0
    # the same joint again: no locomotion, it turns at once
    d0 = hal.d
    assert host.answer(4, "ROT", 8, 3, 100)[1] == "OK"
    _until_done(board, hal, 8, 6000)
    assert abs(hal.d - d0) < 0.3
    assert abs(hal.theta[2] - 100.0) <= CFG.BACKLASH_MRAD / 2 + CFG.ROT_TOL_MRAD + 0.2


def test_the_joint_lands_on_its_angle_wherever_a_fresh_mesh_meets_the_gear():
    """The current sense (drive.py `contact`): the estimate moves only once the worm
    loads its gear, so a worm of 15 mrad play (five times the config's) lands the
    joint within a period's half travel plus ROT_TOL, from either end of its play
    and its middle; the play model alone would be off by up to the play."""
    for gap0 in (-7.5, 0.0, 7.5):
        board, hal, host = _homed()
        hal.backlash = 15.0
        hal.gap0 = gap0
        assert host.answer(3, "ROT", 7, 3, -250)[1] == "OK"
        _until_done(board, hal, 7, 12000)
        assert abs(hal.theta[2] - (-250.0)) <= 1.5 + CFG.ROT_TOL_MRAD, (gap0, hal.theta)
        assert host.answer(4, "ROT", 8, 3, 100)[1] == "OK"           # back the other way: the play crossed
        _until_done(board, hal, 8, 8000)
        assert abs(hal.theta[2] - 100.0) <= 1.5 + CFG.ROT_TOL_MRAD, (gap0, hal.theta)


def test_without_a_current_sense_the_config_play_is_assumed():
    cfg = load_config(WDOG_MS=10000000, ROT_ISENSE_PIN=None)
    board, hal, host = new_board(cfg)
    assert host.answer(2, "HOME", 100)[1] == "OK"
    run_until(board, hal, lambda: not board.unhomed and not board.busy(), 30000)
    hal.sense_dead = True                       # nothing reads it: the firmware must not need it
    hal.gap0 = -cfg.BACKLASH_MRAD / 2
    assert host.answer(3, "ROT", 7, 3, 200)[1] == "OK"
    _until_done(board, hal, 7, 12000)
    assert not board.rot.sense and board.state != "FAULT"
    assert abs(hal.theta[2] - 200.0) <= cfg.BACKLASH_MRAD + cfg.ROT_TOL_MRAD, hal.theta


def test_rot_from_above_and_magnet_events():
    board, hal, host = _homed()
    host.answer(3, "MV", 1, 650)
    host.answer(4, "ROT", 2, 2, 200)
    lines = []

    def each():
        lines.extend(hal.take())
    run_until(board, hal, lambda: 2 in done_ids(lines), 30000, each)
    mags = [int(e[1]) for e in events(lines, "MAGNET")]
    assert mags == [2, 3, 4, 4, 3, 2], mags   # up past 2, 3, 4 to 650, back down over 4, 3 onto 2
    assert abs(hal.d - 200.0) <= 3.0 and abs(hal.theta[1] - 200.0) <= 3.0


def test_ranges_refused_and_the_board_keeps_answering():
    board, hal, host = _homed()
    seq = 3
    for verb, args, detail in (("MV", (1, 801), "d"), ("ROT", (1, 6, 0), "joint"),
                               ("ROT", (1, 2, 874), "2"), ("ROT", (1, 5, -874), "5"),
                               ("ROT", (1, 7, 0), "joint"), ("GRIP", (1, 2), "open"),
                               ("SETLIM", (6, 0, 900, 100), "6"), ("SETLIM", (2, 0, 100, 300), "2")):
        ans = host.answer(seq, verb, *args)
        assert ans[1] == "ER" and ans[2][2] == "RANGE" and ans[2][3] == detail, (verb, args, ans)
        seq += 1
    assert host.answer(seq, "W", 1, 100, 0, 0, 0, 0, 0, 0)[2][2] == "VERB"
    seq += 1
    assert host.answer(seq, "SETLIM", 6, 100, 700, 80)[1] == "OK"
    assert host.answer(seq + 1, "LIM", 6)[2][2:] == ["6", "100", "700", "80"]
    assert host.answer(seq + 2, "MV", 2, 50)[2][3] == "d"
    assert host.answer(seq + 3, "ROT", 2, 1, 0)[2][3] == "joint"   # r_1 = 0 is outside d's range now
    assert host.answer(seq + 4, "MV", 2, 150)[1] == "OK"
    assert host.answer(seq + 5, "SETLIM", 6, 200, 700, 80)[2][2] == "RANGE"   # the queued MV
    assert host.answer(seq + 6, "STAT")[1] == "OK"
    assert board.state in ("RUN", "IDLE")


def test_queue_credits_and_full():
    board, hal, host = _homed()
    # no time passes between the lines: nothing begins, every OK has one credit less
    for i in range(CFG.QSIZE):
        ans = host.answer(3 + i, "GRIP", i, i % 2)
        assert ans[1] == "OK" and ans[2][1] == str(CFG.QSIZE - i - 1), ans
    ans = host.answer(3 + CFG.QSIZE, "GRIP", 99, 1)
    assert ans[1] == "ER" and ans[2][2] == "FULL", ans
    assert board.link.queued == CFG.QSIZE - 1
    _until_done(board, hal, CFG.QSIZE - 1, CFG.QSIZE * (CFG.GRIP_MS + 20))
    assert board.free() == CFG.QSIZE and hal.grip_open is True


def test_reset_mid_move_is_unhomed_until_home():
    board, hal, host = _homed()
    host.answer(3, "MV", 1, 500)
    run_until(board, hal, lambda: hal.d > 250.0, 5000)
    # reset: a new board on the same persisted memory, the MA coasts to rest
    hal.outputs_off()
    hal.step_plant(200)
    b2 = ma.Board(hal, CFG)
    host2 = Host(hal, b2)
    assert host2.hello(1, 8, 2)[1] == "OK"
    hal.take()
    assert b2.unhomed
    assert host2.answer(2, "MV", 1, 100)[2][2] == "UNHOMED"
    assert host2.answer(3, "ROT", 2, 1, 100)[2][2] == "UNHOMED"
    assert host2.answer(4, "HOME", 3)[1] == "OK"
    _until_done(b2, hal, 3, 20000)
    assert not b2.unhomed and hal.d == 0.0
    assert host2.answer(5, "MV", 4, 120)[1] == "OK"
    _until_done(b2, hal, 4, 5000)
    assert abs(hal.d - 120.0) < 4.0


def test_joint_angles_and_d_survive_a_reset_at_rest():
    board, hal, host = _homed()
    host.answer(3, "ROT", 1, 2, 300)
    host.answer(4, "ROT", 2, 4, -150)
    host.answer(5, "MV", 3, 450)
    _until_done(board, hal, 3, 30000)
    run(board, hal, 200)
    th = list(board.theta)
    d = board.loc.d()
    b2 = ma.Board(hal, CFG)
    assert not b2.unhomed
    assert abs(b2.loc.d() - d) < 0.01
    for j in range(5):
        assert abs(b2.theta[j] - th[j]) < 0.01
    assert abs(b2.theta[1] - 300.0) < 1.5 and abs(b2.theta[3] + 150.0) < 1.5
    host2 = Host(hal, b2)
    assert host2.hello(1, 9, 2)[1] == "OK"   # the next epoch (E + 1)
    assert host2.answer(2, "MV", 1, 420)[1] == "OK"      # it knows d: no HOME needed
    _until_done(b2, hal, 1, 5000)
    assert abs(hal.d - 420.0) < 4.0


def test_telemetry_fields():
    board, hal, host = _homed()
    host.answer(3, "RATE", 100)
    host.answer(4, "ROT", 1, 2, 120)
    tl = []
    seen = []

    def each():
        for ln in hal.take():
            if ln[1] == "T":
                tl.append(ln[2])
            elif ln[1] == "EV" and ln[2][1] == "DONE":
                seen.append(int(ln[2][2]))
    run_until(board, hal, lambda: 1 in seen, 10000, each)
    n = CFG.N_JOINTS
    for f in tl:
        assert len(f) == 4 + 3 * n + 3, f
    # while turning: the joint's column carries the rotation output, d the loco's (0)
    turning = [f for f in tl if f[4 + 2 * n + 1] != "0"]
    assert turning
    f = turning[len(turning) // 2]
    assert f[4 + 3 * n - 1] == "0"
    # on joint 2 (r_2 = 200): link 2 at its start, or link 1 at its end
    jd, dlink, speed = [int(x) for x in f[4 + 3 * n:]]
    assert (jd, dlink) in ((2, 0), (2, 1), (1, 200), (1, 199)) and abs(speed) <= 3, f
    assert abs(int(f[4 + n - 1]) - 200) <= 1
    driving = [f for f in tl if f[4 + 3 * n - 1] != "0"]
    assert driving
    g = driving[len(driving) // 2]
    assert int(g[4 + 3 * n + 2]) > 20                  # speed mm/s from the encoder
    assert int(g[4 + 3 * n]) == 1 and 0 < int(g[4 + 3 * n + 1]) < 200   # on link 1
    last = tl[-1]
    assert abs(int(last[4 + 1]) - 120) <= 2           # theta_2 estimate, mrad
    assert abs(int(last[4 + n - 1]) - 200) <= 2        # d, mm
    assert int(last[4 + 3 * n]) in (1, 2)              # at r_2


def test_grip_and_hold_resume():
    board, hal, host = _homed()
    host.answer(3, "GRIP", 1, 1)
    _until_done(board, hal, 1, 1000)
    assert hal.grip_open is True
    host.answer(4, "MV", 2, 300)
    run_until(board, hal, lambda: hal.d > 100.0, 5000)
    assert host.answer(5, "HOLD")[1] == "OK"
    run_until(board, hal, lambda: abs(hal.v) < 0.5, 1000)
    d_held = hal.d
    run(board, hal, 300)
    hal.take()
    assert abs(hal.d - d_held) < 1.0 and board.state == "HOLD"
    assert d_held < 140.0                               # braked at the ramp, not run on
    assert host.answer(6, "RESUME")[1] == "OK"
    _until_done(board, hal, 2, 5000)
    assert abs(hal.d - 300.0) < 4.0
    assert replies(hal.take(), "ER") == []
