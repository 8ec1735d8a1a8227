"""A MASR plan (docs/formats.md §4) as the executor streams it to the MA's board.

A MASR has no servo joints to stream waypoints to: its mobile actuator (MA)
drives along the arm and turns one passive joint at a time. Every step of the
plan's actions becomes one queued board action with its own id, in order:
`move` -> `MV id d` (mm) and `rotate` -> `ROT id j angle` (mrad), the board's
own verbs (docs/protocol.md §3). Between two steps the configuration q =
(theta_1..theta_n, d) changes in one coordinate only, linearly in time, so the
configuration after each step is an ordinary joint-space waypoint: the Plan
built here (one waypoint a step, its duration the step's) is what the rest of
the executor (tracking statistics, the recording, the summary) reads, exactly
as for a servo arm. The board, not the host, times the steps (its speeds are
its limits), so the Plan's durations are the plan's model, eq. (7)-(8).

`masr_report` is the summary's `masr` section: the MA's final pose against
the plan's goal (eq. 9), the executed action time against the plan timed with
the board's ramps (and against tau), and how far the
MA's last position rests on dead reckoning (`dead_reckoning`): the board knows
d from its wheel encoder, re-anchored at every magnet it passes, so after the
plan's last magnet nothing it senses shows a wheel slip; the summary says over
how many mm, and the bound the board's model gives there (firmware/masr_ma/loc.py:
hall window + one count + the slip bound times the travel, + MV's stop
tolerance), which holds only while the wheel slips no more than that bound.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.geometry import wrap_angle
from armbridge.plans import masr as M
from armbridge.plans.format import DURATION_MIN, Plan, make_plan


def _plan(mp: Any) -> Plan:
    """The Plan of a MASR plan (a Plan with its masr section, or planning's MasrPlan view of one)."""
    plan = getattr(mp, "plan", mp)
    if getattr(plan, "masr", None) is None:
        raise ArmbridgeError(f"{getattr(plan, 'source', None) or 'the plan'} is not a MASR plan (no masr section)")
    return plan


def masr_commands(mp, home: bool = False) -> tuple[Plan, list[tuple[str, list[int]]]]:
    """(the Plan of the configuration after each step, the board commands) of a MASR plan
    (its masr section, plans/masr.py).

    home: a `HOME` first (the MA drives to the base and zeroes d): what a board that does
    not know where it is (UNHOMED, after a power on) needs before any MV or ROT; then the
    arm is brought to the plan's start configuration (ROT every joint to its start angle,
    base outward, then MV to the start d), so that the plan's own steps (absolute: MV to d,
    ROT to an angle) run from the configuration they were planned from. The setup's arm
    motion is not the plan's (nothing checked it against the obstacles). Those setup
    commands are counted in the provenance's masr_plan.setup: the executed time starts at
    the last one's DONE."""
    mp = _plan(mp)
    arm = mp.robot
    q = np.array(mp.q[0], dtype=float)
    configs: list[np.ndarray] = []
    durations: list[float] = []
    commands: list[tuple[str, list[int]]] = []

    def setup_step(verb: str, args: list[int], d_to: float, extra_s: float) -> None:
        commands.append((verb, args))
        travel = abs(d_to - q[-1])
        q[-1] = d_to
        configs.append(q.copy())
        durations.append(max(DURATION_MIN, 1.5 * travel / arm.ma_speed + extra_s))  # ramps, approach, a turn

    if home:
        start = float(q[-1])
        setup_step("HOME", [], 0.0, 1.0)
        turn_s = 2.0 * float(np.max(arm.theta_b)) / arm.joint_speed  # whatever angle the board believed
        for j in range(1, arm.n + 1):
            setup_step("ROT", [j, int(round(q[j - 1] * 1000.0))], float(arm.r[j - 1]), turn_s)
        setup_step("MV", [int(round(start * 1000.0))], start, 0.0)
    setup = len(commands)
    for step in M.steps(mp):
        if step["op"] == "move":
            q[-1] = step["d_to"]
            commands.append(("MV", [int(round(step["d_to"] * 1000.0))]))
        elif step["op"] == "rotate":
            j = int(step["joint"])
            q[j - 1] = step["theta_to"]
            commands.append(("ROT", [j, int(round(step["theta_to"] * 1000.0))]))
        else:
            raise ArmbridgeError(f"{mp.source or 'MASR plan'}: unknown step op {step['op']!r}")
        configs.append(q.copy())
        durations.append(max(DURATION_MIN, float(step["duration"])))
    if not commands:
        raise ArmbridgeError(f"{mp.source or 'MASR plan'}: the plan has no steps: nothing to run")
    prov = dict(mp.provenance)
    prov["masr_plan"] = {"tau": M.total_time(mp), "steps": len(commands), "setup": setup,
                         "goal_pose": [float(x) for x in M.goal_pose(mp)]}
    plan = make_plan(arm, np.array(configs), np.array(durations), prov, tool="armbridge run")
    plan.source = mp.source
    return plan, commands


BOARD_OF_MASR = "masr_ma"  # the board that drives a MASR's MA (armbridge.boards: robot masr5)


def board_localisation(fw: str = BOARD_OF_MASR) -> dict[str, float]:
    """The MA board's localisation constants from its firmware config (mm): the hall window
    `w`, the wheel encoder's quantum `q`, the slip bound `s` (a fraction of the wheel's
    travel) and MV's stop tolerance `stop` (loc.py's bound e(T) = w + q + s T)."""
    from armbridge import boards

    cfg = boards.config(fw)
    return {"w": float(cfg.HALL_WINDOW_MM), "q": float(cfg.WHEEL_MM_PER_COUNT), "s": float(cfg.SLIP_MAX),
            "stop": float(cfg.STOP_TOL_MM)}


def board_ramps(fw: str = BOARD_OF_MASR) -> tuple[float, float]:
    """The MA board's ramps from its firmware config: (d in m/s^2, the joints in rad/s^2)."""
    from armbridge import boards

    cfg = boards.config(fw)
    return float(cfg.LOCO_ACCEL_MM_S2) / 1000.0, float(cfg.ROT_ACCEL_MRAD_S2) / 1000.0


def planned_time(mp, fw: str = BOARD_OF_MASR) -> float:
    """The plan's time on the board (s): its steps with the board's ramps (plans/masr.py ramped_time)."""
    return M.ramped_time(_plan(mp), *board_ramps(fw))


def dead_reckoning(mp) -> tuple[int | None, float | None, bool]:
    """(the joint whose magnet the MA passed last, the MA's travel since it in mm, whether the
    plan ends with a move that stops off a magnet), along the plan's own steps: a rotation
    stands on its joint's magnet, a move passes every magnet between its ends (the board
    re-anchors d at each, loc.py) and stops on one when it ends there. (None, None, ...) when
    the plan's steps pass no magnet."""
    mp = _plan(mp)
    r = [float(x) for x in mp.robot.r[: mp.robot.n]]  # magnet j (1-based) at r_j
    last: int | None = None
    since: float | None = None
    off = False
    for st in M.steps(mp):
        if st["op"] == "rotate":
            last, since, off = int(st["joint"]), 0.0, False
            continue
        a, b = float(st["d_from"]), float(st["d_to"])
        lo, hi = min(a, b) - 1e-9, max(a, b) + 1e-9
        passed = [j for j in range(1, len(r) + 1) if lo <= r[j - 1] <= hi]
        if passed:
            last = min(passed, key=lambda j: abs(b - r[j - 1]))  # the one passed last: nearest the end
            since = abs(b - r[last - 1])
        elif since is not None:
            since += abs(b - a)
        off = since is not None and since > 1e-9
    return last, (None if since is None else since * 1000.0), off


def masr_report(mp, final_q: np.ndarray | None, executed_s: float) -> dict[str, Any]:
    """The MA's final pose error (dp in mm, dphi in deg) against the plan's goal, the
    executed action time against the planned time (`planned_s`: the plan's steps with the
    board's ramps, plans/masr.py ramped_time; `time_ratio`) and against eq. (7)'s tau
    (`tau_s`, `tau_ratio`), and the dead reckoning the final d
    rests on (`dead_reckoning`): `dead_reckoning_mm` since the magnet of joint `last_magnet`,
    and `d_bound_mm`, the board's bound there under its slip model (`board_localisation`);
    a slip beyond that model after the last magnet is not seen by the board. A plan `plan masr` made
    also gives the margin it was planned for and its least clearance (`margin_mm`, `clearance_min_mm`)."""
    mp = _plan(mp)
    tau = M.total_time(mp)
    planned = planned_time(mp)
    out: dict[str, Any] = {"tau_s": tau, "planned_s": planned, "executed_s": executed_s,
                           "time_ratio": executed_s / planned if planned > 0 else None,
                           "tau_ratio": executed_s / tau if tau > 0 else None}
    last, since, off = dead_reckoning(mp)
    loc = board_localisation()
    out.update(last_magnet=last, dead_reckoning_mm=since, slip_bound=loc["s"],
               d_bound_mm=None if since is None else
               loc["w"] + loc["q"] + loc["s"] * since + (loc["stop"] if off else 0.0))
    g = M.goal(mp)
    if g is not None:
        out.update(e_p_mm=g[1] * 1000.0, e_phi_deg=float(np.degrees(g[2])))
    prov = _plan(mp).provenance
    if isinstance(prov, dict) and isinstance(prov.get("margin_mm"), (int, float)):  # `plan masr` wrote them
        least = prov.get("clearance_min_mm")
        out.update(margin_mm=float(prov["margin_mm"]),
                   clearance_min_mm=float(least) if isinstance(least, (int, float)) else None)
    if final_q is None:
        out.update(dp_mm=None, dphi_deg=None)
        return out
    goal = M.goal_pose(mp)
    pose = mp.robot.fk(np.asarray(final_q, float))
    out.update(dp_mm=float(np.hypot(*(pose[:2] - goal[:2])) * 1000.0),
               dphi_deg=float(np.degrees(abs(wrap_angle(pose[2] - goal[2])))))
    return out
