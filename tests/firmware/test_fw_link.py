"""The common link layer (link.BoardLink) through the arm's Board: HELLO with
epochs, exactly once against late copies, latches that survive a reset,
outputs off after a boot, the watchdog fed only by lines answered OK, the
persist record."""

import arm
import config
import link
import proto
from fwutil import FakeHal, Host, events, replies, run


def _session(sid=4242, epoch=1, **kw):
    if epoch > 1 and "persist" not in kw:   # a board that last saw epoch - 1 (only E + 1 opens)
        kw["persist"] = b"AB2 0 %d - - - -" % (epoch - 1)
    hal = FakeHal(**kw)
    board = arm.Board(hal, config)
    host = Host(hal, board, epoch)
    assert host.hello(1, sid)[1] == "OK"
    run(board, hal, 1)
    hal.take()
    return hal, board, host


def _reset(hal):
    """A reset: a fresh Board on the same joints and persisted memory."""
    hal2 = FakeHal(q=hal.q, persist=hal.persist, t0=hal.t)
    board2 = arm.Board(hal2, config)
    return hal2, board2, hal2.take()


def _starts(lines, wid):
    return [e for e in events(lines, "START") if e[1] == str(wid)]


# ---------------------------------------------------------------- HELLO rules

def test_wrong_proto_refused_naming_the_board_version():
    hal, board, host = _session()
    host.answer(2, "W", 1, 2000, 2000, -1000, 0)
    for v in (1, 3):
        ans = host.answer(3, "HELLO", v, 4242, 9)
        assert ans[1] == "ER" and ans[2] == ["3", "12", "PROTO", "2"]
    # Another version's HELLO may take other arguments: still PROTO, naming 2.
    for args in ((1, 4242), (3, 4242, 9, 1), (3,)):
        ans = host.answer(3, "HELLO", *args)
        assert ans[1] == "ER" and ans[2] == ["3", "12", "PROTO", "2"], args
    assert host.answer(3, "HELLO", 2, 4242)[2][:3] == ["3", "5", "ARGS"]
    assert board.link.session.epoch == 1 and board.traj.busy()
    assert host.answer(3, "PING")[1] == "OK"           # expect untouched


def test_new_epoch_new_session_flushes_and_stops_here():
    hal, board, host = _session(1)
    host.answer(2, "W", 1, 2000, 2000, -1000, 0)
    run(board, hal, 300)
    ans = host.hello(90, 2, 2)
    assert ans[1] == "OK" and ans[2][1] == "32" and ans[2][-3:] == ["-", "-", "IDLE"]
    assert board.state == "IDLE" and not board.traj.busy()
    for j in range(3):
        assert abs(board.traj.sp[j] - hal.q[j] * 1000.0) < 1.0   # set point = where the arm is
    assert host.answer(91, "PING")[1] == "OK"


def test_same_session_resync_keeps_queue_and_motion():
    hal, board, host = _session(1)
    host.answer(2, "W", 1, 2000, 2000, -1000, 0)
    host.answer(3, "W", 2, 2000, 2100, -1000, 0)
    run(board, hal, 50)
    ans = host.hello(50, 1, 2)
    assert ans[1] == "OK" and ans[2][1] == "31" and ans[2][-3:] == ["-", "2", "RUN"]
    assert board.state == "RUN" and board.traj.busy()
    assert host.answer(51, "PING")[1] == "OK"
    ans = host.answer(4, "W", 3, 100, 2100, -1000, 0)   # the old expect: a seq error now
    assert ans[2][1:4] == ["7", "SEQ", "52"]


def test_copy_of_the_opening_hello_answered_afresh_without_rewinding():
    hal, board, host = _session(7, epoch=5)
    for i in range(40):                                  # far more than the ring
        assert host.answer(2 + i, "PING")[1] == "OK"
    host.answer(42, "W", 9, 300, 1200, -1000, 0)
    ans = host.hello(1, 7, 5)                            # the copy, long after
    assert ans[1] == "OK" and ans[2][-3:] == ["-", "9", "RUN"] and ans[2][1] == "31"
    assert board.traj.queued() + (board.traj.active_id >= 0) == 1
    assert host.answer(43, "PING")[1] == "OK"           # expect was not rewound
    assert host.answer(2, "W", 9, 300, 1200, -1000, 0)[2][1:3] == ["7", "SEQ"]


def test_stale_epoch_refused_with_the_board_epoch():
    hal, board, host = _session(7, epoch=5)
    for epoch, sid, seq in ((4, 7, 1), (5, 8, 1), (5, 7, 2), (1, 9, 30)):
        ans = host.answer(seq, "HELLO", 2, sid, epoch)
        assert ans[1] == "ER" and ans[2] == [str(seq), "11", "STALE", "5"], ans
    assert board.link.session.session == 7 and board.link.session.expect == 2
    assert host.hello(3, 7, 6)[1] == "OK"               # E + 1: accepted


def test_late_copies_of_a_finished_waypoint_never_run_twice():
    hal, board, host = _session(3, epoch=1)
    done = []
    board.on_done = lambda w, t: done.append(w)
    old_hello = proto.encode(1, "HELLO", (2, 3, 1))
    old_w = proto.encode(2, "W", (5, 100, 1200, -1000, 0), 1)
    hal.send(old_w)
    run(board, hal, 300)
    assert done == [5]
    assert host.hello(20, 3, 2)[1] == "OK"              # a resync opens epoch 2
    host.answer(21, "PING")
    lines = []
    for _ in range(3):
        hal.send(old_hello)                               # a stale HELLO ...
        hal.send(old_w)                                   # ... and the W it had opened
        run(board, hal, 200)
        lines += hal.take()
    ers = [ln[2][:4] for ln in replies(lines, "ER")]
    assert ers == [["1", "11", "STALE", "2"], ["-", "2", "CRC"]] * 3, ers
    assert _starts(lines, 5) == [] and done == [5]
    assert host.answer(22, "STAT")[2][3:5] == ["5", "5"]


# ---------------------------------------------------------------- latches and boots

def test_power_on_outputs_off_until_hello():
    hal = FakeHal()
    board = arm.Board(hal, config)
    assert hal.take()[0][2] == ["arm3r", "0.1.0", "2", "IDLE"]
    run(board, hal, 500)
    assert not hal.on and hal.off_calls >= 1 and board.state == "IDLE"
    host = Host(hal, board, epoch=0)                   # no epoch opened since power on
    assert host.answer(1, "STAT")[1] == "OK"            # read-only: answered, still off
    run(board, hal, 50)
    assert not hal.on
    assert host.hello(2, 9, 1)[1] == "OK"
    run(board, hal, 20)
    assert hal.on and hal.u == [0.0, 0.0, 0.0]          # on, holding where it is


def _latch_estop(board, hal, host):
    hal.send(b"\x98")
    board.poll()


def _latch_wdog(board, hal, host):
    host.answer(2, "W", 1, 5000, 2000, -1000, 0)
    run(board, hal, 1200)


def _latch_fault(board, hal, host):
    hal.stalled = True
    host.answer(2, "W", 1, 1000, 2500, -1000, 0)
    for i in range(12):
        run(board, hal, 100)
        host.send(3 + i, "PING")
    run(board, hal, 1)


def test_latches_survive_a_reset_and_only_clr_releases_them():
    for name, make in (("ESTOP", _latch_estop), ("WDOG", _latch_wdog), ("FAULT", _latch_fault)):
        hal, board, host = _session(11)
        make(board, hal, host)
        assert board.state == name, (name, board.state)
        hal2, board2, boot = _reset(hal)
        assert boot[0][1:] == ("BOOT", ["arm3r", "0.1.0", "2", name]), boot
        assert board2.state == name and not hal2.on
        host2 = Host(hal2, board2, epoch=1)
        ans = host2.hello(1, 11, 2)                        # resync: still latched
        assert ans[1] == "OK" and ans[2][-1] == name
        assert host2.answer(2, "W", 7, 500, 1200, -1000, 0)[2][1:3] == ["9", "LATCHED"]
        ans = host2.hello(3, 12, 3)                        # new session: still latched
        assert ans[1] == "OK" and ans[2][-1] == name
        run(board2, hal2, 100)
        assert not hal2.on and board2.state == name
        hal3, board3, boot = _reset(hal2)                  # and across a second reset
        assert boot[0][2][3] == name
        host3 = Host(hal3, board3)
        assert host3.hello(1, 12, 4)[1] == "OK"
        ans = host3.answer(2, "CLR")
        assert ans[1] == "OK" and board3.state == "IDLE"
        run(board3, hal3, 20)
        assert hal3.on
        assert host3.answer(3, "W", 7, 500, 1200, -1000, 0)[1] == "OK"
        hal4, board4, boot = _reset(hal3)
        assert boot[0][2][3] == "IDLE"


def test_fault_reason_in_stat_and_persisted():
    hal, board, host = _session()
    _latch_fault(board, hal, host)
    evs = events(hal.take(), "FAULT")
    assert len(evs) == 1 and evs[0][1] == "1"
    st = host.answer(15, "STAT")[2]
    assert st[2] == "FAULT" and st[6] == "FOLLOW:1"
    hal2, board2, boot = _reset(hal)
    host2 = Host(hal2, board2)
    host2.hello(1, 4242, 2)
    assert host2.answer(2, "STAT")[2][6] == "FOLLOW:1"
    host2.answer(3, "CLR")
    assert host2.answer(4, "STAT")[2][6] == "-"


def test_an_estop_over_a_latch_keeps_its_first_cause():
    """docs/protocol.md §9: an e-stop while FAULT or WDOG latches ESTOP (outputs off) and
    STAT's reason keeps the first cause (before: FAULT's FOLLOW:1 was replaced by "-");
    persisted; CLR releases both."""
    for make, first, seq in ((_latch_fault, "FOLLOW:1", 15), (_latch_wdog, "WDOG", 3)):
        hal, board, host = _session()
        make(board, hal, host)
        hal.take()
        _latch_estop(board, hal, host)
        assert len(events(hal.take(), "ESTOP")) == 1      # the byte confirmed
        st = host.answer(seq, "STAT")[2]
        assert st[2] == "ESTOP" and st[6] == first, st
        _latch_estop(board, hal, host)                      # a second e-stop keeps it too
        assert host.answer(seq + 1, "STAT")[2][6] == first
        hal2, board2, boot = _reset(hal)
        host2 = Host(hal2, board2)
        host2.hello(1, 4242, 2)
        assert host2.answer(2, "STAT")[2][2::4] == ["ESTOP", first]
        host2.answer(3, "CLR")
        assert host2.answer(4, "STAT")[2][2::4] == ["IDLE", "-"]


def test_an_estop_byte_that_came_while_the_board_booted_latches():
    """docs/protocol.md §2: a byte in the receiver when the firmware starts (it came
    after the UART was opened, before BOOT) is the first the board reads: ESTOP. What
    came before the receiver was on is lost; BOOT's state tells the host to send again."""
    hal = FakeHal()
    hal.send(b"\x98")
    board = arm.Board(hal, config)
    boot = hal.take()
    assert boot[0][1:] == ("BOOT", ["arm3r", "0.1.0", "2", "IDLE"])   # sent before it read anything
    board.poll()
    assert board.state == "ESTOP" and len(events(hal.take(), "ESTOP")) == 1


def test_done_id_and_session_persist_across_reset():
    hal, board, host = _session(555, epoch=3)
    host.answer(2, "W", 31, 100, 1100, -1000, 0)
    run(board, hal, 200)
    assert board.done == 31
    assert hal.persist == b"AB2 555 3 1 31 - -"
    hal2, board2, boot = _reset(hal)
    host2 = Host(hal2, board2, epoch=3)
    assert host2.answer(2, "W", 32, 100, 1200, -1000, 0)[2][1:3] == ["10", "NOSESSION"]
    assert host2.hello(1, 555, 3)[2][-3:] == ["31", "-", "IDLE"]   # the copy: answered, not opened
    assert host2.answer(3, "W", 32, 100, 1200, -1000, 0)[2][1:3] == ["10", "NOSESSION"]
    assert host2.hello(1, 555, 4)[2][-3:] == ["31", "-", "IDLE"]   # resync
    assert host2.answer(2, "W", 32, 100, 1200, -1000, 0)[1] == "OK"
    hal3, board3, boot = _reset(hal)
    assert Host(hal3, board3).hello(1, 556, 4)[2][-3:] == ["-", "-", "IDLE"]


def test_unreadable_persist_is_power_on():
    for mem in (b"", b"\xff\x00junk", b"AB1 555 31", b"AB2 555 3 1 31 - ", b"AB2 x 3 1 31 - -",
                b"AB2 555 3 1 31 HALT -", b"AB2 555 1073741824 1 31 - -"):
        assert link.parse_persist(mem) is None, mem
        hal = FakeHal(persist=mem)
        board = arm.Board(hal, config)
        s = board.link.session
        assert (s.session, s.epoch, board.done, board.state) == (0, 0, -1, "IDLE")
    assert link.parse_persist(b"AB2 9 8 7 - WDOG -") == (9, 8, 7, -1, "WDOG", "-", None)
    # a board's own token rides as an eighth field; a ninth is not a record
    assert link.parse_persist(b"AB2 9 8 7 - WDOG - 1,2,3") == (9, 8, 7, -1, "WDOG", "-", "1,2,3")
    assert link.parse_persist(b"AB2 9 8 7 - WDOG - 1,2,3 x") is None


class _Keeping(arm.Board):
    """A board with persisted state of its own (as the MASR actuator's position)."""

    seen = "unset"

    def persist_extra(self):
        return "42,-7"

    def restore(self, token):
        self.seen = token


def test_a_boards_own_state_is_persisted_and_restored():
    hal = FakeHal()
    board = _Keeping(hal, config)
    assert board.seen is None                      # power on: nothing to restore
    board.link.save()
    assert hal.persist.split()[-1] == b"42,-7"
    again = _Keeping(FakeHal(persist=hal.persist), config)
    assert again.seen == "42,-7"
    assert again.link.session.session == board.link.session.session


# ---------------------------------------------------------------- watchdog

def _running(wdog_ms=300):
    hal, board, host = _session()
    host.answer(2, "WDOG", wdog_ms)
    host.answer(3, "W", 1, 5000, 2000, -1000, 0)
    hal.take()
    return hal, board, host


def _keep_sending(board, hal, line_for, ms=1000):
    for i in range(ms // 100):
        hal.send(line_for(i))
        run(board, hal, 100)


def test_watchdog_not_fed_by_seq_errors_crc_failures_or_refusals():
    kinds = (
        lambda host, i: proto.encode(900 + i, "PING", (), host.epoch),        # ER SEQ, valid CRC
        lambda host, i: proto.encode(4, "PING", (), host.epoch + 1),          # ER CRC
        lambda host, i: proto.encode(4 + i, "W", (2, 100, -5, -1000, 0), host.epoch),  # ER RANGE
        lambda host, i: proto.encode(4 + i, "JUMP", (), host.epoch),          # ER VERB
    )
    for make in kinds:
        hal, board, host = _running()
        _keep_sending(board, hal, lambda i: make(host, i))
        lines = hal.take()
        assert board.state == "WDOG", lines
        assert replies(lines, "OK") == [] and len(replies(lines, "ER")) >= 3
        assert len(events(lines, "WDOG")) == 1


def test_watchdog_fed_by_ping_and_replayed_ok():
    hal, board, host = _running()
    _keep_sending(board, hal, lambda i: proto.encode(4 + i, "PING", (), host.epoch))
    assert board.state == "RUN"
    hal, board, host = _running()                      # a retransmitted W: replayed OK
    _keep_sending(board, hal, lambda i: proto.encode(3, "W", (1, 5000, 2000, -1000, 0), host.epoch))
    assert board.state == "RUN" and board.traj.active_id == 1
    hal2, board2, host2 = _session()
    run(board2, hal2, 3000)                            # idle: no watchdog
    assert board2.state == "IDLE"
