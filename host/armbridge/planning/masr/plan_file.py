"""MASR plan files: a configuration path, the MA's action sequence and tau (docs/formats.md, "MASR plans").

A MASR is not a chain of servo joints, so its plans are a sibling of the
armbridge-plan format (same conventions: versioned JSON, no unknown fields,
one ArmbridgeError naming the file and place of the first problem,
provenance kept as is), with `"format": "armbridge-masr-plan"`:

    save_masr_plan(env, path, "plan.json", provenance={...})   # path (K, n+1) from the planner
    plan = load_masr_plan("plan.json")                          # -> MasrPlan, validated
    plan.q, plan.tau, plan.actions, plan.steps(), plan.env

Each action k -> k+1 lists the steps of MasrArm.action_sequence with their
durations (move |d_to - d_from| / d-dot, rotate |theta_to - theta_from| /
theta-dot); the durations of an action sum to its cost c(a), eq. (8), and all
of them to tau, eq. (7). The environment is embedded, so a reader can check
the path against the obstacles again (load_masr_plan does, along the motion
convention). The last waypoint must be executable by a real MA: its d at
least the robot's d_margin (the MA's localisation bound) from every joint,
and, with a goal, the goal check (eq. 9) must hold for every d within that
margin (MasrArm.span_pose_errors: exact by checking the interval's ends).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.jsonfile import read_json
from armbridge.planning.masr.environment import Environment, environment_from_dict
from armbridge.robots.catalog import get_masr, is_registered
from armbridge.robots.masr import MasrArm

FORMAT = "armbridge-masr-plan"
VERSION = 1
_TOP = ("format", "version", "robot", "configuration", "tau", "goal", "environment", "provenance", "waypoints",
        "actions")
_TOL = 1e-6  # s / rad / m: consistency of stored numbers with the model


@dataclass
class MasrPlan:
    """A validated MASR plan: q (K, n+1), tau (K,) cumulative action time in s."""

    arm: MasrArm
    q: np.ndarray
    tau: np.ndarray
    actions: list
    env: Optional[Environment] = None
    provenance: dict = field(default_factory=dict)
    source: Optional[Path] = None

    @property
    def total_time(self) -> float:
        """tau of the whole path, eq. (7), in s."""
        return float(self.tau[-1])

    def steps(self) -> list[dict]:
        """Every MA step of the plan in order (move / rotate dicts with durations)."""
        return [s for a in self.actions for s in a["steps"]]


def configuration_names(arm: MasrArm) -> list[dict]:
    return [{"name": f"theta_{j + 1}", "unit": "rad"} for j in range(arm.n)] + [{"name": "d", "unit": "m"}]


def _steps(arm: MasrArm, qa: np.ndarray, qb: np.ndarray) -> list[dict]:
    out = []
    for st in arm.action_sequence(qa, qb):
        if len(st) == 3:  # ("move", d_from, d_to)
            d0, d1 = float(st[1]), float(st[2])
            out.append({"op": "move", "d_from": d0, "d_to": d1, "duration": abs(d1 - d0) / arm.ma_speed})
        else:  # ("rotate", joint, theta_from, theta_to)
            j, t0, t1 = st[1], float(st[2]), float(st[3])  # type: ignore[misc]
            out.append({"op": "rotate", "joint": int(j), "theta_from": t0, "theta_to": t1,
                        "duration": abs(t1 - t0) / arm.joint_speed})
    return out


def masr_plan_document(env: Environment, path: Any, provenance: Optional[dict] = None) -> dict:
    """The JSON document of a plan for env along path (K, n+1)."""
    arm = env.arm
    P = arm._q(np.asarray(path, dtype=float), "path")
    if P.ndim != 2 or P.shape[0] < 1:
        raise ArmbridgeError(f"a MASR plan needs a path of shape (K, {arm.n + 1}), K >= 1; got {P.shape}")
    costs = arm.action_cost(P[:-1], P[1:]) if P.shape[0] > 1 else np.zeros(0)
    tau = np.concatenate([[0.0], np.cumsum(costs)])
    prov = dict(provenance or {})
    prov.setdefault("tool", "armbridge.planning")
    prov.setdefault("created", datetime.now(timezone.utc).isoformat(timespec="seconds"))
    envdoc = env.to_dict()
    envdoc.pop("known_path", None)
    return {
        "format": FORMAT,
        "version": VERSION,
        "robot": arm.name if is_registered(arm) else arm.to_dict(),
        "configuration": configuration_names(arm),
        "tau": float(tau[-1]),
        "goal": {"pose": [float(v) for v in env.goal_pose], "e_p": env.e_p, "e_phi": env.e_phi},
        "environment": envdoc,
        "provenance": prov,
        "waypoints": [{"q": [float(v) for v in P[k]], "tau": float(tau[k])} for k in range(P.shape[0])],
        "actions": [{"from": k, "to": k + 1, "cost": float(costs[k]), "steps": _steps(arm, P[k], P[k + 1])}
                    for k in range(P.shape[0] - 1)],
    }


def save_masr_plan(env: Environment, path: Any, out: Any, provenance: Optional[dict] = None) -> Path:
    """Write a MASR plan file (validated first; one waypoint and one step a line)."""
    out = Path(out)
    doc = masr_plan_document(env, path, provenance)
    plan_from_document(json.loads(json.dumps(doc)), out)  # never write what we would refuse
    lines = ["{"]
    for key in ("format", "version", "robot", "configuration", "tau", "goal", "environment", "provenance"):
        lines.append(f"  {json.dumps(key)}: {json.dumps(doc[key], allow_nan=False)},")
    lines.append('  "waypoints": [')
    lines.append(",\n".join("    " + json.dumps(w, allow_nan=False) for w in doc["waypoints"]))
    lines.append("  ],")
    lines.append('  "actions": [')
    acts = []
    for a in doc["actions"]:
        head = json.dumps({k: a[k] for k in ("from", "to", "cost")})[:-1]
        steps = ",\n".join("      " + json.dumps(s, allow_nan=False) for s in a["steps"])
        acts.append(f'    {head}, "steps": [\n{steps}\n    ]}}' if a["steps"] else f'    {head}, "steps": []}}')
    lines.append(",\n".join(acts))
    lines.append("  ]")
    lines.append("}")
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    except OSError as exc:
        raise ArmbridgeError(f"{out}: cannot write the plan: {exc.strerror}") from None
    return out


def _num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def plan_from_document(doc: Any, source: Any = None) -> MasrPlan:
    """Validate a parsed MASR plan document; ArmbridgeError names the first problem."""
    name = str(source) if source is not None else "<masr plan>"

    def err(msg: str) -> ArmbridgeError:
        return ArmbridgeError(f"{name}: {msg}")

    if not isinstance(doc, dict):
        raise err("a MASR plan is a JSON object")
    if doc.get("format") != FORMAT:
        raise err(f'format is {json.dumps(doc.get("format"))}, expected "{FORMAT}"')
    if doc.get("version") != VERSION or isinstance(doc.get("version"), bool):
        raise err(f"unsupported version {json.dumps(doc.get('version'))} (this armbridge reads version {VERSION})")
    for key in doc:
        if key not in _TOP:
            raise err(f'unknown field "{key}" (allowed: {", ".join(_TOP)})')
    for key in ("robot", "configuration", "tau", "waypoints", "actions"):
        if key not in doc:
            raise err(f'missing field "{key}"')
    try:
        arm = get_masr(doc["robot"]) if isinstance(doc["robot"], str) else MasrArm.from_dict(doc["robot"])
    except ArmbridgeError as exc:
        raise err(f"robot: {exc}") from None
    n = arm.n
    if doc["configuration"] != configuration_names(arm):
        raise err(f"configuration must be {json.dumps(configuration_names(arm))}")
    wps = doc["waypoints"]
    if not isinstance(wps, list) or not wps:
        raise err("waypoints must be a non-empty list")
    q = np.empty((len(wps), n + 1))
    tau = np.empty(len(wps))
    for k, w in enumerate(wps):
        if not isinstance(w, dict) or set(w) != {"q", "tau"}:
            raise err(f"waypoint {k} must be an object with exactly q and tau")
        if not isinstance(w["q"], list) or len(w["q"]) != n + 1 or not all(_num(v) for v in w["q"]):
            raise err(f"waypoint {k}, q must be {n + 1} finite numbers (theta_1..theta_{n} rad, d m)")
        if not _num(w["tau"]):
            raise err(f"waypoint {k}, tau must be a finite number of seconds")
        q[k] = w["q"]
        tau[k] = w["tau"]
        if not arm.within_limits(q[k]):
            off = [j for j in range(n) if abs(q[k, j]) > arm.theta_b[j]]
            what = (f"theta_{off[0] + 1} = {q[k, off[0]]:.4f} rad is outside +-{arm.theta_b[off[0]]:.4f}" if off
                    else f"d = {q[k, n]:.4f} m is off the arm [0, {arm.total_length:.4f}]")
            raise err(f"waypoint {k}: {what}")
    costs = arm.action_cost(q[:-1], q[1:]) if len(q) > 1 else np.zeros(0)
    expect = np.concatenate([[0.0], np.cumsum(costs)])
    bad = np.flatnonzero(np.abs(expect - tau) > _TOL * (1 + np.abs(expect)))
    if bad.size:
        k = int(bad[0])
        raise err(f"waypoint {k}, tau = {tau[k]:.6f} s but eq. (7) along the path gives {expect[k]:.6f} s")
    if not _num(doc["tau"]) or abs(doc["tau"] - expect[-1]) > _TOL * (1 + expect[-1]):
        raise err(f"tau = {doc['tau']} s but the path takes {expect[-1]:.6f} s (eq. 7)")
    acts = doc["actions"]
    if not isinstance(acts, list) or len(acts) != len(q) - 1:
        raise err(f"actions must list {len(q) - 1} actions, one per pair of consecutive waypoints")
    for k, a in enumerate(acts):
        if not isinstance(a, dict) or set(a) != {"from", "to", "cost", "steps"}:
            raise err(f"action {k} must be an object with exactly from, to, cost, steps")
        if a["from"] != k or a["to"] != k + 1:
            raise err(f"action {k} must go from waypoint {k} to {k + 1}")
        if not _num(a["cost"]) or abs(a["cost"] - costs[k]) > _TOL * (1 + costs[k]):
            raise err(f"action {k}, cost = {a['cost']} s but eq. (8) gives {costs[k]:.6f} s")
        want = _steps(arm, q[k], q[k + 1])
        if not isinstance(a["steps"], list) or len(a["steps"]) != len(want):
            raise err(f"action {k}: the motion convention gives {len(want)} steps, the file lists "
                      f"{len(a['steps']) if isinstance(a['steps'], list) else a['steps']!r}")
        for i, (got, exp) in enumerate(zip(a["steps"], want)):
            if not isinstance(got, dict) or set(got) != set(exp) or got.get("op") != exp["op"] or any(
                    (not _num(got[f]) or abs(got[f] - exp[f]) > _TOL) for f in exp if f != "op"):
                raise err(f"action {k}, step {i}: expected {json.dumps(exp)} (motion convention, section II-C)")
        if abs(sum(s["duration"] for s in a["steps"]) - costs[k]) > _TOL * (1 + costs[k]):
            raise err(f"action {k}: step durations do not sum to its cost")
    env = None
    if "environment" in doc:
        try:
            env = environment_from_dict(doc["environment"], f"{name}: environment")
        except ArmbridgeError as exc:
            raise ArmbridgeError(str(exc)) from None
        if env.arm != arm:
            raise err("environment: its robot differs from the plan's robot")
        if np.max(np.abs(env.start - q[0])) > _TOL:
            raise err("waypoint 0 is not the environment's start configuration")
        problem = env.checker().path_problem(q)
        if problem:
            raise err(f"path collides: {problem}")
    d_end = float(q[-1, n])
    if not arm.holds_margin(d_end):
        raise err(f"the last waypoint puts the MA at d = {d_end:.6f} m, {float(arm.joint_clearance(d_end)) * 1e3:.3f} mm "
                  f"from a joint, inside the robot's d_margin = {arm.d_margin * 1e3:g} mm (the MA's localisation "
                  f"bound): a real MA cannot stop there reliably")
    if "goal" in doc:
        g = doc["goal"]
        if not isinstance(g, dict) or set(g) != {"pose", "e_p", "e_phi"}:
            raise err("goal must be an object with exactly pose, e_p, e_phi")
        pose = np.asarray(g["pose"], float)
        dp, dphi = (float(v) for v in arm.span_pose_errors(q[-1], pose))
        if dp > g["e_p"] + 1e-12 or dphi > g["e_phi"] + 1e-12:
            raise err(f"the last waypoint puts the MA up to {dp * 1e3:.2f} mm and {math.degrees(dphi):.2f} deg from "
                      f"the goal for d within d_margin = {arm.d_margin * 1e3:g} mm of its d, outside "
                      f"e_p = {g['e_p'] * 1e3:g} mm, e_phi = {math.degrees(g['e_phi']):g} deg (eq. 9)")
    prov = doc.get("provenance", {})
    if not isinstance(prov, dict):
        raise err("provenance must be an object")
    return MasrPlan(arm=arm, q=q, tau=tau, actions=acts, env=env, provenance=dict(prov),
                    source=Path(source) if source is not None else None)


def load_masr_plan(path: Any) -> MasrPlan:
    """Read and validate a MASR plan file."""
    doc = read_json(path, "plan file")
    return plan_from_document(doc, Path(path))
