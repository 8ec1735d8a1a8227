"""The first line since boot (link.BoardLink._joining, docs/protocol.md section 8).

The host never waits for BOOT, so the board's receiver may come up in the middle
of a HELLO and the link get its tail: dropped without ER. A whole first line runs
(and gets its answer, ER too); a damaged line that starts later, or comes after
the first line, is answered ER as every line is. Both boards on firmware/common's
link: the 3R arm and the MASR actuator. FakeHal's clock counts whole ms, so one ms
on is past the two byte times (174 us at 115200 baud) the rule allows."""

import arm
import config
import ma
import proto
import protodef as P
from fwma import FakeMaHal, load_config
from fwutil import FakeHal, Host, replies, run

HELLO = proto.encode(1, "HELLO", [P.PROTOCOL_VERSION, 4242, 1])
CUTS = (1, 2, 9, len(HELLO) - 12, len(HELLO) - 1)   # the last: the tail is its LF alone


def _arm(**kw):
    """A freshly booted arm -> (hal, board, host); BOOT taken."""
    hal = FakeHal(**kw)
    board = arm.Board(hal, config)
    assert [ln[1] for ln in hal.take()] == ["BOOT"]
    return hal, board, Host(hal, board)


def _connects(hal, board, host, sid=4242):
    """The host's next HELLO is answered OK, then a PING."""
    assert host.hello(2, sid)[1] == "OK"
    assert host.answer(3, "PING")[1] == "OK"


def _er(lines) -> list:
    return [ln[2][:3] for ln in replies(lines) if ln[1] == "ER"]


def test_the_tail_of_a_hello_at_boot_is_dropped_silently():
    for cut in CUTS:
        hal, board, host = _arm()
        hal.send(HELLO[cut:])
        board.poll()                      # the first poll, at the link's start
        assert replies(hal.take()) == [], cut
        _connects(hal, board, host)


def test_a_tail_over_several_reads_or_waiting_in_the_buffer_is_dropped():
    hal, board, host = _arm()
    hal.send(HELLO[5:12])                 # the receiver came up mid-line: the rest follows
    board.poll()
    hal.send(HELLO[12:])
    run(board, hal, 3)
    assert replies(hal.take()) == []
    _connects(hal, board, host)
    hal, board, host = _arm()
    hal.t += 5                            # the first read comes 5 ms after the link started:
    hal.send(HELLO[7:])                   # the tail came while the board booted
    run(board, hal, 1)
    assert replies(hal.take()) == []
    _connects(hal, board, host)


def test_a_whole_first_line_gets_its_answer():
    hal, board, host = _arm()
    assert host.hello(1, 4242)[1] == "OK"     # HELLO at once: it runs
    hal, board, host = _arm()
    ans = Host(hal, board, 0).answer(1, "W", 1, 100, 0, 0, 0)   # passes its checks: answered,
    assert ans[1] == "ER" and ans[2][:3] == ["1", str(P.NOSESSION), "NOSESSION"], ans   # ER too


def test_a_damaged_line_that_starts_later_is_answered():
    hal, board, host = _arm()
    run(board, hal, 1)                    # a read found nothing one ms after the start
    hal.send(HELLO[9:])
    board.poll()
    assert _er(hal.take()) == [["-", str(P.CRC), "CRC"]]
    _connects(hal, board, host)
    start = (P.TICKS_PERIOD - 500) // 1000   # ticks_us wraps 0.8 ms after the link starts
    hal, board, host = _arm(t0=start)
    run(board, hal, 1)
    hal.send(b"\n")
    board.poll()
    assert _er(hal.take()) == [["-", str(P.PARSE), "PARSE"]]


def test_an_empty_read_within_two_byte_times_leaves_the_window_open():
    """This board reads in pieces: a byte counts as come in time unless a read
    found nothing after the two byte times had passed."""
    hal, board, host = _arm()
    board.poll()                          # nothing yet, at the link's start
    hal.step_plant(1)
    hal.send(HELLO[3:])
    board.poll()
    assert replies(hal.take()) == []
    _connects(hal, board, host)


def test_only_the_first_line_may_be_a_tail():
    hal, board, host = _arm()
    hal.send(HELLO[9:] + b"garbage\n" + HELLO[9:])
    board.poll()
    assert _er(hal.take()) == [["-", str(P.PARSE), "PARSE"], ["-", str(P.CRC), "CRC"]]
    hal, board, host = _arm()
    assert host.hello(1, 4242)[1] == "OK"     # a whole first line ends the window too
    hal.send(HELLO[9:])
    board.poll()
    assert _er(hal.take()) == [["-", str(P.CRC), "CRC"]]
    hal, board, host = _arm()
    hal.send(bytes([P.ESTOP_BYTE]) + HELLO[9:])   # so does the e-stop byte (an item first)
    board.poll()
    lines = hal.take()
    assert board.state == "ESTOP" and _er(lines) == [["-", str(P.CRC), "CRC"]], lines


def test_the_masr_actuator_drops_a_tail_at_boot_too():
    cfg = load_config()
    hal = FakeMaHal(cfg)
    board = ma.Board(hal, cfg)
    host = Host(hal, board)
    hal.send(HELLO[9:])
    board.poll()
    assert [ln[1] for ln in replies(hal.take())] == ["BOOT"]
    assert host.hello(2, 7)[1] == "OK"
    hal.send(HELLO[9:])                   # after the first line: answered
    board.poll()
    assert _er(hal.take()) == [["-", str(P.CRC), "CRC"]]
