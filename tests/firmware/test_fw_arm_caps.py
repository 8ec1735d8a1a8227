"""The arm's capabilities on a fake HAL: the pen-lift servo (PEN, modal, its
dwell and event), the positional rig (write_positions, ZERO holds, CAL) and
the Cartesian verbs' handling (X/XY with an injected solver: the board IK
itself is tests/test_board_ik.py, end to end tests/test_draw_run.py)."""

import arm
import config
import protodef
from fwutil import FakeHal, Host, events, replies, run


class PenHal(FakeHal):
    has_pen = True

    def __init__(self, **kw) -> None:
        FakeHal.__init__(self, **kw)
        self.pen_log = []     # (ms, down)

    def write_pen(self, down) -> None:
        self.pen_log.append((self.t, down))


class PositionalHal(PenHal):
    """Positional servos: each joint goes where it is sent (no lag: the board's
    logic, not the servo, is under test)."""
    POSITIONAL = True

    def __init__(self, **kw) -> None:
        PenHal.__init__(self, **kw)
        self.sent = None
        self.cal = {}
        self.leads = []   # (joint 0-based, mrad) of every DBAND

    def write_positions(self, q) -> None:
        self.on = True
        self.sent = list(q)
        for j in range(len(q)):
            self.q[j] = q[j]

    def write_outputs(self, efforts) -> None:
        raise AssertionError("a positional rig gets positions, not efforts")

    def set_calibration(self, j, us_a, a, us_b, b) -> None:
        self.cal[j] = (us_a, a, us_b, b)

    def set_lead(self, j, mrad) -> None:
        self.leads.append((j, mrad))


def _session(hal):
    board = arm.Board(hal, config)
    host = Host(hal, board)
    assert host.hello(1, 4242)[1] == "OK"
    run(board, hal, 1)
    hal.take()
    return board, host


def _code(ans):
    return int(ans[2][1])


def test_pen_is_refused_without_a_pen_servo():
    hal = FakeHal()
    board, host = _session(hal)
    ans = host.answer(2, "PEN", 1)
    assert ans[1] == "ER" and _code(ans) == protodef.VERB
    # the effort rig has no positional servo: CAL is its pots' calibration (arm_cal.py), slope within 0.8..1.25
    ans = host.answer(3, "CAL", 1, 1000, 0, 2000, 2000)
    assert ans[1] == "ER" and _code(ans) == protodef.RANGE
    assert host.answer(4, "CAL", 1, 1000, 1071, 2000, 2071)[1] == "OK"   # the identity: mid 1571 +- 500


def test_pen_at_rest_moves_now_and_reports_when_settled():
    hal = PenHal()
    board, host = _session(hal)
    assert host.answer(2, "PEN", 1)[1] == "OK"
    assert hal.pen_log and hal.pen_log[-1][1] is True
    t0 = hal.pen_log[-1][0]
    run(board, hal, config.PEN_SETTLE_MS + 20)
    pen = [ln for ln in hal.take() if ln[1] == "EV" and ln[2][1] == "PEN"]
    assert len(pen) == 1 and pen[0][2][2] == "1"
    settled = int(pen[0][2][0])
    assert config.PEN_SETTLE_MS <= settled - t0 <= config.PEN_SETTLE_MS + 2 * config.PERIOD_MS


def test_pen_rides_with_the_queue_and_dwells_at_a_change():
    hal = PenHal()
    board, host = _session(hal)
    q0 = list(hal.q)
    w = lambda seq, wid, dq: host.answer(seq, "W", wid, 100, int(round((q0[0] + dq) * 1000)),
                                         int(round(q0[1] * 1000)), int(round(q0[2] * 1000)))
    assert w(2, 1, 0.05)[1] == "OK"          # pen up (the default)
    assert host.answer(3, "PEN", 1)[1] == "OK"
    assert hal.pen_log == []                  # busy: the change waits for its waypoint
    assert w(4, 2, 0.10)[1] == "OK"          # drawn pen down
    assert host.answer(5, "PEN", 0)[1] == "OK"
    assert w(6, 3, 0.15)[1] == "OK"
    run(board, hal, 1200)
    lines = hal.take()
    done = {}
    for ln in lines:
        if ln[1] == "EV" and ln[2][1] == "DONE":
            done[int(ln[2][2])] = int(ln[2][0])
    assert [d for _, d in hal.pen_log] == [True, False]
    t_down, t_up = hal.pen_log[0][0], hal.pen_log[1][0]
    # the pen goes down as waypoint 2 begins (1 is done), and 2 takes its 100 ms
    # of motion after the settle time
    assert done[1] <= t_down <= done[1] + config.PERIOD_MS
    assert done[2] - done[1] >= 100 + config.PEN_SETTLE_MS
    assert done[2] <= t_up <= done[2] + config.PERIOD_MS
    assert done[3] - done[2] >= 100 + config.PEN_SETTLE_MS
    assert [e[1] for e in events(lines, "PEN")] == ["1", "0"]


def test_a_stop_resets_the_modal_pen_to_where_the_pen_is():
    hal = PenHal()
    board, host = _session(hal)
    assert host.answer(2, "HOLD")[1] == "OK"
    q = [int(round(x * 1000)) for x in hal.q]
    assert host.answer(3, "W", 1, 100, *q)[1] == "OK"
    assert host.answer(4, "PEN", 1)[1] == "OK"
    board.estop()
    assert board.pen.next == board.pen.state == 0
    assert host.answer(5, "PEN", 1)[1] == "ER"               # latched: a motion verb


def test_positional_rig_writes_the_set_point():
    hal = PositionalHal()
    board, host = _session(hal)
    q = [int(round(x * 1000)) for x in hal.q]
    q[0] += 200
    assert host.answer(2, "W", 1, 200, *q)[1] == "OK"
    run(board, hal, 300)
    assert abs(hal.sent[0] * 1000 - q[0]) < 1e-6
    assert [e[0] for e in events(hal.take())] == ["START", "DONE"]
    assert board.u == [0.0, 0.0, 0.0]                          # no PID on this rig


def test_positional_rig_holds_where_sent_on_watchdog():
    hal = PositionalHal()
    board, host = _session(hal)
    q = [int(round(x * 1000)) for x in hal.q]
    q[0] += 800
    assert host.answer(2, "W", 1, 2000, *q)[1] == "OK"
    run(board, hal, config.WDOG_MS + 50)                       # silence: the watchdog fires
    assert board.state == "WDOG"
    held = list(hal.sent)
    run(board, hal, 100)
    assert hal.sent == held and hal.on


def test_cal_on_the_positional_rig():
    hal = PositionalHal()
    board, host = _session(hal)
    assert host.answer(2, "CAL", 2, 600, -3000, 2400, 500)[1] == "OK"
    assert hal.cal[1] == (600, -3000, 2400, 500)
    for seq, args in ((3, (2, 1500, 0, 1500, 100)), (4, (2, 1000, 7, 2000, 7)),
                      (5, (2, 2000, 0, 1000, 100))):
        ans = host.answer(seq, "CAL", *args)
        assert ans[1] == "ER" and _code(ans) == protodef.RANGE, args
    assert hal.cal == {1: (600, -3000, 2400, 500)}


class _Solver:
    """Stands in for ik3r.BoardIK: a fixed answer, None outside x > 0."""

    def __init__(self, q) -> None:
        self.q = q
        self.calls = []

    def solve(self, x, y, theta):
        self.calls.append((x, y, theta))
        return None if x <= 0 else list(self.q)


def test_x_and_xy_queue_the_solved_joints_and_refuse_reach():
    hal = FakeHal()
    assert "X" not in arm.Board(hal, config).verbs  # no weights file: VERB
    solver = _Solver([1.2, -1.1, 0.1])
    load = arm._load_ik
    arm._load_ik = lambda hal, cfg: solver
    try:
        board = arm.Board(hal, config)
    finally:
        arm._load_ik = load
    host = Host(hal, board)
    assert host.hello(1, 4242)[1] == "OK"
    assert host.answer(2, "X", 5, 300, 80000, 190000, -250)[1] == "OK"
    assert solver.calls[-1] == (0.08, 0.19, -0.25)
    assert host.answer(3, "XY", 6, 300, 70000, 200000)[1] == "OK"
    assert solver.calls[-1] == (0.07, 0.2, config.IK_THETA_MRAD / 1000.0)
    ans = host.answer(4, "XY", 7, 300, -1000, 200000)
    assert ans[1] == "ER" and _code(ans) == protodef.REACH and ans[2][2] == "REACH"
    run(board, hal, 800)
    done = [ln for ln in replies(hal.take(), "EV") if ln[2][1] == "DONE"]
    assert done[-1][2][2] == "6"
    assert abs(hal.q[0] - 1.2) < 0.03


def test_dband_is_the_servos_hysteresis_on_the_positional_rig_only():
    """DBAND j mrad: the pca9685 rig's servo lead (half of it, servos.py), kept by CALID's
    cal_text as D<j>=mrad; refused RANGE above LEAD_MAX_MRAD; VERB on the effort rig."""
    hal = FakeHal()
    board, host = _session(hal)
    ans = host.answer(2, "DBAND", 1, 10)
    assert ans[1] == "ER" and _code(ans) == protodef.VERB
    hal = PositionalHal()
    board, host = _session(hal)
    assert host.answer(2, "DBAND", 2, 16)[1] == "OK"
    assert hal.leads[-1] == (1, 16)
    ans = host.answer(3, "DBAND", 2, 101)
    assert ans[1] == "ER" and _code(ans) == protodef.RANGE
    assert "D2=16" in board.cal.cal_text()
    board.cal.cal_apply(["D3=7"])
    assert hal.leads[-1] == (2, 7)
