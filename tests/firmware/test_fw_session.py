"""Sequence rules (protocol section 6) and board line formatting."""

import proto
import session as sess


def test_no_session_before_hello():
    s = sess.Session()
    assert not s.open
    assert s.classify(0, "PING") == sess.NOSESSION
    assert s.classify(5, "W") == sess.NOSESSION
    assert s.classify(5, "HELLO") == sess.EXEC


def test_hello_at_any_seq_sets_expect():
    s = sess.Session()
    s.hello(300)
    assert s.open and s.expect == 301
    s.hello(65535)
    assert s.expect == 0
    assert s.classify(0, "W") == sess.EXEC


def test_stale_hello_copy_is_replayed_not_reopened():
    s = sess.Session()
    s.hello(1)
    s.record(1, "OK", [1, 32])
    s.record(2, "OK", [2, 31])
    assert s.classify(1, "HELLO", True) == sess.REPLAY     # same session: a late copy
    assert s.expect == 3
    assert s.classify(1, "HELLO", False) == sess.EXEC      # another session reopens
    assert s.classify(9, "HELLO", True) == sess.EXEC       # resync at a fresh seq


def test_in_order_exec_and_record_advances():
    s = sess.Session()
    s.hello(1)
    assert s.classify(2, "W") == sess.EXEC
    s.record(2, "OK", [2, 31])
    assert s.expect == 3
    assert s.classify(3, "W") == sess.EXEC
    s.record(3, "ER", [3, proto.RANGE, "RANGE"])   # an error also advances expect
    assert s.expect == 4


def test_retransmit_is_replayed_not_executed():
    s = sess.Session()
    s.hello(1)
    s.record(2, "OK", [2, 31])
    s.record(3, "ER", [3, 8, "FULL"])
    assert s.classify(2, "W") == sess.REPLAY
    assert s.replay(2) == ("OK", [2, 31])
    assert s.classify(3, "W") == sess.REPLAY
    assert s.replay(3) == ("ER", [3, 8, "FULL"])


def test_read_only_retransmit_answered_fresh():
    s = sess.Session()
    s.hello(1)
    s.record(2, "OK", [2, 32, 100])
    for verb in ("STAT", "LIM", "PING"):
        assert s.classify(2, verb) == sess.FRESH


def test_ahead_and_far_behind_are_seq_errors():
    s = sess.Session()
    s.hello(100)
    for seq in range(101, 134):
        s.record(seq, "OK", [seq, 32])
    assert s.expect == 134
    assert s.classify(135, "W") == sess.SEQERR       # ahead
    assert s.classify(134 - 32, "W") == sess.REPLAY  # 32 behind: still in the ring
    assert s.classify(134 - 33, "W") == sess.SEQERR  # further behind
    assert s.classify(60000, "W") == sess.SEQERR


def test_behind_but_never_accepted_is_seq_error():
    s = sess.Session()
    s.hello(10)
    assert s.classify(9, "W") == sess.SEQERR       # before this session's HELLO
    assert s.classify(10, "W") == sess.SEQERR      # the HELLO's own seq: not in the ring


def test_wraparound():
    s = sess.Session()
    s.hello(65534)
    s.record(65535, "OK", [65535, 31])
    assert s.expect == 0
    s.record(0, "OK", [0, 30])
    assert s.classify(65535, "W") == sess.REPLAY
    assert s.classify(0, "W") == sess.REPLAY
    assert s.classify(1, "W") == sess.EXEC


def test_board_lines_count_and_parse():
    s = sess.Session()
    a = s.boot("arm3r", "0.1.0", 1)
    b = s.ok(5, 31)
    c = s.er("-", proto.CRC)
    d = s.er(7, proto.SEQ, 9)
    e = s.ev(123, "DONE", [4, 32])
    assert proto.decode(a, 192) == (0, "BOOT", ["arm3r", "0.1.0", "1"])
    assert proto.decode(b, 192) == (1, "OK", ["5", "31"])
    assert proto.decode(c, 192) == (2, "ER", ["-", "2", "CRC"])
    assert proto.decode(d, 192) == (3, "ER", ["7", "7", "SEQ", "9"])
    assert proto.decode(e, 192) == (4, "EV", ["123", "DONE", "4", "32"])


def test_board_seq_wraps_and_lines_stay_short():
    s = sess.Session()
    s.bseq = 65535
    s.ok(1, 1)
    assert s.bseq == 0
    line = s.line("T", ["x" * 50] * 10)
    assert len(line) <= proto.MAX_BOARD_LINE
    assert line.endswith(b"\n")
