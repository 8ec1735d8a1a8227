"""What a run did: `Summary` (the table and the `--json` document, docs/formats.md §3).

The numbers it holds are computed from the client's records and the telemetry in
executor/tracking.py; the run (executor/run.py) collects, those sum up.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass
class JointTracking:
    rms: float = math.nan  # the joint's unit (rad, or m)
    max: float = math.nan  # the joint's unit, largest |error|
    samples: int = 0


@dataclass
class JointSettle:
    """A joint's settle times (s of board time): after the DONE of each waypoint that
    ends a move of this joint, until its measured angle stays within the tolerance of
    the waypoint's value (`settle_times`)."""

    mean_s: float = math.nan  # over the waypoints that settled
    max_s: float = math.nan
    waypoints: int = 0  # waypoints that end a move of this joint (DONE seen)
    unsettled: int = 0  # of those: not within the tolerance for good before the joint's next move began


@dataclass
class Summary:
    """What a run did. Errors are in each joint's unit (`joint_units`: rad, or m for a MASR's
    d); times in s of board time."""

    plan: str
    port: str
    rrd: str | None
    robot: str
    waypoints_total: int
    waypoints_done: int = 0
    waypoints_sent: int = 0  # distinct waypoints sent at least once
    waypoints_acked: int = 0  # distinct waypoints the board answered OK
    waypoints_retransmitted: int = 0  # W lines sent beyond the first of each waypoint
    lines_sent: int = 0
    line_errors: int = 0  # damaged lines, both directions (board ER framing + host decode errors)
    board_lines_lost: int = 0  # gaps in the board's line counter
    timeouts: int = 0
    seq_errors: int = 0
    resyncs: int = 0
    slow_events: int = 0
    spurious_timeouts: int = 0  # timeouts a later answer showed to be a late board, not a lost line
    longest_quiet_s: float = 0.0  # the longest the host sent nothing while connected (keep-alives bound it)
    emulator_pace: dict | None = None  # an emulator paced in this process: EmulatedBoard.pace()
    # The plan's goal against where the arm ended (goal_check): what, distance and tolerance, reached.
    # A completed run that missed it exits 3 (docs/formats.md §7).
    goal: dict | None = None
    telemetry_samples: int = 0
    events: int = 0
    planned_duration_s: float = math.nan  # a MASR plan: tau, its own actions' time
    measured_duration_s: float = math.nan  # a MASR plan: its own actions, the setup apart; held time left out
    holds: int = 0  # times the board was held mid-run (HOLD / RESUME: space or p at the terminal)
    held_s: float = 0.0  # board time held, in all (not in measured_duration_s)
    setup_steps: int = 0  # a MASR plan run with --home: the setup's actions ahead of the plan's own
    setup_duration_s: float = math.nan  # ... and their board time (START of the first to DONE of the last)
    joint_units: dict[str, str] = field(default_factory=dict)  # the robot's unit per joint: "rad" or "m"
    tracking_setpoint: dict[str, JointTracking] = field(default_factory=dict)  # q vs board set point, RUN
    tracking_plan: dict[str, JointTracking] = field(default_factory=dict)  # q vs the plan's linear path
    final_state: str | None = None
    stopped_by_user: bool = False
    stopped_by: str | None = None  # SIGINT, SIGTERM or SIGHUP
    estop_sent: bool = False
    estop_confirmed: bool = False  # the board reported ESTOP within estop.ESTOP_CONFIRM_S of the e-stop
    error: str | None = None
    fault: str | None = None  # a latched FAULT: the joint and the reason, from the board's event
    fw: str | None = None
    fw_version: str | None = None
    calibration: dict | None = None  # executor/calcheck.Calibration: the board's chip id and calibration
    drawing: dict | None = None  # a plan with pen flags: plans/drawing.py run_drawing_report
    safety_filter: dict | None = None  # a drawing plan: the CBF filter on what was streamed (prepare.safety_filter)
    pen: str | None = None  # a plan with pen flags: "servo" (PEN lines) or "marked" (no pen-lift servo)
    pen_pos: dict | None = None  # the PENPOS sent (up_us, down_us, settle_ms; executor/penpos.py), None: none
    ik: str = "host"  # "host": joint waypoints (W); "board": Cartesian waypoints (X) solved on the board
    masr: dict | None = None  # a MASR plan: executor/masr.py masr_report (final MA pose error, time vs tau)
    settle: dict[str, JointSettle] = field(default_factory=dict)  # boards with a dead band (settle_times)
    settle_tolerance: dict[str, float] = field(default_factory=dict)  # rad: dead band + a sensor count (settle.py)
    settle_tolerance_source: str | None = None  # "board" (read from it) or "default" (the firmware's config)

    @property
    def completed(self) -> bool:
        return self.waypoints_done == self.waypoints_total and not self.stopped_by_user and self.error is None

    @property
    def goal_missed(self) -> bool:
        """The plan ran to its end and the arm ended outside the plan's goal tolerance."""
        return self.completed and self.goal is not None and not self.goal["reached"]

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["completed"] = self.completed

        def clean(x):
            if isinstance(x, float) and not math.isfinite(x):
                return None
            if isinstance(x, dict):
                return {k: clean(v) for k, v in x.items()}
            if isinstance(x, list):
                return [clean(v) for v in x]
            return x

        return clean(d)

    @property
    def reached_board(self) -> bool:
        """Whether a board answered (HELLO, or a state while connecting): else the summary holds nothing
        but the error, and the run writes neither a table nor a recording."""
        return self.fw is not None or self.final_state is not None

    def table(self):
        """The summary as a rich Table."""
        from rich.table import Table

        t = Table(title=f"run of {self.plan}", show_header=True, header_style="bold")
        t.add_column("", style="bold")
        t.add_column("value", justify="right")
        status = "completed" if self.completed else (f"stopped by {self.stopped_by or 'user'}" if
                                                      self.stopped_by_user else
                                                      f"failed: {self.error}" if self.error else "incomplete")
        t.add_row("status", status)
        if self.final_state:
            estop = (", e-stop confirmed" if self.estop_confirmed else
                     ", e-stop sent, not confirmed" if self.estop_sent else "")
            t.add_row("final board state", self.final_state + estop)
        if self.fault:
            t.add_row("fault", self.fault)
        t.add_row("board", f"{self.fw} {self.fw_version}" if self.fw else "-")
        if self.calibration and self.calibration.get("uid"):
            cal = self.calibration
            t.add_row("calibration", f"{cal['status']} (board {cal['uid']}, id {cal['id']})")
        t.add_row("waypoints done / total", f"{self.waypoints_done} / {self.waypoints_total}")
        t.add_row("waypoints sent / acknowledged", f"{self.waypoints_sent} / {self.waypoints_acked}")
        t.add_row("waypoints retransmitted", str(self.waypoints_retransmitted))
        t.add_row("line errors (damaged lines)", str(self.line_errors))
        t.add_row("board lines lost", str(self.board_lines_lost))
        t.add_row("timeouts (spurious) / ER SEQ", f"{self.timeouts} ({self.spurious_timeouts}) / {self.seq_errors}")
        t.add_row("resyncs", str(self.resyncs))
        t.add_row("longest the host was quiet", f"{_f(self.longest_quiet_s, 3)} s")
        pace = self.emulator_pace
        if pace and pace.get("achieved") is not None and (pace["overruns"] or pace["achieved"] < 0.95 * pace["speed"]):
            t.add_row("emulator", f"could not keep the wall clock: {pace['achieved']:.2f}x of {pace['speed']:g}x, "
                                  f"{pace['overruns']} backlogs given up (the host's clock followed the board's)")
        if self.slow_events:
            t.add_row("segments slowed by the board", str(self.slow_events))
        if self.setup_steps:  # a MASR run's setup: not part of the plan, kept out of the rows below
            t.add_row("setup before the plan (apart)", f"{self.setup_steps} actions, {_f(self.setup_duration_s, 3)} s")
        t.add_row("duration planned / measured", f"{_f(self.planned_duration_s, 3)} s / {_f(self.measured_duration_s, 3)} s")
        if self.holds:
            t.add_row("held (holds / time)", f"{self.holds} / {_f(self.held_s, 3)} s (not in the measured duration)")
        for name, tr in self.tracking_setpoint.items():
            tp = self.tracking_plan.get(name, JointTracking())
            unit = _milli_unit(self.joint_units.get(name, "rad"))
            t.add_row(
                f"tracking {name} (rms / max)",
                f"set point {_mrad(tr.rms)} / {_mrad(tr.max)}; plan {_mrad(tp.rms)} / {_mrad(tp.max)} {unit}",
            )
        for name, st in self.settle.items():
            tol = self.settle_tolerance.get(name, math.nan)
            unit = _milli_unit(self.joint_units.get(name, "rad"))
            t.add_row(f"settle {name} (mean / max, within {_mrad(tol)} {unit})",
                      f"{_f(st.mean_s, 3)} / {_f(st.max_s, 3)} s; {st.unsettled} of {st.waypoints} never settled")
        if self.pen:
            t.add_row("pen", "pen-lift servo (PEN)" if self.pen == "servo" else "no pen-lift servo: pen-up moves marked")
        if self.pen_pos:
            p = self.pen_pos
            t.add_row("pen heights (PENPOS)", f"up {p['up_us']} us, down {p['down_us']} us, settle {p['settle_ms']} ms")
        untouched = (self.drawing or {}).get("pen_untouched")
        if untouched is not None:
            t.add_row("pen on the paper (emulated)", f"{untouched} of {self.drawing['pen_down_samples']} pen-down "
                                                     "samples did not touch it")
        if self.ik == "board":
            t.add_row("IK", "on the board (X waypoints)")
        if self.masr:
            m = self.masr
            t.add_row("MA pose error at the end (dp / dphi)", f"{_f(m.get('dp_mm'), 2)} mm / {_f(m.get('dphi_deg'), 2)} deg")
            t.add_row("action time (run / planned / tau)",
                      f"{_f(m.get('executed_s'), 2)} s / {_f(m.get('planned_s'), 2)} s / {_f(m.get('tau_s'), 2)} s")
            if m.get("margin_mm") is not None:  # the plan's own (plan masr: planning/masr/margin.py)
                t.add_row("planned clearance (least / margin)",
                          f"{_f(m.get('clearance_min_mm'), 2)} mm / {_f(m['margin_mm'], 2)} mm")
            if m.get("dead_reckoning_mm") is not None:  # what no magnet checked (executor/masr.py)
                t.add_row("MA d at the end: dead reckoning",
                          f"{m['dead_reckoning_mm']:.0f} mm since magnet {m['last_magnet']}: within "
                          f"{_f(m.get('d_bound_mm'), 2)} mm if the wheel slipped <= {100 * m['slip_bound']:g} % "
                          "(a slip there is not seen)")
        if self.safety_filter and self.safety_filter.get("moved"):
            f = self.safety_filter
            t.add_row("safety filter (CBF)", f"{f['moved']} waypoints moved into the safe disc (max "
                                             f"{f['max_shift_mm']:.2f} mm; margin {f['margin_m'] * 1000:.1f} mm)")
        if self.drawing:
            d = self.drawing
            t.add_row("drawing error, trace from strokes (mean / max)",
                      f"{_f(d.get('trace_mean_mm'), 2)} / {_f(d.get('trace_max_mm'), 2)} mm")
            t.add_row("drawing error, strokes from trace (mean / max)",
                      f"{_f(d.get('target_mean_mm'), 2)} / {_f(d.get('target_max_mm'), 2)} mm")
            if d.get("characters"):
                t.add_row("time per character", f"{_f(d.get('s_per_character'), 2)} s ({d['characters']} characters)")
        if self.goal:
            g = self.goal
            angle = (f", {_f(g['angle_deg'], 2)} / {_f(g['angle_tolerance_deg'], 2)} deg"
                     if g.get("angle_deg") is not None else "")
            t.add_row(f"goal: {g['what']} off / tolerance",
                      f"{_f(g['distance_mm'], 2)} / {_f(g['tolerance_mm'], 2)} mm{angle}: "
                      + ("reached" if g["reached"] else "MISSED"))
        t.add_row("telemetry samples", str(self.telemetry_samples))
        if self.rrd:
            t.add_row("recording", self.rrd)
        return t


def _f(x: float, nd: int) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{nd}f}"


def _mrad(x: float) -> str:
    """x in milli-units of its joint (mrad for rad, mm for m)."""
    return "-" if x is None or not math.isfinite(x) else f"{x * 1000:.1f}"


MILLI_UNITS = {"rad": "mrad", "m": "mm"}


def _milli_unit(unit: str) -> str:
    """The table's unit for a joint in `unit` (robots/base.py UNITS): its thousandth."""
    return MILLI_UNITS.get(unit, "m" + unit)
