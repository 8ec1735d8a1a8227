"""The plan file: versioned JSON, loaded, validated and saved here. One format for every robot.

A plan is a list of joint-space waypoints for one robot; each waypoint is
reached at the end of its `duration`, starting where the previous one ends
(the first one starts wherever the arm is). See docs/formats.md. The robot
is any `robots.base.Robot`: named from the registry, or described inline
(an object with its `kind`, default "planar"); a waypoint holds its `dof`
coordinates, each in its own unit (rad, or m for a MASR's d). What a kind of
robot needs beyond that rides in a section of its own, checked at load from
the plan and its robot alone: per-waypoint `pen` flags (a drawing),
`masr` (the mobile actuator's actions, tau and goal: plans/masr.py), `soft`
(the soft arm's scene and planned path: plans/soft.py). Planners write these
files and the executor reads them; nothing here plans again.

Version 2 is written; version 1 files (a soft plan's section then in
`provenance["soft_plan"]`) and the old MASR sibling format
(`"armbridge-masr-plan"` version 1) are read into it.

Every problem is an `ArmbridgeError` whose message names the file, the
waypoint index, the field and the allowed range, e.g.

    plan.json: waypoint 17, q[1] (elbow) = 0.4 rad is outside [-3.1416, 0]

A plan that fails here never reaches a port: the executor validates first.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.jsonfile import parse_json, read_json
from armbridge.plans import masr as masr_section
from armbridge.plans import soft as soft_section
from armbridge.robots import catalog
from armbridge.robots.base import Robot

FORMAT = "armbridge-plan"
VERSION = 2
READS = (1, 2)  # versions this armbridge reads
DURATION_MIN = 0.001  # s: one board tick of the ms wire unit
DURATION_MAX = 60.0  # s: the protocol's W limit (60000 ms)
# Relative slack on the speed check, so a segment planned at exactly v_max
# is not refused for a rounding error in the last digit.
SPEED_SLACK = 1e-9

_TOP_FIELDS = ("format", "version", "robot", "joints", "waypoints", "provenance", "masr", "soft")
_V1_FIELDS = ("format", "version", "robot", "joints", "waypoints", "provenance")


@dataclass
class Plan:
    """A validated plan: `q` is (k, dof) in the robot's units, `durations` is (k,) in s."""

    robot: Robot
    q: np.ndarray
    durations: np.ndarray
    provenance: dict = field(default_factory=dict)
    source: Path | None = None
    inline_robot: bool = False  # the file described the robot inline (not a registry name)
    # Optional (k,) pen flags, one a waypoint: 1 = the move into it draws (pen down), 0 = pen up.
    pen: np.ndarray | None = None
    masr: dict | None = None  # a MASR's actions, tau, goal (plans/masr.py), checked
    soft: dict | None = None  # the soft arm's scene and planned path (plans/soft.py), checked

    @property
    def k(self) -> int:
        """Number of waypoints."""
        return int(self.q.shape[0])

    @property
    def n(self) -> int:
        """Coordinates per waypoint (the robot's dof)."""
        return int(self.q.shape[1])

    @property
    def total_duration(self) -> float:
        """Planned duration in s (sum of all segment durations)."""
        return float(np.sum(self.durations))

    @property
    def name(self) -> str:
        """The file's stem; for a plan made in memory, provenance["name"], else "plan"."""
        if self.source is not None:
            return self.source.stem
        name = self.provenance.get("name")
        return name if isinstance(name, str) and name else "plan"

    def ee_path(self) -> np.ndarray:
        """(k, draw_dim) planned end-effector positions in m at the waypoints (robot.ee_point)."""
        return np.asarray(self.robot.ee_point(self.q))


# ---------------------------------------------------------------------------
# small helpers


def fmt_num(x: float) -> str:
    """A number as a person reads it in a message: 4 decimals at most, no trailing zeros."""
    if not math.isfinite(x):
        return str(x)
    s = f"{x:.4f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _describe(v: Any) -> str:
    if isinstance(v, str):
        return f"the string {json.dumps(v)}"
    if v is None:
        return "null"
    if isinstance(v, bool):
        return json.dumps(v)
    if isinstance(v, list):
        return f"a list of {len(v)}"
    if isinstance(v, dict):
        return "an object"
    return repr(v)


class _Ctx:
    """Builds error messages that start with the file name."""

    def __init__(self, source: Path | str | None):
        self.name = str(source) if source is not None else "<plan>"

    def err(self, msg: str) -> ArmbridgeError:
        return ArmbridgeError(f"{self.name}: {msg}")


# ---------------------------------------------------------------------------
# robots


def known_robots() -> list[str]:
    """Names of the registered robots."""
    return catalog.names()


def _registry_robot(name: str, ctx: _Ctx) -> Robot:
    if name.lower() not in known_robots():
        raise ctx.err(f'robot: unknown robot "{name}" (known: {", ".join(known_robots())})')
    try:
        return catalog.get_robot(name)
    except ArmbridgeError as exc:  # e.g. a kind whose optional dependency is missing
        raise ctx.err(f"robot: {exc}") from None


def robot_from_dict(d: Any, ctx: _Ctx | None = None) -> Robot:
    """An inline robot description -> a robot (see docs/formats.md): `kind` (default
    "planar") and that model's keys; `name` may be left out, and so may a planar
    chain's `joint_names` (j1..jn). The model class checks every value."""
    ctx = ctx or _Ctx(None)
    if not isinstance(d, dict):
        raise ctx.err(f"robot must be a registered robot's name or an object, got {_describe(d)}")
    full = {"name": "inline", **d}
    if d.get("kind", "planar") == "planar" and "joint_names" not in d:
        n = len(d["link_lengths"]) if isinstance(d.get("link_lengths"), list) else 0
        full["joint_names"] = [f"j{i + 1}" for i in range(n)]
    try:
        return catalog.robot_from_dict(full)
    except ArmbridgeError as exc:
        raise ctx.err(f"robot: {exc}") from None


# ---------------------------------------------------------------------------
# parse + validate


def plan_from_dict(doc: Any, source: Path | str | None = None) -> Plan:
    """Validate a parsed plan document and build the Plan. Raises ArmbridgeError."""
    ctx = _Ctx(source)
    if not isinstance(doc, dict):
        raise ctx.err(f"a plan is a JSON object, got {_describe(doc)}")
    fmt = doc.get("format")
    if fmt == masr_section.FORMAT_V1:  # the old MASR sibling format
        plan = plan_from_dict(masr_section.v1_to_v2(doc, source, DURATION_MIN), source)
        masr_section.check_v1_tau(doc, plan.robot, plan.q, ctx.err)
        return plan
    if fmt != FORMAT:
        if "format" not in doc:
            raise ctx.err(f'missing field "format" (expected "{FORMAT}")')
        raise ctx.err(f'format is {json.dumps(fmt)}, expected "{FORMAT}"')
    if "version" not in doc:
        raise ctx.err(f'missing field "version" (this armbridge reads versions {", ".join(map(str, READS))})')
    version = doc["version"]
    if not (_is_number(version) and version in READS):
        raise ctx.err(f"unsupported version {json.dumps(version)} (this armbridge reads versions "
                      f"{', '.join(map(str, READS))})")
    allowed = _TOP_FIELDS if version == 2 else _V1_FIELDS
    for key in doc:
        if key not in allowed:
            raise ctx.err(f'unknown field "{key}" (allowed: {", ".join(allowed)})')
    for key in ("robot", "joints", "waypoints"):
        if key not in doc:
            raise ctx.err(f'missing field "{key}"')

    # robot
    spec = doc["robot"]
    if isinstance(spec, str):
        robot = _registry_robot(spec, ctx)
        inline = False
    else:
        robot = robot_from_dict(spec, ctx)
        inline = True
    n = int(robot.dof)
    jnames = list(robot.joint_names)
    units = list(robot.joint_units)
    q_min = np.asarray(robot.q_min, dtype=float)
    q_max = np.asarray(robot.q_max, dtype=float)
    v_max = np.asarray(robot.v_max, dtype=float)

    # joints
    joints = doc["joints"]
    if not isinstance(joints, list):
        raise ctx.err(f"joints must be a list, got {_describe(joints)}")
    if len(joints) != n:
        raise ctx.err(f"joints lists {len(joints)} joints, robot {robot.name} has {n} ({', '.join(jnames)})")
    for j, jd in enumerate(joints):
        if not isinstance(jd, dict):
            raise ctx.err(f"joints[{j}] must be an object with name and unit, got {_describe(jd)}")
        for key in ("name", "unit"):
            if key not in jd:
                raise ctx.err(f'joints[{j}]: missing field "{key}"')
        for key in jd:
            if key not in ("name", "unit"):
                raise ctx.err(f'joints[{j}]: unknown field "{key}" (allowed: name, unit)')
        if jd["name"] != jnames[j]:
            raise ctx.err(
                f"joints[{j}].name is {json.dumps(jd['name'])}, robot {robot.name} calls joint {j} "
                f'"{jnames[j]}" (joints: {", ".join(jnames)})'
            )
        if jd["unit"] != units[j]:
            raise ctx.err(f'joints[{j}] ({jnames[j]}).unit is {json.dumps(jd["unit"])}, allowed: "{units[j]}"')

    # provenance (a version 1 soft plan kept its section there)
    prov = doc.get("provenance", {})
    if not isinstance(prov, dict):
        raise ctx.err(f"provenance must be an object, got {_describe(prov)}")
    prov = dict(prov)
    soft = doc.get("soft", prov.pop(soft_section.KEY_V1, None) if version == 1 else None)
    masr = doc.get("masr")

    # waypoints
    wps = doc["waypoints"]
    if not isinstance(wps, list):
        raise ctx.err(f"waypoints must be a list, got {_describe(wps)}")
    if len(wps) == 0:
        raise ctx.err("waypoints is empty: a plan needs at least one waypoint")
    k = len(wps)
    q = np.empty((k, n))
    dur = np.empty(k)
    pens: list[int] = []
    for i, wp in enumerate(wps):
        where = f"waypoint {i}"
        if not isinstance(wp, dict):
            raise ctx.err(f"{where} must be an object with q and duration, got {_describe(wp)}")
        for key in ("q", "duration"):
            if key not in wp:
                raise ctx.err(f'{where}: missing field "{key}"')
        for key in wp:
            if key not in ("q", "duration", "pen"):
                raise ctx.err(f'{where}: unknown field "{key}" (allowed: q, duration, pen)')
        if i > 0 and ("pen" in wp) != bool(pens):
            raise ctx.err(f"{where}: pen is given on some waypoints only: give it on every waypoint or on none")
        if "pen" in wp:
            if wp["pen"] not in (0, 1) or isinstance(wp["pen"], bool):
                raise ctx.err(f"{where}, pen must be 0 (up) or 1 (down), got {_describe(wp['pen'])}")
            pens.append(int(wp["pen"]))
        qi = wp["q"]
        if not isinstance(qi, list):
            raise ctx.err(f"{where}, q must be a list of {n} numbers, got {_describe(qi)}")
        if len(qi) != n:
            raise ctx.err(f"{where}, q has {len(qi)} values, robot {robot.name} has {n} joints ({', '.join(jnames)})")
        for j, x in enumerate(qi):
            label = f"{where}, q[{j}] ({jnames[j]})"
            if not _is_number(x):
                raise ctx.err(f"{label} must be a number, got {_describe(x)}")
            if not math.isfinite(x):
                raise ctx.err(f"{label} is {x}: plans hold finite numbers only")
            if not (q_min[j] <= x <= q_max[j]):
                raise ctx.err(f"{label} = {fmt_num(x)} {units[j]} is outside [{fmt_num(q_min[j])}, {fmt_num(q_max[j])}]")
            q[i, j] = x
        d = wp["duration"]
        if not _is_number(d):
            raise ctx.err(f"{where}, duration must be a number of seconds, got {_describe(d)}")
        if not math.isfinite(d):
            raise ctx.err(f"{where}, duration is {d}: plans hold finite numbers only")
        if not (DURATION_MIN <= d <= (math.inf if masr is not None else DURATION_MAX)):  # MA actions: no W
            raise ctx.err(
                f"{where}, duration = {fmt_num(d)} s is outside [{fmt_num(DURATION_MIN)}, {fmt_num(DURATION_MAX)}]"
            )
        dur[i] = d
        if i > 0:
            speed = np.abs(q[i] - q[i - 1]) / d
            over = np.nonzero(speed > v_max * (1 + SPEED_SLACK))[0]
            if over.size:
                j = int(over[0])
                u = units[j]
                raise ctx.err(
                    f"{where}, joint {j} ({jnames[j]}) moves {fmt_num(abs(q[i, j] - q[i - 1, j]))} {u} in "
                    f"{fmt_num(d)} s = {fmt_num(speed[j])} {u}/s, above the robot's v_max "
                    f"{fmt_num(v_max[j])} {u}/s (needs duration >= {fmt_num(abs(q[i, j] - q[i - 1, j]) / v_max[j])} s)"
                )
    if masr is not None:
        masr = masr_section.check_section(masr, robot, q, dur, DURATION_MIN, ctx.err)
    if soft is not None:
        soft_section.read_section(soft, n, k, f"{ctx.name}: soft")
    return Plan(
        robot=robot,
        q=q,
        durations=dur,
        provenance=prov,
        source=Path(source) if source is not None else None,
        inline_robot=inline,
        pen=np.array(pens, dtype=int) if pens else None,
        masr=masr,
        soft=soft,
    )


def loads_plan(text: str, source: Path | str | None = None) -> Plan:
    """Parse and validate plan text."""
    return plan_from_dict(parse_json(text, _Ctx(source).name), source)


def load_plan(path: Path | str) -> Plan:
    """Read, parse and validate a plan file. Raises ArmbridgeError naming what is wrong."""
    return plan_from_dict(read_json(path, "plan file"), Path(path))


def validate(plan: Plan | dict, source: Path | str | None = None) -> Plan:
    """Validate a Plan (re-checked through its document form) or a parsed document."""
    if isinstance(plan, Plan):
        return plan_from_dict(plan_to_dict(plan), source if source is not None else plan.source)
    return plan_from_dict(plan, source)


def plan_to_dict(plan: Plan) -> dict:
    """The JSON document of a plan (robot by registry name unless it was inline)."""
    robot = plan.robot
    robot_spec: Any = catalog.robot_to_dict(robot) if plan.inline_robot else robot.name
    prov = dict(plan.provenance)
    return {
        "format": FORMAT,
        "version": VERSION,
        "robot": robot_spec,
        "joints": [{"name": nm, "unit": u} for nm, u in zip(robot.joint_names, robot.joint_units)],
        "waypoints": [
            {"q": [float(x) for x in plan.q[i]], "duration": float(plan.durations[i]),
             **({} if plan.pen is None else {"pen": int(plan.pen[i])})} for i in range(plan.k)
        ],
        "provenance": prov,
        **({} if plan.masr is None else {"masr": plan.masr}),
        **({} if plan.soft is None else {"soft": plan.soft}),
    }


def make_plan(robot: Robot, q, durations, provenance: dict | None = None, *, tool: str = "armbridge",
              pen=None, masr: dict | None = None, soft: dict | None = None) -> Plan:
    """Build (and validate) a Plan in memory; fills provenance.tool and .created when missing.
    A robot that is not the registry's robot of its name is written inline. `pen`: optional
    per-waypoint pen flags (1 down, 0 up); `masr`, `soft`: a section (plans/masr.py, soft.py)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    durations = np.broadcast_to(np.asarray(durations, dtype=float), (q.shape[0],)).copy()
    prov = dict(provenance or {})
    prov.setdefault("tool", tool)
    prov.setdefault("created", datetime.now(timezone.utc).isoformat(timespec="seconds"))
    inline = not catalog.is_registered(robot)
    pen = None if pen is None else np.asarray(pen).astype(int).tolist()
    if pen is not None and len(pen) != q.shape[0]:
        raise ArmbridgeError(f"pen has {len(pen)} flags for {q.shape[0]} waypoints")
    plan = Plan(robot=robot, q=q, durations=durations, provenance=prov, inline_robot=inline,
                pen=None if pen is None else np.array(pen, dtype=int), masr=masr, soft=soft)
    return validate(plan)


def save_plan(plan: Plan, path: Path | str) -> Path:
    """Write a plan file (pretty JSON, one waypoint a line). Refuses NaN and invalid plans."""
    path = Path(path)
    doc = plan_to_dict(plan)
    plan_from_dict(doc, path)  # never write a file we would refuse to load
    head = {k: v for k, v in doc.items() if k not in ("waypoints", "masr")}
    lines = ["{"]
    for key, value in head.items():
        lines.append(f"  {json.dumps(key)}: {json.dumps(value, allow_nan=False)},")
    if "masr" in doc:
        lines.append(f'  "masr": {_masr_text(doc["masr"])},')
    lines.append('  "waypoints": [')
    wps = [json.dumps(w, allow_nan=False) for w in doc["waypoints"]]
    lines.append(",\n".join("    " + w for w in wps))
    lines.append("  ]")
    lines.append("}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _masr_text(sec: dict) -> str:
    """The masr section as it reads best: an action a line and a step a line under it."""
    head = {k: v for k, v in sec.items() if k != "actions"}
    parts = [f"    {json.dumps(k)}: {json.dumps(v, allow_nan=False)}" for k, v in head.items()]
    acts = []
    for a in sec["actions"]:
        first = json.dumps({k: a[k] for k in ("from", "to", "cost")})[:-1]
        steps = ",\n".join("        " + json.dumps(st, allow_nan=False) for st in a["steps"])
        acts.append(f'      {first}, "steps": [\n{steps}\n      ]}}' if a["steps"] else f'      {first}, "steps": []}}')
    parts.append('    "actions": [\n' + ",\n".join(acts) + "\n    ]")
    return "{\n" + ",\n".join(parts) + "\n  }"
