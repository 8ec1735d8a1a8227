"""The numbers of a run's `Summary` (executor/summary.py), from the client's records and the telemetry:
tracking against the set point and against the plan's piecewise-linear path, settle times on a board
with a dead band, the measured duration less the time held, and the goal check.

Pure: numpy in, numbers out; the run (executor/run.py) collects, this sums up.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from armbridge.executor.summary import JointSettle, JointTracking, Summary
from armbridge.plans.format import Plan


def setup_steps(plan: Plan) -> int:
    """How many of the plan's waypoints are set-up, not plan: the actions a MASR run with
    --home puts ahead of the plan's own (executor/masr.py masr_commands: HOME, a ROT per
    joint to its start angle, the MV to the start d; provenance masr_plan.setup); 0 for any
    other plan."""
    prov = plan.provenance if isinstance(plan.provenance, dict) else {}
    masr = prov.get("masr_plan")
    return int(masr.get("setup", 0)) if isinstance(masr, dict) else 0


def _tracking(err: np.ndarray, names: list[str]) -> dict[str, JointTracking]:
    out = {}
    for j, name in enumerate(names):
        e = err[:, j] if err.size else np.zeros(0)
        if e.size:
            out[name] = JointTracking(float(np.sqrt(np.mean(e**2))), float(np.max(np.abs(e))), int(e.size))
        else:
            out[name] = JointTracking()
    return out


def plan_error(plan: Plan, t: np.ndarray, q: np.ndarray, seg: np.ndarray, seg_start: dict[int, float],
               first: int = 1) -> np.ndarray:
    """q minus the plan's piecewise-linear path, for samples in segments >= `first` (>= 1)
    whose start on the board's clock is known; rows of other samples are dropped.

    seg[s]: the plan index of the segment active at sample s. seg_start[i]: board
    time at which segment i began (the DONE of waypoint i-1, else the START of i;
    both are stamped at the control tick, so the anchor is within one control
    period of the true start). Within segment i the plan moves linearly from
    q[i-1] to q[i] over durations[i] and then holds q[i] (a segment the board
    stretched shows as error).
    """
    rows = []
    for s in range(len(t)):
        i = int(seg[s])
        if i < max(1, first) or i >= plan.k or i not in seg_start:
            continue
        f = min(1.0, max(0.0, (t[s] - seg_start[i]) / plan.durations[i]))
        want = plan.q[i - 1] + f * (plan.q[i] - plan.q[i - 1])
        rows.append(q[s] - want)
    return np.array(rows).reshape(-1, plan.n)


def settle_table(t: np.ndarray, q: np.ndarray, plan_q: np.ndarray, done_t: dict[int, float],
                 band: np.ndarray, end_t: float) -> np.ndarray:
    """(k, n): how long after waypoint i's DONE joint j's measured angle took to stay within
    `band` of the waypoint's value (s); nan where waypoint i does not move joint j or its DONE
    was not seen, inf where the joint never settled (the board's dead band and a sensor count,
    executor/settle.py: the P controller of the soft-arm paper, eq. 24, drives nothing inside
    the dead band, so that is where a joint rests).

    t, q: the telemetry (board time, measured q (m, n)); plan_q (k, n); done_t: plan
    index -> board time of its DONE; end_t: the run's last board time. Only waypoints
    that move the joint count (the first, and any whose value differs from the one
    before it by a milli-unit or more): a repeated value is a hold that extends the
    window. The window of waypoint i is from its DONE to the start of the joint's next
    move (the DONE of the waypoint before it), or end_t after the last move. Settled:
    the window's last sample is within the band; the settle time is from the DONE to
    the first sample after the last one outside it (0 when none was). A window holding
    no sample (the next move began at once) is judged by the last sample before its end.
    """
    t = np.asarray(t, float)
    q = np.asarray(q, float).reshape(len(t), -1)
    plan_q = np.asarray(plan_q, float)
    k, n = plan_q.shape
    out = np.full((k, n), np.nan)
    for j in range(n):
        moves = [i for i in range(k) if i == 0 or abs(plan_q[i, j] - plan_q[i - 1, j]) >= 5e-4]
        for m, i in enumerate(moves):
            if i not in done_t:
                continue
            a = done_t[i]
            nxt = moves[m + 1] if m + 1 < len(moves) else None
            b = done_t.get(nxt - 1, end_t) if nxt is not None else end_t
            inside = (t >= a) & (t <= b)
            if not inside.any():
                before = np.nonzero(t <= b)[0]
                inside = np.zeros(len(t), bool)
                if before.size:
                    inside[before[-1]] = True
            idx = np.nonzero(inside)[0]
            if idx.size == 0:
                out[i, j] = np.inf
                continue
            ok = np.abs(q[idx, j] - plan_q[i, j]) <= band[j] + 1e-9
            if not ok[-1]:
                out[i, j] = np.inf
                continue
            bad = np.nonzero(~ok)[0]
            out[i, j] = 0.0 if bad.size == 0 else max(0.0, float(t[idx[bad[-1] + 1]] - a))
    return out


def settle_times(t: np.ndarray, q: np.ndarray, plan_q: np.ndarray, done_t: dict[int, float],
                 band: np.ndarray, end_t: float) -> list[JointSettle]:
    """Per joint, the settle times of `settle_table` (same arguments): mean and max over the
    waypoints that settled, how many waypoints moved the joint, how many never settled."""
    table = settle_table(t, q, plan_q, done_t, band, end_t)
    out = []
    for col in table.T:
        times = col[np.isfinite(col)]
        unsettled = int(np.sum(np.isinf(col)))
        out.append(JointSettle(float(np.mean(times)) if times.size else math.nan,
                               float(np.max(times)) if times.size else math.nan, int(times.size) + unsettled,
                               unsettled))
    return out


def fill(summary: Summary, client, plan: Plan, samples, names: list[str],
         held: Sequence[tuple[float, float]] = ()) -> None:
    """The link statistics, the board-time duration and the tracking errors of a
    finished (or stopped) run, from the client and the telemetry samples. `held`: the
    board-time intervals the board was held, left out of the measured duration."""
    s = client.stats
    summary.waypoints_done = client.done_index + 1
    summary.waypoints_sent = s.waypoints_sent
    summary.waypoints_acked = s.waypoints_acked
    summary.waypoints_retransmitted = s.waypoints_retransmitted
    summary.lines_sent = s.lines_sent
    summary.line_errors = s.line_errors
    summary.board_lines_lost = s.board_lines_lost
    summary.timeouts = s.timeouts
    summary.seq_errors = s.seq_errors
    summary.resyncs = s.resyncs
    summary.slow_events = s.slow_events
    summary.spurious_timeouts = s.spurious_timeouts
    summary.longest_quiet_s = s.longest_quiet_s
    emu = getattr(getattr(client, "port", None), "emulator", None)
    if emu is not None and emu.speed > 0:
        summary.emulator_pace = emu.pace()
    summary.telemetry_samples = len(samples)
    summary.joint_units = dict(zip(names, getattr(plan.robot, "joint_units", ("rad",) * len(names))))
    # Planned against executed, like with like: a MASR run's setup (HOME, the joints to the
    # plan's start, the MV to its start d: no part of the plan) is reported apart, and the
    # duration and the tracking are the plan's own steps (waypoints setup .. k-1).
    setup = setup_steps(plan)
    summary.setup_steps = setup
    done, start = client.done_times, client.start_times
    if setup and 0 in start and setup - 1 in done:
        summary.setup_duration_s = float(done[setup - 1] - start[0])
    # Duration on the board's clock: START of the plan's first step (the DONE of the setup's
    # last: the board goes straight on) to DONE of the last one.
    last = plan.k - 1
    t0 = done.get(setup - 1) if setup else None
    if t0 is None:
        t0 = start.get(setup)
    later = [i for i in done if i >= setup]
    if t0 is None and later:  # its START was lost: back from the first DONE seen
        i = min(later)
        t0 = done[i] - float(np.sum(plan.durations[setup: i + 1]))
    t1 = done.get(last) if client.done_index >= last else None
    if t0 is not None and t1 is not None:
        summary.measured_duration_s = float(t1 - t0) - held_between(held, t0, t1)
    run = [x for x in samples if x[1] == "RUN" and x[4] >= setup]
    if run:
        t = np.array([x[0] for x in run])
        q = np.stack([x[2] for x in run])
        tg = np.stack([x[3] for x in run])
        seg = np.array([x[4] for x in run])
        summary.tracking_setpoint = _tracking(tg - q, names)
        # Segment i begins at the DONE of i-1 when the board went straight on
        # (same control tick as the START of i), at the START of i after a pause.
        seg_start = dict(client.start_times)
        for i, td in client.done_times.items():
            ts = client.start_times.get(i + 1)
            if ts is None or ts - td <= 0.011:
                seg_start[i + 1] = td
        if held:  # the plan's clock stood still while the board was held: both times on it
            t = t - np.array([_held_before(held, x) for x in t])
            seg_start = {i: ts - _held_before(held, ts) for i, ts in seg_start.items()}
        summary.tracking_plan = _tracking(plan_error(plan, t, q, seg, seg_start, first=setup), names)
    else:
        summary.tracking_setpoint = _tracking(np.zeros((0, len(names))), names)
        summary.tracking_plan = _tracking(np.zeros((0, len(names))), names)


def _held_before(held: Sequence[tuple[float, float]], t: float) -> float:
    """Board time held before `t`."""
    return float(sum(max(0.0, min(b, t) - a) for a, b in held))


def held_between(held: Sequence[tuple[float, float]], t0: float, t1: float) -> float:
    """Board time held between `t0` and `t1` (`held`: the intervals the board was held)."""
    return float(sum(max(0.0, min(b, t1) - max(a, t0)) for a, b in held))


def fill_settle(summary: Summary, client, plan: Plan, samples, names: list[str], band: np.ndarray,
                source: str) -> None:
    """The settle times of a run on a board with a dead band (`settle_times`), from the
    client's DONE times and the telemetry samples; `band` (rad per joint) and where it
    came from (`source`: "board" or "default") go beside them."""
    summary.settle_tolerance = {name: float(b) for name, b in zip(names, band)}
    summary.settle_tolerance_source = source
    if not samples:
        summary.settle = {name: JointSettle() for name in names}
        return
    t = np.array([x[0] for x in samples])
    q = np.stack([x[2] for x in samples])
    st = settle_times(t, q, plan.q, dict(client.done_times), np.asarray(band, float), float(t[-1]))
    summary.settle = dict(zip(names, st))


def goal_check(what: str, distance_m: float, tolerance_m: float, angle_rad: float | None = None,
               angle_tolerance_rad: float | None = None) -> dict[str, Any]:
    """The summary's goal section: where the arm ended against the plan's goal (a tip point, or
    a pose with its angle), reached when within every tolerance (a NaN distance: not reached)."""
    reached = bool(distance_m <= tolerance_m)
    if angle_rad is not None and angle_tolerance_rad is not None:
        reached = reached and bool(abs(angle_rad) <= angle_tolerance_rad)
    return {"what": what, "distance_mm": distance_m * 1000.0, "tolerance_mm": tolerance_m * 1000.0,
            "angle_deg": None if angle_rad is None else math.degrees(abs(angle_rad)),
            "angle_tolerance_deg": None if angle_tolerance_rad is None else math.degrees(angle_tolerance_rad),
            "reached": reached}
