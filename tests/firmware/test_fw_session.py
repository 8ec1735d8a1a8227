"""Session rules (session.py's table: HELLO with epochs, sequence numbers,
the replay ring) and board line formatting."""

import proto
import protodef as P
import session as sess


def _opened(seq=1, sid=7, epoch=1):
    s = sess.Session(0, epoch - 1)                    # a board that last saw epoch - 1
    assert s.classify(seq, "HELLO", (2, sid, epoch)) == sess.NEW
    s.accept(seq, sid, epoch)
    return s


def test_no_session_before_hello():
    s = sess.Session()
    assert not s.open
    assert s.classify(0, "W") == sess.NOSESSION
    assert s.classify(5, "CLR") == sess.NOSESSION
    assert s.classify(5, "PING") == sess.FRESH     # read-only verbs answer without a session
    assert s.classify(5, "STAT") == sess.FRESH


def test_hello_wrong_proto_is_refused_before_anything_else():
    s = _opened()
    for v in (1, 3, 65535):
        assert s.classify(9, "HELLO", (v, 7, 5)) == sess.BADPROTO
        assert s.classify(1, "HELLO", (v, 7, 1)) == sess.BADPROTO   # even an exact copy's seq
    assert (s.session, s.epoch, s.hello_seq, s.expect) == (7, 1, 1, 2)


def test_newer_epoch_other_session_is_new_same_session_is_resync():
    s = sess.Session()
    assert s.classify(300, "HELLO", (2, 9, 1)) == sess.NEW
    s.accept(300, 9, 1)
    assert s.open and s.expect == 301 and (s.session, s.epoch, s.hello_seq) == (9, 1, 300)
    assert s.classify(5, "HELLO", (2, 9, 2)) == sess.RESYNC
    assert s.classify(5, "HELLO", (2, 10, 2)) == sess.NEW
    s.accept(65535, 9, 2)
    assert s.expect == 0 and s.classify(0, "W") == sess.EXEC


def test_accept_clears_the_replay_ring():
    s = _opened()
    s.record(2, "OK", [2, 31])
    assert s.classify(2, "W") == sess.REPLAY
    s.accept(3, 7, 2)
    assert s.classify(2, "W") == sess.SEQERR


def test_copy_of_the_opening_hello_is_fresh_and_changes_nothing():
    s = _opened(seq=1, sid=7, epoch=4)
    for seq in range(2, 60):                          # far beyond the ring
        s.record(seq, "OK", [seq, 32])
    assert s.classify(1, "HELLO", (2, 7, 4)) == sess.FRESH
    assert s.expect == 60 and s.epoch == 4


def test_stale_hellos():
    s = _opened(seq=10, sid=7, epoch=4)
    assert s.classify(10, "HELLO", (2, 7, 3)) == sess.STALE     # older epoch
    assert s.classify(10, "HELLO", (2, 8, 4)) == sess.STALE     # same epoch, other session
    assert s.classify(11, "HELLO", (2, 7, 4)) == sess.STALE     # same epoch, other seq
    assert s.classify(10, "HELLO", (2, 8, 3)) == sess.STALE
    assert (s.session, s.epoch, s.hello_seq, s.expect) == (7, 4, 10, 11)


def test_only_the_next_epoch_opens():
    """A HELLO that jumps ahead is STALE: one at EPOCH_MAX would leave no epoch for a
    resync (issue 21); the host then retries with E + 1, which opens."""
    s = _opened(seq=10, sid=7, epoch=4)
    for sid, epoch in ((7, 6), (8, 6), (7, 1000), (8, P.EPOCH_MAX), (7, P.EPOCH_MAX)):
        assert s.classify(11, "HELLO", (2, sid, epoch)) == sess.STALE, (sid, epoch)
    assert s.classify(11, "HELLO", (2, 7, 5)) == sess.RESYNC
    assert s.classify(11, "HELLO", (2, 8, 5)) == sess.NEW
    assert sess.Session().classify(1, "HELLO", (2, 9, 2)) == sess.STALE   # power on: epoch 1 first


def test_persisted_state_after_a_reset_needs_a_newer_epoch():
    s = sess.Session(7, 4, 10)                        # what a reset leaves
    assert not s.open and s.expect == -1
    assert s.classify(11, "W") == sess.NOSESSION
    assert s.classify(10, "HELLO", (2, 7, 4)) == sess.FRESH     # a late copy: answered, not opened
    assert s.classify(12, "HELLO", (2, 7, 4)) == sess.STALE
    assert s.classify(12, "HELLO", (2, 7, 5)) == sess.RESYNC


def test_in_order_exec_and_record_advances():
    s = _opened()
    assert s.classify(2, "W") == sess.EXEC
    s.record(2, "OK", [2, 31])
    assert s.expect == 3
    assert s.classify(3, "W") == sess.EXEC
    s.record(3, "ER", [3, proto.RANGE, "RANGE"])   # an error also advances expect
    assert s.expect == 4


def test_retransmit_is_replayed_not_executed():
    s = _opened()
    s.record(2, "OK", [2, 31])
    s.record(3, "ER", [3, 8, "FULL"])
    assert s.classify(2, "W") == sess.REPLAY
    assert s.replay(2) == ("OK", [2, 31])
    assert s.classify(3, "W") == sess.REPLAY
    assert s.replay(3) == ("ER", [3, 8, "FULL"])


def test_read_only_retransmit_answered_fresh():
    s = _opened()
    s.record(2, "OK", [2, 32, 100])
    for verb in ("STAT", "LIM", "PING"):
        assert s.classify(2, verb) == sess.FRESH
        assert s.classify(1, verb) == sess.FRESH       # behind, never recorded: still fresh


def test_ahead_and_far_behind_are_seq_errors():
    s = _opened(seq=100)
    for seq in range(101, 134):
        s.record(seq, "OK", [seq, 32])
    assert s.expect == 134
    assert s.classify(135, "W") == sess.SEQERR       # ahead
    assert s.classify(134 - 32, "W") == sess.REPLAY  # 32 behind: still in the ring
    assert s.classify(134 - 33, "W") == sess.SEQERR  # further behind
    assert s.classify(134 - 33, "PING") == sess.SEQERR
    assert s.classify(60000, "W") == sess.SEQERR


def test_behind_but_never_accepted_is_seq_error():
    s = _opened(seq=10)
    assert s.classify(9, "W") == sess.SEQERR       # before this epoch's HELLO
    assert s.classify(10, "W") == sess.SEQERR      # the HELLO's own seq: not in the ring


def test_wraparound():
    s = _opened(seq=65534)
    s.record(65535, "OK", [65535, 31])
    assert s.expect == 0
    s.record(0, "OK", [0, 30])
    assert s.classify(65535, "W") == sess.REPLAY
    assert s.classify(0, "W") == sess.REPLAY
    assert s.classify(1, "W") == sess.EXEC


def test_board_lines_count_and_parse():
    s = sess.Session()
    a = s.boot("arm3r", "0.1.0", "IDLE")
    b = s.line("OK", [5, 31])
    c = s.er("-", proto.CRC)
    d = s.er(7, proto.SEQ, 9)
    e = s.ev(123, "DONE", [4, 32])
    f = s.er(8, P.STALE, 3)
    assert proto.decode(a, 192) == (0, "BOOT", ["arm3r", "0.1.0", "2", "IDLE"])
    assert proto.decode(b, 192) == (1, "OK", ["5", "31"])
    assert proto.decode(c, 192) == (2, "ER", ["-", "2", "CRC"])
    assert proto.decode(d, 192) == (3, "ER", ["7", "7", "SEQ", "9"])
    assert proto.decode(e, 192) == (4, "EV", ["123", "DONE", "4", "32"])
    assert proto.decode(f, 192) == (5, "ER", ["8", "11", "STALE", "3"])


def test_board_seq_wraps_and_lines_stay_short():
    s = sess.Session()
    s.bseq = 65535
    s.line("OK", [1, 1])
    assert s.bseq == 0
    line = s.line("T", ["x" * 50] * 10)
    assert len(line) <= proto.MAX_BOARD_LINE
    assert line.endswith(b"\n")
