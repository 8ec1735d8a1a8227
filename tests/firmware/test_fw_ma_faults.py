"""The MASR actuator's faults on the fake MA: a missed or a spurious magnet,
a slip burst, stalled motors, e-stop and watchdog. Each stops the motion,
latches, and the board keeps answering."""

import protodef as P
from fwma import done_ids, load_config, new_board, run_until
from fwutil import events, run

CFG = load_config(WDOG_MS=10000000)


def _homed(cfg=CFG, **kw):
    board, hal, host = new_board(cfg, **kw)
    assert host.answer(2, "HOME", 100)[1] == "OK"
    run_until(board, hal, lambda: not board.unhomed and not board.busy(), 30000)
    hal.take()
    return board, hal, host


def _fault(board, hal, ms_max):
    lines = []

    def each():
        lines.extend(hal.take())
    run_until(board, hal, lambda: board.state == "FAULT", ms_max, each)
    return lines


def _stopped(board, hal):
    """Outputs off, and the MA coasts to rest (100 mm/s behind the 40 ms lag: ~6 mm)."""
    assert hal.u_loco == 0.0 and hal.u_rot == 0.0 and not hal.on
    d0 = hal.d
    run(board, hal, 300)
    assert abs(hal.d - d0) < 8.0 and abs(hal.v) < 0.5
    assert not hal.on


def test_missed_magnet_faults_and_stops():
    board, hal, host = _homed()
    hal.present[1] = False                         # magnet 2 (r = 200) never fires
    host.answer(3, "MV", 1, 300)
    lines = _fault(board, hal, 5000)
    ev = events(lines, "FAULT")
    assert ev == [["FAULT", "6", "2"]], ev
    assert 1 not in done_ids(lines)
    assert 200.0 < hal.d < 215.0, hal.d            # right past the window, not at 300
    _stopped(board, hal)
    stat = host.answer(4, "STAT")
    assert stat[2][2] == "FAULT" and stat[2][6] == "MAGNET:MISSED", stat
    assert host.answer(5, "MV", 2, 100)[2][2] == "LATCHED"
    assert host.answer(6, "CLR")[1] == "OK"
    assert board.unhomed                           # a localisation fault: only HOME moves it
    assert host.answer(7, "MV", 3, 100)[2][2] == "UNHOMED"
    assert host.answer(8, "HOME", 4)[1] == "OK"
    seen = []
    run_until(board, hal, lambda: 4 in seen, 20000, lambda: seen.extend(done_ids(hal.take())))
    assert hal.d == 0.0 and not board.unhomed


def test_spurious_magnet_faults():
    board, hal, host = _homed()
    hal.extra = [100.0]                            # an edge halfway along link 1
    host.answer(3, "MV", 1, 150)
    lines = _fault(board, hal, 5000)
    assert events(lines, "FAULT")[0][:2] == ["FAULT", "6"]
    assert board.link.reason == "MAGNET:SPURIOUS"
    assert 100.0 <= hal.d < 106.0
    _stopped(board, hal)
    assert host.answer(4, "PING")[1] == "OK"


def test_slip_burst_beyond_the_bound_is_caught_at_the_next_magnet():
    board, hal, host = _homed()
    hal.burst = (20.0, 180.0, -0.15)               # the wheel spins: the MA advances 15 % less
    host.answer(3, "MV", 1, 260)
    _fault(board, hal, 8000)
    assert board.link.reason == "MAGNET:MISSED"
    assert hal.d < 200.0 - CFG.HALL_WINDOW_MM      # it never got there: no magnet under it
    _stopped(board, hal)


def test_slip_within_the_bound_is_no_fault():
    board, hal, host = _homed(slip=CFG.SLIP_MAX)
    host.answer(3, "MV", 1, 690)
    seen = []
    errs = []

    def each():
        seen.extend(done_ids(hal.take()))
        errs.append((abs(board.loc.d() - hal.d), board.loc.err()))
    run_until(board, hal, lambda: 1 in seen, 12000, each)
    assert board.state == "IDLE"
    assert max([e[0] - e[1] for e in errs]) <= 1e-6      # within the bound all the way
    assert abs(hal.d - 690.0) <= 4.05


def test_stalled_wheel_is_stall_loco():
    board, hal, host = _homed()
    host.answer(3, "MV", 1, 400)
    run_until(board, hal, lambda: hal.d > 50.0, 3000)
    hal.wheel_stalled = True
    _fault(board, hal, 3000)
    assert board.link.reason == "STALL:LOCO"
    _stopped(board, hal)
    assert not board.unhomed                       # it still knows where it is


def test_stalled_joint_is_stall_j():
    board, hal, host = _homed()
    hal.joint_stalled = 1                          # joint 2 seized
    host.answer(3, "ROT", 1, 2, 300)
    lines = _fault(board, hal, 10000)
    assert board.link.reason == "STALL:2"
    assert events(lines, "FAULT")[0][1] == "2"
    assert abs(hal.theta[1]) < 0.01
    _stopped(board, hal)


def test_a_worm_that_meets_no_gear_is_mesh_j():
    """No load on the current sense for PLAY_MAX_MRAD of worm travel: no gear there (or
    a dead sense): FAULT MESH:j, outputs off, and the joint's estimate never moved."""
    board, hal, host = _homed()
    hal.sense_dead = True
    host.answer(3, "ROT", 1, 2, 300)
    lines = _fault(board, hal, 10000)
    assert board.link.reason == "MESH:2"
    ev = events(lines, "FAULT")[0]
    assert ev[1] == "2" and int(ev[2]) > board.cfg.PLAY_MAX_MRAD
    assert board.theta[1] == 0.0
    _stopped(board, hal)


def test_estop_mid_move():
    board, hal, host = _homed()
    host.answer(3, "MV", 1, 400)
    run_until(board, hal, lambda: hal.d > 100.0, 3000)
    hal.send(bytes([P.ESTOP_BYTE]))
    board.poll()
    assert board.state == "ESTOP" and not hal.on
    lines = hal.take()
    assert events(lines, "ESTOP")
    run(board, hal, 300)
    assert abs(hal.v) < 0.5 and hal.d < 120.0
    assert 1 not in done_ids(hal.take())
    assert host.answer(4, "MV", 2, 100)[2][2] == "LATCHED"
    assert host.answer(5, "CLR")[1] == "OK"
    assert not board.unhomed                       # it tracked the coast: d still known
    assert abs(board.loc.d() - hal.d) < 3.0
    assert host.answer(6, "MV", 3, 50)[1] == "OK"
    seen = []
    run_until(board, hal, lambda: 3 in seen, 5000, lambda: seen.extend(done_ids(hal.take())))
    assert abs(hal.d - 50.0) < 4.05


def test_watchdog_stops_the_ma():
    cfg = load_config()                            # WDOG_MS 1000: the host must keep talking
    board, hal, host = new_board(cfg)
    assert host.answer(2, "HOME", 1)[1] == "OK"
    run_until(board, hal, lambda: not board.busy(), 3000)
    assert host.answer(3, "MV", 2, 500)[1] == "OK"
    run_until(board, hal, lambda: board.state == "WDOG", 2000)
    assert hal.u_loco == 0.0
    run(board, hal, 300)
    assert abs(hal.v) < 0.5
    assert host.answer(4, "STAT")[2][2] == "WDOG"
    assert host.answer(5, "MV", 3, 100)[2][2] == "LATCHED"
