"""Board(hal, cfg), the arm's part, with a fake HAL: scripted bytes in, lines
out: waypoints, telemetry, e-stop, watchdog, SETLIM, following error, the
completion hook. The link's session and latch rules: test_fw_link.py."""

import arm
import config
import proto
from fwutil import FakeHal, Host, events, replies, run


def _board(**kw):
    hal = FakeHal(**kw)
    board = arm.Board(hal, config)
    return hal, board


def _session(sid=4242, **kw):
    hal, board = _board(**kw)
    host = Host(hal, board)
    assert host.hello(1, sid)[1] == "OK"
    run(board, hal, 1)
    hal.take()
    return hal, board, host


def test_boot_line_and_hello_reply():
    hal, board = _board()
    lines = hal.take()
    assert lines[0][1:] == ("BOOT", ["arm3r", "0.1.0", "2", "IDLE"])
    ans = Host(hal, board).hello(1, 4242)
    assert ans[1:] == ("OK", ["1", "32", "arm3r", "0.1.0", "2", "3", "32", "25", "1000",
                              "-", "-", "IDLE"])
    assert ans[0] == 1                                  # board line counter after BOOT
    assert board.state == "IDLE"


def test_lim_and_stat_and_ping():
    hal, board, host = _session()
    assert host.answer(2, "LIM", 1)[2] == ["2", "32", "1", "0", "3142", "3000"]
    assert host.answer(3, "LIM", 2)[2] == ["3", "32", "2", "-3142", "0", "3000"]
    assert host.answer(4, "LIM", 3)[2] == ["4", "32", "3", "-1571", "1571", "3000"]
    st = host.answer(5, "STAT")[2]
    assert st[:5] == ["5", "32", "IDLE", "-", "-"] and st[6] == "-"   # no latch reason
    assert host.answer(6, "PING")[2][:2] == ["6", "32"]


def test_waypoints_run_to_done_and_report():
    hal, board, host = _session()
    assert host.answer(2, "W", 10, 300, 1300, -1200, 200)[2] == ["2", "31"]
    assert host.answer(3, "W", 11, 200, 1400, -1100, 300)[2] == ["3", "30"]
    assert board.state == "RUN"
    run(board, hal, 700)
    lines = hal.take()
    evs = events(lines)
    # START only from rest: waypoint 11 starts in the tick waypoint 10 is DONE,
    # which frees its slot, so 32 are free both times
    assert evs == [["START", "10"], ["DONE", "10", "32"], ["DONE", "11", "32"]], evs
    assert board.state == "IDLE"
    assert abs(hal.q[0] - 1.4) < 0.02 and abs(hal.q[1] + 1.1) < 0.02
    st = host.answer(4, "STAT")[2]
    assert st[2:5] == ["IDLE", "11", "11"]


def test_events_of_one_tick_are_coalesced():
    """Five 2 ms waypoints end within one or two 10 ms ticks: one DONE per tick,
    naming the last waypoint completed in it; START only for the first."""
    hal, board, host = _session()
    host.answer(2, "W", 20, 500, 1571, -1571, 0)
    for i in range(5):
        host.answer(3 + i, "W", 21 + i, 2, 1571 + i, -1571, 0)
    run(board, hal, 700)
    evs = events(hal.take())
    dones = [e for e in evs if e[0] == "DONE"]
    assert dones[-1] == ["DONE", "25", "32"] and len(dones) <= 3, evs
    assert [e for e in evs if e[0] == "START"] == [["START", "20"]], evs
    assert host.answer(8, "STAT")[2][2:5] == ["IDLE", "25", "25"]


def test_slow_event_when_too_fast():
    hal, board, host = _session()
    host.answer(2, "W", 1, 100, 2000, -1000, 0)   # 1000 mrad in 100 ms on joint 1
    run(board, hal, 20)
    assert ["SLOW", "1", "1"] in events(hal.take())


def test_telemetry_rate_and_fields():
    hal, board, host = _session()
    run(board, hal, 1000)
    ts = [ln for ln in hal.take() if ln[1] == "T"]
    assert 24 <= len(ts) <= 26
    args = ts[-1][2]
    assert len(args) == 4 + 3 * 3
    assert args[1] == "IDLE" and args[2] == "-" and args[3] == "32"
    assert abs(int(args[4]) - 1000) < 20 and abs(int(args[5]) + 1000) < 20
    host.answer(2, "RATE", 100)
    run(board, hal, 500)
    assert 49 <= len([ln for ln in hal.take() if ln[1] == "T"]) <= 51
    host.answer(3, "RATE", 0)
    run(board, hal, 300)
    assert [ln for ln in hal.take() if ln[1] == "T"] == []


def test_estop_mid_queue_outputs_off_in_same_poll_and_latched():
    hal, board, host = _session()
    for i in range(5):
        host.answer(2 + i, "W", i, 400, 1000 + 100 * (i + 1), -1000, 0)
    run(board, hal, 150)
    assert hal.on and board.state == "RUN"
    hal.send(b"3 PI\x98")                                # e-stop in the middle of a line
    off_before = hal.off_calls
    board.poll()
    assert not hal.on and hal.off_calls == off_before + 1
    assert board.state == "ESTOP"
    assert board.traj.free() == 32 and not board.traj.busy()
    assert ["ESTOP"] in events(hal.take())
    hal.send(b"NG*0000\n")                               # rest of the cut line: dropped silently
    run(board, hal, 300)
    assert not hal.on and board.state == "ESTOP"
    assert replies(hal.take(), "ER") == []
    ans = host.answer(7, "W", 9, 400, 1500, -1000, 0)
    assert ans[2][1:3] == ["9", "LATCHED"]
    assert host.answer(8, "HOLD")[2][1:3] == ["9", "LATCHED"]
    assert board.state == "ESTOP"
    host.send(9, "CLR")
    board.poll()
    lines = replies(hal.take())
    assert lines[0][1:] == ("OK", ["9", "32"]) and events(lines) == [["CLEAR"]]
    assert board.state == "IDLE"
    run(board, hal, 20)
    assert hal.on
    assert host.answer(10, "W", 9, 400, 1500, -1000, 0)[1] == "OK"


def test_estop_works_before_hello_and_with_full_queue():
    hal, board = _board()
    hal.send(b"\x98")
    board.poll()
    assert board.state == "ESTOP" and not hal.on
    hal2, board2, host2 = _session()
    for i in range(32):
        host2.answer(2 + i, "W", i, 1000, 1000, -1000, 0)
    assert host2.answer(34, "W", 99, 1000, 1000, -1000, 0)[2][1:3] == ["8", "FULL"]
    hal2.send(b"\x98")
    board2.poll()
    assert board2.state == "ESTOP" and not hal2.on


def test_watchdog_stops_on_silence_while_running():
    hal, board, host = _session()
    host.answer(2, "W", 1, 5000, 2000, -1000, 0)
    run(board, hal, 900)
    assert board.state == "RUN"
    hal.take()
    run(board, hal, 200)
    assert board.state == "WDOG"
    assert ["WDOG"] in events(hal.take())
    assert not board.traj.busy()
    assert hal.u == [0.0, 0.0, 0.0]                    # zero effort, held
    assert host.answer(3, "W", 2, 500, 1000, -1000, 0)[2][1:3] == ["9", "LATCHED"]
    assert host.answer(4, "CLR")[1] == "OK"
    assert board.state == "IDLE"


def test_watchdog_kept_alive_by_ping_and_silent_when_idle():
    hal, board, host = _session()
    host.answer(2, "WDOG", 200)
    host.answer(3, "W", 1, 1000, 2000, -1000, 0)
    for i in range(8):
        run(board, hal, 100)
        host.send(4 + i, "PING")
    run(board, hal, 1)
    assert board.state == "RUN"
    run(board, hal, 400)                               # done at 1000 ms, then silence
    assert board.state in ("IDLE", "WDOG")
    hal2, board2, host2 = _session()
    run(board2, hal2, 3000)
    assert board2.state == "IDLE"


def test_range_nosession_and_seq_errors():
    hal, board = _board()
    hal.take()
    host = Host(hal, board, epoch=0)                   # no epoch opened since power on
    assert host.answer(1, "W", 1, 500, 1000, -1000, 0)[2][1:3] == ["10", "NOSESSION"]
    assert host.answer(2, "PING")[1] == "OK"   # read-only verbs answer without a session
    assert host.hello(5, 77, 1)[1] == "OK"
    ans = host.answer(6, "W", 1, 500, -10, -1000, 0)   # shoulder below 0
    assert ans[2][1:4] == ["6", "RANGE", "1"]
    ans = host.answer(7, "W", 1, 500, 1000, 10, 0)     # elbow above 0
    assert ans[2][1:4] == ["6", "RANGE", "2"]
    ans = host.answer(9, "PING")                        # 8 skipped
    assert ans[1] == "ER" and ans[2] == ["9", "7", "SEQ", "8"]
    assert host.answer(8, "W", 1, 500, 1000, -1000, 1571)[1] == "OK"


def test_duplicates_replayed_not_executed():
    hal, board, host = _session()
    first = host.answer(2, "W", 1, 500, 1200, -1000, 0)
    assert board.traj.queued() == 1
    again = host.answer(2, "W", 1, 500, 1200, -1000, 0)
    assert again[2] == first[2] and again[0] != first[0]
    assert board.traj.queued() == 1
    err = host.answer(3, "W", 2, 500, -5, -1000, 0)
    assert host.answer(3, "W", 2, 500, -5, -1000, 0)[2] == err[2]
    assert host.answer(4, "W", 3, 500, 1300, -1000, 0)[2] == ["4", "30"]


def test_setlim_only_narrows():
    hal, board, host = _session()
    assert host.answer(2, "SETLIM", 1, 500, 2500, 2000)[1] == "OK"
    assert host.answer(3, "LIM", 1)[2][2:] == ["1", "500", "2500", "2000"]
    assert host.answer(4, "SETLIM", 1, -1, 2500, 2000)[2][1:3] == ["6", "RANGE"]
    assert host.answer(5, "SETLIM", 3, -1571, 1572, 2000)[2][1:3] == ["6", "RANGE"]
    assert host.answer(6, "SETLIM", 2, -3000, 0, 3001)[2][1:3] == ["6", "RANGE"]
    assert host.answer(7, "W", 1, 500, 2600, -1000, 0)[2][1:3] == ["6", "RANGE"]
    assert host.answer(8, "W", 1, 500, 2400, -1000, 0)[1] == "OK"
    assert host.answer(9, "GAIN", 1, 6000, 0, 100)[1] == "OK"
    assert board.pids[0].kp == 6.0 and board.pids[0].kd == 0.1


def test_bad_input_answered_and_board_keeps_answering():
    hal, board, host = _session()
    hal.send(b"garbage\n")
    hal.send(b"x" * 300 + b"\n")
    good = proto.encode(2, "PING", [], host.epoch)
    hal.send(good[:-10] + b"*00000000\n")               # bad CRC
    hal.send(proto.encode(2, "JUMP", [], host.epoch))
    hal.send(b"\n\xff\x00\n")
    board.poll()
    ers = [ln[2][:3] for ln in replies(hal.take(), "ER")]
    assert ers == [["-", "1", "PARSE"], ["-", "3", "LONG"], ["-", "2", "CRC"],
                   ["2", "4", "VERB"], ["-", "1", "PARSE"], ["-", "1", "PARSE"]], ers
    ans = host.answer(3, "PING")
    assert ans[1] == "OK" and ans[2][0] == "3"


def test_hold_resume_events():
    hal, board, host = _session()
    host.answer(2, "W", 1, 400, 1400, -1000, 0)
    run(board, hal, 100)
    host.send(3, "HOLD")
    board.poll()
    assert board.state == "HOLD"
    sp = list(board.traj.sp)
    run(board, hal, 300)
    assert board.traj.sp == sp
    host.send(4, "RESUME")
    run(board, hal, 400)
    lines = hal.take()
    kinds = [e[0] for e in events(lines)]
    assert kinds == ["START", "HOLD", "RESUME", "DONE"], kinds
    assert board.state == "IDLE"


def test_following_error_faults():
    hal, board, host = _session()
    hal.stalled = True
    host.answer(2, "W", 1, 1000, 2500, -1000, 0)
    for i in range(12):
        run(board, hal, 100)
        host.send(3 + i, "PING")
    assert board.state == "FAULT"
    evs = events(hal.take(), "FAULT")
    assert len(evs) == 1 and evs[0][1] == "1"
    assert not hal.on


def test_late_poll_runs_one_tick_and_resyncs():
    hal, board, host = _session()
    n = [0]
    orig = board.link.tick

    def counting():
        n[0] += 1
        orig()

    board.link.tick = counting
    hal.t += 100                                       # the loop stalled for 100 ms
    board.poll()
    board.poll()
    assert n[0] == 1
    run(board, hal, 100)
    assert 9 <= n[0] <= 11


def test_ticks_wrap():
    hal, board = _board(t0=(1 << 30) - 500)
    host = Host(hal, board)
    host.send(1, "HELLO", 2, 3, 1)
    host.send(2, "W", 1, 800, 1400, -1000, 0)
    run(board, hal, 1000)
    assert ["DONE", "1", "32"] in events(hal.take())
    assert board.state == "IDLE"


def test_setlim_narrowing_moves_the_set_point_at_vmax_with_one_limit_event():
    hal, board, host = _session()                      # shoulder at 1000 mrad, vmax 3000
    assert host.answer(2, "SETLIM", 1, 2000, 2500, 2000)[1] == "OK"
    prev = board.traj.sp[0]
    lines = []
    for _ in range(80):
        run(board, hal, 10)
        lines += hal.take()
        sp = board.traj.sp[0]
        assert 0.0 <= sp - prev <= 2000 * 0.010 + 1e-6, (prev, sp)   # never above vmax
        prev = sp
    assert board.traj.sp[0] == 2000.0
    assert events(lines, "LIMIT") == [["LIMIT", "1"]]
    assert board.state == "IDLE" and abs(hal.q[0] - 2.0) < 0.05
    assert host.answer(3, "SETLIM", 2, -500, -500, 1000)[1] == "OK"   # min == max: locked
    run(board, hal, 800)
    assert board.traj.sp[1] == -500.0
    assert host.answer(4, "LIM", 2)[2][2:] == ["2", "-500", "-500", "1000"]
    assert host.answer(5, "W", 1, 100, 2200, -400, 0)[2][1:4] == ["6", "RANGE", "2"]
    assert host.answer(6, "W", 1, 100, 2200, -500, 0)[1] == "OK"


def test_setlim_excluding_a_queued_target_refused():
    hal, board, host = _session()
    host.answer(2, "WDOG", 5000)
    host.answer(3, "W", 1, 1000, 1500, -1000, 0)
    host.answer(4, "W", 2, 1000, 2500, -1000, 0)
    ans = host.answer(5, "SETLIM", 1, 0, 2000, 3000)      # waypoint 2 would fall outside
    assert ans[1] == "ER" and ans[2][1:4] == ["6", "RANGE", "1"]
    assert host.answer(6, "LIM", 1)[2][2:] == ["1", "0", "3142", "3000"]
    assert host.answer(7, "SETLIM", 1, 0, 2500, 3000)[1] == "OK"
    run(board, hal, 1100)                                  # 1 done, 2 under way
    assert board.state == "RUN" and board.traj.active_id == 2
    ans = host.answer(8, "SETLIM", 1, 0, 2400, 3000)       # the active target counts too
    assert ans[2][1:4] == ["6", "RANGE", "1"]
    assert host.answer(9, "SETLIM", 2, -1000, -1000, 3000)[1] == "OK"


def test_on_done_gets_id_and_values():
    hal, board, host = _session()
    got = []
    board.on_done = lambda w, targets: got.append((w, list(targets)))
    host.answer(2, "W", 40, 200, 1100, -900, 50)
    for i in range(4):                                     # short ones: coalesced events,
        host.answer(3 + i, "W", 41 + i, 2, 1100 + i, -900, 50)   # each still reported here
    run(board, hal, 400)
    assert got == [(40, [1100, -900, 50])] + [(41 + i, [1100 + i, -900, 50]) for i in range(4)]
