"""The MASR section of a plan: the mobile actuator's actions, tau, the goal (docs/formats.md §4).

A MASR (masr paper) has no servo joints to stream waypoints to: its mobile
actuator (MA) drives along the arm and turns one passive joint at a time. Its
plan is an ordinary plan file (plans/format.py) whose waypoints are the
configuration path q = (theta_1..theta_n, d), each waypoint's duration the
action time c(a) of the action into it (eq. 8; the first waypoint, the start,
takes DURATION_MIN), and whose `masr` section holds the rest:

    tau          the path's action time, eq. (7), s
    goal         (optional) the goal pose (x, y, phi) and its eq. (9) tolerances e_p (m), e_phi (rad)
    environment  (optional) the planning environment, as docs/planning.md writes it (obstacles,
                 start, goal): kept as data; the executor draws its obstacles, planning tools
                 rebuild it (planning/masr/plan_file.py)
    actions      one per consecutive pair: from, to, cost c(a) and the steps of the motion
                 convention (MasrArm.action_sequence: move d_from -> d_to, rotate joint j
                 theta_from -> theta_to, each with its duration)

Checked at load, from the robot alone (robots/masr.py), never by planning again:
the steps are the motion convention's, their durations sum to each action's cost
and the costs to tau, the environment's start is waypoint 0, the last waypoint
holds the robot's d_margin, and with a goal the goal check (eq. 9) holds for every
d within that margin (MasrArm.span_pose_errors). The path against the obstacles
is planning's check (load_masr_plan), not the executor's.

The old sibling format (`"format": "armbridge-masr-plan"`, version 1: waypoints
with a cumulative tau, the same actions) is read (`v1_to_v2`, `check_v1_tau`, with
its own checks and messages) into this one.
"""
from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.plans.checks import polygon

FORMAT_V1 = "armbridge-masr-plan"
_V1_TOP = ("format", "version", "robot", "configuration", "tau", "goal", "environment", "provenance", "waypoints",
           "actions")
_SECTION = ("tau", "goal", "environment", "actions")
TOL = 1e-6  # s / rad / m: consistency of stored numbers with the model


def _num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def steps_of(arm: Any, qa: np.ndarray, qb: np.ndarray) -> list[dict]:
    """The motion convention's steps from qa to qb (MasrArm.action_sequence), with durations."""
    out = []
    for st in arm.action_sequence(qa, qb):
        if len(st) == 3:  # ("move", d_from, d_to)
            d0, d1 = float(st[1]), float(st[2])
            out.append({"op": "move", "d_from": d0, "d_to": d1, "duration": abs(d1 - d0) / arm.ma_speed})
        else:  # ("rotate", joint, theta_from, theta_to)
            j, t0, t1 = st[1], float(st[2]), float(st[3])
            out.append({"op": "rotate", "joint": int(j), "theta_from": t0, "theta_to": t1,
                        "duration": abs(t1 - t0) / arm.joint_speed})
    return out


def masr_section(arm: Any, path: Any, environment: dict | None = None, goal: dict | None = None) -> dict:
    """The section of a plan along `path` (K, n+1) for `arm` (what a planner writes)."""
    P = np.asarray(path, dtype=float)
    costs = arm.action_cost(P[:-1], P[1:]) if P.shape[0] > 1 else np.zeros(0)
    sec: dict[str, Any] = {"tau": float(np.sum(costs))}
    if goal is not None:
        sec["goal"] = {"pose": [float(v) for v in goal["pose"]], "e_p": float(goal["e_p"]),
                       "e_phi": float(goal["e_phi"])}
    if environment is not None:
        sec["environment"] = environment
    sec["actions"] = [{"from": k, "to": k + 1, "cost": float(costs[k]), "steps": steps_of(arm, P[k], P[k + 1])}
                      for k in range(P.shape[0] - 1)]
    return sec


def path_durations(costs: np.ndarray, duration_min: float) -> np.ndarray:
    """The waypoints' durations of a path whose actions cost `costs`: the start DURATION_MIN."""
    return np.concatenate([[duration_min], np.maximum(np.asarray(costs, float), duration_min)])


def check_section(sec: Any, robot: Any, q: np.ndarray, durations: np.ndarray, duration_min: float,
                  err: Any) -> dict:
    """The section `sec` of a plan of `robot` along q (K, n+1) with these durations, checked
    (module docstring); `err(msg)` makes the ArmbridgeError naming the file."""
    if not hasattr(robot, "action_sequence"):
        raise err(f"masr: robot {robot.name} is not a MASR")
    if not isinstance(sec, dict):
        raise err("masr must be an object with tau, actions and optionally goal, environment")
    for key in sec:
        if key not in _SECTION:
            raise err(f'masr: unknown field "{key}" (allowed: {", ".join(_SECTION)})')
    for key in ("tau", "actions"):
        if key not in sec:
            raise err(f'masr: missing field "{key}"')
    arm, n = robot, robot.n
    costs = arm.action_cost(q[:-1], q[1:]) if len(q) > 1 else np.zeros(0)
    expect = path_durations(costs, duration_min)
    for k in range(len(q)):
        if abs(durations[k] - expect[k]) > TOL * (1 + expect[k]):
            raise err(f"waypoint {k}, duration = {durations[k]:.6f} s but the action into it takes {expect[k]:.6f} s "
                      "(eq. 8; the start: the shortest duration)")
    if not _num(sec["tau"]) or abs(sec["tau"] - float(np.sum(costs))) > TOL * (1 + float(np.sum(costs))):
        raise err(f"tau = {sec['tau']} s but the path takes {float(np.sum(costs)):.6f} s (eq. 7)")
    acts = sec["actions"]
    if not isinstance(acts, list) or len(acts) != len(q) - 1:
        raise err(f"actions must list {len(q) - 1} actions, one per pair of consecutive waypoints")
    for k, a in enumerate(acts):
        if not isinstance(a, dict) or set(a) != {"from", "to", "cost", "steps"}:
            raise err(f"action {k} must be an object with exactly from, to, cost, steps")
        if a["from"] != k or a["to"] != k + 1:
            raise err(f"action {k} must go from waypoint {k} to {k + 1}")
        if not _num(a["cost"]) or abs(a["cost"] - costs[k]) > TOL * (1 + costs[k]):
            raise err(f"action {k}, cost = {a['cost']} s but eq. (8) gives {costs[k]:.6f} s")
        want = steps_of(arm, q[k], q[k + 1])
        if not isinstance(a["steps"], list) or len(a["steps"]) != len(want):
            raise err(f"action {k}: the motion convention gives {len(want)} steps, the file lists "
                      f"{len(a['steps']) if isinstance(a['steps'], list) else a['steps']!r}")
        for i, (got, exp) in enumerate(zip(a["steps"], want)):
            if not isinstance(got, dict) or set(got) != set(exp) or got.get("op") != exp["op"] or any(
                    (not _num(got[f]) or abs(got[f] - exp[f]) > TOL) for f in exp if f != "op"):
                raise err(f"action {k}, step {i}: expected {json.dumps(exp)} (motion convention, section II-C)")
        if abs(sum(s["duration"] for s in a["steps"]) - costs[k]) > TOL * (1 + costs[k]):
            raise err(f"action {k}: step durations do not sum to its cost")
    env = sec.get("environment")
    if env is not None:
        if not isinstance(env, dict) or not isinstance(env.get("obstacles"), list):
            raise err("masr.environment must be an environment object (docs/planning.md) with its obstacles")
        start = np.asarray(env.get("start", q[0]), dtype=float)
        if start.shape != q[0].shape or np.max(np.abs(start - q[0])) > TOL:
            raise err("waypoint 0 is not the environment's start configuration")
        for i, p in enumerate(env["obstacles"]):
            try:
                polygon(p, f"masr.environment.obstacles[{i}]", 3)
            except ArmbridgeError as exc:
                raise err(str(exc)) from None
    d_end = float(q[-1, n])
    if not arm.holds_margin(d_end):
        raise err(f"the last waypoint puts the MA at d = {d_end:.6f} m, {float(arm.joint_clearance(d_end)) * 1e3:.3f} mm "
                  f"from a joint, inside the robot's d_margin = {arm.d_margin * 1e3:g} mm (the MA's localisation "
                  f"bound): a real MA cannot stop there reliably")
    if "goal" in sec:
        g = sec["goal"]
        if not isinstance(g, dict) or set(g) != {"pose", "e_p", "e_phi"}:
            raise err("goal must be an object with exactly pose, e_p, e_phi")
        pose = np.asarray(g["pose"], float)
        dp, dphi = (float(v) for v in arm.span_pose_errors(q[-1], pose))
        if dp > g["e_p"] + 1e-12 or dphi > g["e_phi"] + 1e-12:
            raise err(f"the last waypoint puts the MA up to {dp * 1e3:.2f} mm and {math.degrees(dphi):.2f} deg from "
                      f"the goal for d within d_margin = {arm.d_margin * 1e3:g} mm of its d, outside "
                      f"e_p = {g['e_p'] * 1e3:g} mm, e_phi = {math.degrees(g['e_phi']):g} deg (eq. 9)")
    return dict(sec)


# ------------------------------------------------------------------ reading a plan's section

def steps(plan: Any) -> list[dict]:
    """Every MA step of a MASR plan in order (move / rotate dicts with durations)."""
    return [s for a in plan.masr["actions"] for s in a["steps"]]


def total_time(plan: Any) -> float:
    """tau of the whole path, eq. (7), s."""
    return float(plan.masr["tau"])


def trapezoid_time(x: float, v: float, a: float) -> float:
    """Time of a move of |x| from rest to rest at top speed v and acceleration a
    (a trapezoid; a triangle when |x| < v^2 / a; a <= 0: no ramp, |x| / v). Pure."""
    x = abs(float(x))
    if x == 0.0:
        return 0.0
    if a <= 0.0:
        return x / v
    if x >= v * v / a:
        return x / v + v / a
    return 2.0 * math.sqrt(x / a)


def ramped_time(plan: Any, ma_accel: float, joint_accel: float) -> float:
    """The plan's time on a board that ramps each step from rest to rest (s): every step of
    the motion convention timed by `trapezoid_time` at the robot's speeds (ma_speed,
    joint_speed) and the board's accelerations (m/s^2, rad/s^2). Eq. (8) prices a step at
    |x| / v, as if the MA changed speed at once; each stop-to-stop step on a board adds
    v / a to that (less on a short one), the share of tau that single actions miss by."""
    arm = plan.robot
    total = 0.0
    for st in steps(plan):
        if st["op"] == "move":
            total += trapezoid_time(st["d_to"] - st["d_from"], arm.ma_speed, ma_accel)
        else:
            total += trapezoid_time(st["theta_to"] - st["theta_from"], arm.joint_speed, joint_accel)
    return total


def tau(plan: Any) -> np.ndarray:
    """The cumulative action time at each waypoint (0 at the first)."""
    return np.concatenate([[0.0], np.cumsum([float(a["cost"]) for a in plan.masr["actions"]])])


def goal(plan: Any) -> tuple[np.ndarray, float, float] | None:
    """(goal pose, e_p, e_phi), or None for a plan without a goal."""
    g = plan.masr.get("goal")
    return None if g is None else (np.asarray(g["pose"], float), float(g["e_p"]), float(g["e_phi"]))


def goal_pose(plan: Any) -> np.ndarray:
    """The goal pose (x, y, phi), or (no goal) the MA pose the plan's last waypoint puts it in."""
    g = goal(plan)
    return g[0] if g is not None else np.asarray(plan.robot.fk(plan.q[-1]), dtype=float)


def obstacles(plan: Any) -> list[np.ndarray]:
    """The obstacles of the plan's environment (polygons in m), [] without one."""
    env = plan.masr.get("environment") or {}
    return [np.asarray(p, dtype=float) for p in env.get("obstacles", [])]


# ------------------------------------------------------------------ the old sibling format

def v1_to_v2(doc: dict, source: Any, duration_min: float) -> dict:
    """An `armbridge-masr-plan` version 1 document, its own fields checked, as the plan document of
    version 2 (plans/format.py reads that; `check_v1_tau` then checks version 1's waypoint tau)."""
    from armbridge.robots.catalog import get_masr
    from armbridge.robots.masr import MasrArm

    name = str(source) if source is not None else "<masr plan>"

    def err(msg: str) -> ArmbridgeError:
        return ArmbridgeError(f"{name}: {msg}")

    if doc.get("version") != 1 or isinstance(doc.get("version"), bool):
        raise err(f"unsupported version {json.dumps(doc.get('version'))} (this armbridge reads version 1 of "
                  f"{FORMAT_V1})")
    for key in doc:
        if key not in _V1_TOP:
            raise err(f'unknown field "{key}" (allowed: {", ".join(_V1_TOP)})')
    for key in ("robot", "configuration", "tau", "waypoints", "actions"):
        if key not in doc:
            raise err(f'missing field "{key}"')
    try:
        arm = get_masr(doc["robot"]) if isinstance(doc["robot"], str) else MasrArm.from_dict(doc["robot"])
    except ArmbridgeError as exc:
        raise err(f"robot: {exc}") from None
    wps = doc["waypoints"]
    if not isinstance(wps, list) or not wps:
        raise err("waypoints must be a non-empty list")
    for k, w in enumerate(wps):
        if not isinstance(w, dict) or set(w) != {"q", "tau"}:
            raise err(f"waypoint {k} must be an object with exactly q and tau")
        if not isinstance(w["q"], list) or len(w["q"]) != arm.n + 1 or not all(_num(v) for v in w["q"]):
            raise err(f"waypoint {k}, q must be {arm.n + 1} finite numbers (theta_1..theta_{arm.n} rad, d m)")
        if not _num(w["tau"]):
            raise err(f"waypoint {k}, tau must be a finite number of seconds")
    q = np.array([w["q"] for w in wps], float)
    n = arm.n
    for k in range(len(q)):
        if not arm.within_limits(q[k]):
            off = [j for j in range(n) if abs(q[k, j]) > arm.theta_b[j]]
            what = (f"theta_{off[0] + 1} = {q[k, off[0]]:.4f} rad is outside +-{arm.theta_b[off[0]]:.4f}" if off
                    else f"d = {q[k, n]:.4f} m is off the arm [0, {arm.total_length:.4f}]")
            raise err(f"waypoint {k}: {what}")
    costs = arm.action_cost(q[:-1], q[1:]) if len(q) > 1 else np.zeros(0)
    return {"format": "armbridge-plan", "version": 2, "robot": doc["robot"], "joints": doc["configuration"],
            "waypoints": [{"q": w["q"], "duration": float(d)}
                          for w, d in zip(wps, path_durations(costs, duration_min))],
            "provenance": doc.get("provenance", {}),
            "masr": {k: doc[k] for k in _SECTION if k in doc}}


def check_v1_tau(doc: dict, robot: Any, q: np.ndarray, err: Any) -> None:
    """Version 1's own check: each waypoint's tau is eq. (7) along the path."""
    costs = robot.action_cost(q[:-1], q[1:]) if len(q) > 1 else np.zeros(0)
    expect = np.concatenate([[0.0], np.cumsum(costs)])
    tau_k = np.array([w["tau"] for w in doc["waypoints"]], float)
    bad = np.flatnonzero(np.abs(expect - tau_k) > TOL * (1 + np.abs(expect)))
    if bad.size:
        k = int(bad[0])
        raise err(f"waypoint {k}, tau = {tau_k[k]:.6f} s but eq. (7) along the path gives {expect[k]:.6f} s")
