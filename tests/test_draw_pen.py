"""The pen-lift servo end to end: a drawing plan's pen flags go down as modal
PEN lines, the emulated board moves its pen servo at the segment boundaries
(after a settle dwell), and a board without the servo draws with pen-up moves
only marked; --pen on refuses such a board. The Cartesian mode (X lines solved
by the board's own IK) is at the end."""
from __future__ import annotations

import numpy as np
import pytest

from armbridge.draw.build import build
from armbridge.draw.sources import text_lines
from armbridge.emulator.simhal import SimHal
from armbridge.executor.run import RunFailed, run_plan
from armbridge.robots import get_robot

SETTLE_S = 0.150  # firmware/esp32/config.py PEN_SETTLE_MS
TICK_S = 0.010  # the firmware's control period: DONE comes at the tick after a segment's (unrounded) end


def _plan(text: str = "IO"):
    return build(text_lines(text), get_robot("arm3r"), name=text, source=f"text {text!r}", size=0.05,
                 speed=0.03).plan


def test_the_pen_servo_follows_the_plans_flags(ports, tmp_path):
    plan = _plan()
    s = run_plan(plan, "emu:esp32?speed=0", tmp_path / "r.rrd", progress=False)
    assert s.completed and s.pen == "servo"
    emu = ports[0].emulator
    hal = emu.hal
    # one PEN 0 probe at the start, one lift at the end, and a down and an up per stroke
    strokes = int(np.sum(np.diff(np.concatenate([[0], plan.pen])) == 1))
    assert strokes == 2
    downs = [t for t, d in hal.pen_log if d]
    assert len(downs) == strokes and len(hal.pen_log) == 2 * strokes, hal.pen_log  # the PEN 0 probe: pen already up
    assert hal.pen_log[-1][1] is False
    # just before the end of every waypoint the pen is where the plan says (at the
    # end, in the same tick, the next waypoint may already have moved it)
    for ms, wid, _ in emu.executed:
        assert hal.pen_down_at((ms - 1) / 1000.0) == bool(plan.pen[wid]), (wid, ms)
    # a pen-down segment does not move before the pen touches: it dwells the settle time (the
    # DONE before it may come up to a tick after that segment's end, which anchors this one)
    done = {wid: ms / 1000.0 for ms, wid, _ in emu.executed}
    for wid in np.flatnonzero(np.diff(np.concatenate([[0], plan.pen])) == 1):
        assert done[wid] - done[wid - 1] >= plan.durations[wid] + SETTLE_S - TICK_S - 1e-6


def test_without_a_pen_servo_pen_up_is_only_marked(ports, tmp_path, monkeypatch):
    monkeypatch.setattr(SimHal, "has_pen", False)
    plan = _plan("I")
    s = run_plan(plan, "emu:esp32?speed=0", tmp_path / "r.rrd", progress=False)
    assert s.completed and s.pen == "marked" and s.drawing is not None
    assert ports[0].emulator.hal.pen_log == []
    with pytest.raises(RunFailed, match="no pen-lift servo"):
        run_plan(plan, "emu:esp32?speed=0", tmp_path / "r2.rrd", progress=False, pen="on")


def test_pen_off_sends_no_pen_line(ports, tmp_path):
    s = run_plan(_plan("I"), "emu:esp32?speed=0", tmp_path / "r.rrd", progress=False, pen="off")
    assert s.completed and s.pen == "marked"
    assert ports[0].emulator.hal.pen_log == []


def test_pen_state_survives_a_damaged_link_and_a_board_reset(ports, tmp_path):
    """Resyncs (line damage) and a reset mid-drawing: the host says PEN again before
    it resends, so every waypoint still ends with the pen where the plan says."""
    plan = _plan()
    url = "emu:esp32?speed=0&drop=0.01&corrupt=0.01&seed=5&reset_at=2.0"
    s = run_plan(plan, url, tmp_path / "r.rrd", progress=False)
    assert s.completed and s.pen == "servo" and s.resyncs >= 1, s.to_dict()
    emu = ports[0].emulator
    ids = [wid for _, wid, _ in emu.executed]
    assert ids == list(range(plan.k))  # each once, in order
    for ms, wid, _ in emu.executed:
        assert emu.hal.pen_down_at((ms - 1) / 1000.0) == bool(plan.pen[wid]), (wid, ms)
