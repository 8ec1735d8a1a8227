"""PENPOS on a fake HAL (firmware/esp32/arm_pen.py): the pen servo's up and down
widths and the settle dwell at once, a pen at rest moved to its state's new
width, the new settle used by every later pen change, refused while waypoints
are queued or out of range, VERB without a pen servo, and kept by CALID across
a reboot (a bad saved token leaves the defaults). The emulated rigs, the real
MicroPython interpreter and the host's options are tests/test_draw_penpos.py."""

import arm
import config
import protodef
from fwutil import FakeHal, Host, events, run


class WidthHal(FakeHal):
    has_pen = True

    def __init__(self, **kw) -> None:
        FakeHal.__init__(self, **kw)
        self.pen_log = []      # (ms, down)
        self.widths = []       # (ms, up_us, down_us) of every set_pen_widths

    def write_pen(self, down) -> None:
        self.pen_log.append((self.t, down))

    def set_pen_widths(self, up_us, down_us) -> None:
        self.widths.append((self.t, up_us, down_us))


def _session(hal, session=4242):
    board = arm.Board(hal, config)
    host = Host(hal, board)
    assert host.hello(1, session)[1] == "OK"
    run(board, hal, 1)
    hal.take()
    return board, host


def _code(ans):
    return int(ans[2][1])


def test_penpos_sets_the_widths_and_moves_a_pen_at_rest():
    hal = WidthHal()
    board, host = _session(hal)
    assert host.answer(2, "PEN", 1)[1] == "OK"
    run(board, hal, config.PEN_SETTLE_MS + 20)
    hal.take()
    assert host.answer(3, "PENPOS", 1100, 1800, 300)[1] == "OK"
    assert hal.widths[-1][1:] == (1100, 1800)
    assert (board.pen.up_us, board.pen.down_us, board.pen.settle_ms) == (1100, 1800, 300)
    t0 = hal.t
    run(board, hal, 320)
    ev = [ln for ln in hal.take() if ln[1] == "EV" and ln[2][1] == "PEN"]
    assert len(ev) == 1 and ev[0][2][2] == "1"          # the pen moved to its new down width, and settled
    assert 300 <= int(ev[0][2][0]) - t0 <= 300 + 2 * config.PERIOD_MS
    # the same widths again move nothing: no settle, no event
    assert host.answer(4, "PENPOS", 1100, 1800, 300)[1] == "OK"
    run(board, hal, 50)
    assert events(hal.take(), "PEN") == []


def test_the_new_settle_is_the_dwell_of_a_pen_change():
    hal = WidthHal()
    board, host = _session(hal)
    assert host.answer(2, "PENPOS", 1200, 1700, 400)[1] == "OK"
    q0 = list(hal.q)
    w = lambda seq, wid, dq: host.answer(seq, "W", wid, 100, int(round((q0[0] + dq) * 1000)),
                                         int(round(q0[1] * 1000)), int(round(q0[2] * 1000)))
    assert w(3, 1, 0.05)[1] == "OK"
    assert host.answer(4, "PEN", 1)[1] == "OK"
    assert w(5, 2, 0.10)[1] == "OK"
    run(board, hal, 1200)
    done = {}
    for ln in hal.take():
        if ln[1] == "EV" and ln[2][1] == "DONE":
            done[int(ln[2][2])] = int(ln[2][0])
    assert done[2] - done[1] >= 100 + 400


def test_penpos_is_refused_while_queued_out_of_range_and_without_a_pen():
    hal = WidthHal()
    board, host = _session(hal)
    for seq, args in ((2, (499, 1700, 150)), (3, (1200, 2501, 150)), (4, (1200, 1700, 2001))):
        ans = host.answer(seq, "PENPOS", *args)
        assert ans[1] == "ER" and _code(ans) == protodef.RANGE, args
    ans = host.answer(5, "PENPOS", 1200, 1700)
    assert ans[1] == "ER" and _code(ans) == protodef.ARGS
    q = [int(round(x * 1000)) for x in hal.q]
    assert host.answer(6, "W", 1, 500, *q)[1] == "OK"
    ans = host.answer(7, "PENPOS", 1100, 1800, 100)
    assert ans[1] == "ER" and _code(ans) == protodef.RANGE and ans[2][3] == "queued"
    assert hal.widths == [] and board.pen.up_us == config.PEN_UP_US
    hal = FakeHal()
    board, host = _session(hal)
    ans = host.answer(2, "PENPOS", 1200, 1700, 150)
    assert ans[1] == "ER" and _code(ans) == protodef.VERB


def test_calid_keeps_the_pen_across_a_reboot():
    hal = WidthHal()
    board, host = _session(hal)
    assert "P=" not in " ".join(board.cal_text())       # never set: the config's stay the firmware's
    assert host.answer(2, "PENPOS", 1000, 1900, 250)[1] == "OK"
    assert host.answer(3, "CALID", 77)[1] == "OK"
    assert b"P=1000,1900,250" in hal.files["cal.txt"]
    hal.widths = []
    hal.persist = b""                                  # a power cycle: RTC memory lost, the filesystem kept
    board, host = _session(hal, 4243)
    assert (board.pen.up_us, board.pen.down_us, board.pen.settle_ms) == (1000, 1900, 250)
    assert hal.widths and hal.widths[-1][1:] == (1000, 1900)
    ans = host.answer(2, "IDENT")
    assert ans[1] == "OK" and ans[2][-1] == "77"
    # a saved pen out of range (or on a board without a pen) is no calibration: the defaults stay
    hal.files["cal.txt"] = hal.files["cal.txt"].replace(b"P=1000,", b"P=3000,")
    hal.persist = b""
    board, host = _session(hal, 4244)
    assert (board.pen.up_us, board.pen.settle_ms) == (config.PEN_UP_US, config.PEN_SETTLE_MS)
    assert host.answer(2, "IDENT")[2][-1] == "0"
