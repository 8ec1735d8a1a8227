"""MASR planning environments: polygons, a start configuration and a goal pose (JSON).

    env = load_environment("host/armbridge/planning/masr/envs/E1.json")   # or fixed_environment("E1")
    env.obstacles, env.start, env.goal_pose, env.goal_q, env.e_p, env.e_phi
    save_environment(env, "mine.json")

Random environments (section V-C) are random_env.random_environment.

File format (docs/planning.md): `"format": "armbridge-masr-env"`, version 1;
angles in rad, lengths in m. Loading validates and stops at the first
problem with one ArmbridgeError line naming it: a self-intersecting polygon,
a goal out of reach, a start in collision or outside the joint limits.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.jsonfile import read_json
from armbridge.ik import masr_dls
from armbridge.ik.masr_dls import E_P, E_PHI  # the goal tolerances of section V-A
from armbridge.planning.base import Problem
from armbridge.planning.envfile import Ctx, fmt, header, number, obstacle, vector
from armbridge.planning.margin import check_margin
from armbridge.planning.masr.collision import SWEEP_RES, CollisionChecker
from armbridge.planning.masr.space import MasrChecker, MasrGoal, MasrSpace
from armbridge.robots.catalog import get_masr, is_registered
from armbridge.robots.masr import MasrArm
from armbridge.geometry import wrap_angle

FORMAT = "armbridge-masr-env"
VERSION = 1
ENV_DIR = Path(__file__).with_name("envs")
FIXED = ("E1", "E2", "E3")

_TOP = ("format", "version", "name", "description", "robot", "obstacles", "margin", "start", "goal", "known_path",
        "provenance")
_GOAL = ("pose", "q", "e_p", "e_phi")


@dataclass(eq=False)
class Environment:
    """A validated planning problem for one MASR.

    obstacles: list of (k, 2) vertex arrays (m). start: (n+1,) configuration.
    goal_pose: (x, y, phi). goal_q: a collision-free configuration in the goal
    region (given in the file, or found by numeric IK when loading).
    e_p (m), e_phi (rad): the goal region of eq. (9). known_path: optional
    (K, n+1) configurations of a known solution (random environments store
    the path that verified them).
    """

    name: str
    arm: MasrArm
    obstacles: list
    start: np.ndarray
    goal_pose: np.ndarray
    goal_q: Optional[np.ndarray] = None
    e_p: float = E_P
    e_phi: float = E_PHI
    description: str = ""
    known_path: Optional[np.ndarray] = None
    provenance: dict = field(default_factory=dict)
    margin: Optional[float] = None  # m kept beyond half the link width when planning; None: the MA's execution
    #                                 bound (planning/masr/margin.py; E1-E3 and Fig. 5's environments say 0)
    source: Optional[Path] = None
    _checkers: dict = field(default_factory=dict, repr=False)

    def checker(self, sweep_res: Optional[float] = None, margin: Optional[float] = None) -> CollisionChecker:
        """The collision checker of this environment (obstacles inflated by half the link width)."""
        key = (SWEEP_RES if sweep_res is None else float(sweep_res), margin)
        if key not in self._checkers:
            self._checkers[key] = CollisionChecker.create(self.arm, self.obstacles, margin=margin, sweep_res=key[0])
        return self._checkers[key]

    @property
    def planning_margin(self) -> float:
        """The clearance plans keep beyond half the link width (m): the file's "margin", else the MA's
        execution bound (planning/masr/margin.py: 5.25 mm for masr5)."""
        from armbridge.planning.masr.margin import execution_margin

        return float(self.margin) if self.margin is not None else execution_margin(self.arm)

    def planning_checker(self, sweep_res: Optional[float] = None, margin: Optional[float] = None
                         ) -> CollisionChecker:
        """The checker plans are made with: obstacles inflated by half the link width plus `margin` (m;
        default planning_margin)."""
        extra = self.planning_margin if margin is None else check_margin(margin)
        if extra == 0.0:
            return self.checker(sweep_res)
        return self.checker(sweep_res, margin=0.5 * self.arm.link_width + extra)

    def problem(self, *, sweep_res: Optional[float] = None, steer: str = "linear",
                goal_rect_width: Optional[float] = None, checker: Any = None) -> Problem:
        """This environment as a planning problem (planning.base): MasrSpace (with `steer`), MasrChecker
        (this environment's planning checker at `sweep_res`, or the given CollisionChecker / MasrChecker),
        the start, MasrGoal (OnGoal's rectangle `goal_rect_width`, default e_p) and goal_q as goal_states."""
        chk = checker if checker is not None else self.planning_checker(sweep_res=sweep_res)
        if isinstance(chk, CollisionChecker):
            chk = MasrChecker(chk)
        n = self.arm.n
        states = np.zeros((0, n + 1)) if self.goal_q is None else np.asarray(self.goal_q, dtype=float).reshape(1, n + 1)
        return Problem(MasrSpace(self.arm, steer), chk, np.asarray(self.start, dtype=float),
                       MasrGoal(self.arm, self.goal_pose, self.e_p, self.e_phi, goal_rect_width), states, self.name)

    def pose_errors(self, q: Any) -> tuple[np.ndarray, np.ndarray]:
        """(dp in m, |dphi| in rad) of the MA pose f(q) against the goal pose."""
        x = self.arm.fk(q)
        return (np.linalg.norm(x[..., :2] - self.goal_pose[:2], axis=-1),
                np.abs(wrap_angle(x[..., 2] - self.goal_pose[2])))

    def in_goal(self, q: Any) -> np.ndarray:
        """The goal check (MasrArm.reaches): d at least the arm's d_margin from every joint and the MA
        pose within e_p and e_phi of the goal pose (eq. 9) for every d within that margin."""
        return self.arm.reaches(q, self.goal_pose, self.e_p, self.e_phi)

    def to_dict(self) -> dict[str, Any]:
        robot: Any = self.arm.name if is_registered(self.arm) else self.arm.to_dict()
        goal: dict[str, Any] = {"pose": [float(v) for v in self.goal_pose]}
        if self.goal_q is not None:
            goal["q"] = [float(v) for v in self.goal_q]
        goal["e_p"] = float(self.e_p)
        goal["e_phi"] = float(self.e_phi)
        d: dict[str, Any] = {"format": FORMAT, "version": VERSION, "name": self.name}
        if self.description:
            d["description"] = self.description
        d["robot"] = robot
        d["obstacles"] = [[[float(x), float(y)] for x, y in p] for p in self.obstacles]
        if self.margin is not None:
            d["margin"] = float(self.margin)
        d["start"] = [float(v) for v in self.start]
        d["goal"] = goal
        if self.known_path is not None:
            d["known_path"] = [[float(v) for v in q] for q in self.known_path]
        if self.provenance:
            d["provenance"] = dict(self.provenance)
        return d

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Environment) and self.to_dict() == other.to_dict()


# ------------------------------------------------------------------ validation
def _robot(spec: Any, ctx: Ctx) -> MasrArm:
    try:
        if isinstance(spec, str):
            return get_masr(spec)
        return MasrArm.from_dict(spec)
    except ArmbridgeError as exc:
        raise ctx.err(f"robot: {exc}") from None


def _describe_q(arm: MasrArm, q: np.ndarray) -> Optional[str]:
    """Why q is outside C_f (eq. 5), or None."""
    for j in range(arm.n):
        if abs(q[j]) > arm.theta_b[j]:
            return (f"theta_{j + 1} = {fmt(q[j])} rad is outside the joint limits "
                    f"[-{fmt(arm.theta_b[j])}, {fmt(arm.theta_b[j])}]")
    if not 0.0 <= q[-1] <= arm.total_length:
        return f"d = {fmt(q[-1])} m is off the arm [0, {fmt(arm.total_length)}]"
    return None


def find_goal_configs(arm: MasrArm, goal_pose: np.ndarray, checker: CollisionChecker, *, e_p: float = E_P,
                      e_phi: float = E_PHI, starts: int = 512, seed: int = 0,
                      extra_starts: Optional[np.ndarray] = None) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Multi-start DLS IK for the goal pose.

    Returns (configurations passing the goal check (m, n+1): MasrArm.reaches,
    the joint margin held; which of them are collision-free (m,); best dp (m),
    best dphi (rad) at d) over all starts.
    """
    rng = np.random.default_rng(seed)
    tb = arm.theta_b
    q0 = np.concatenate([rng.uniform(-tb, tb, (starts, arm.n)), rng.uniform(0, arm.total_length, (starts, 1))], 1)
    if extra_starts is not None:
        q0 = np.concatenate([np.asarray(extra_starts, float).reshape(-1, arm.n + 1), q0])
    q, _ = masr_dls.solve(arm, goal_pose, q0, e_p=e_p, e_phi=e_phi, iters=60)
    x = arm.fk(q)
    dp = np.linalg.norm(x[:, :2] - goal_pose[:2], axis=-1)
    dphi = np.abs(wrap_angle(x[:, 2] - goal_pose[2]))
    ok = arm.reaches(q, goal_pose, e_p, e_phi) & arm.within_limits(q)
    best = int(np.argmin(dp / e_p + dphi / e_phi))
    good = q[ok]
    return good, checker.free(good) if good.size else np.zeros(0, bool), float(dp[best]), float(dphi[best])


def environment_from_dict(doc: Any, source: Any = None) -> Environment:
    """Validate a parsed environment document; ArmbridgeError names the first problem."""
    ctx = Ctx(source, "environment")
    name, description = header(doc, ctx, FORMAT, VERSION, _TOP, ("robot", "obstacles", "start", "goal"), "env")
    arm = _robot(doc["robot"], ctx)
    n = arm.n

    obs = doc["obstacles"]
    if not isinstance(obs, list):
        raise ctx.err("obstacles must be a list of polygons")
    obstacles = [obstacle(p, i, ctx) for i, p in enumerate(obs)]
    checker = CollisionChecker.create(arm, obstacles)
    margin = None
    if "margin" in doc:
        value = number(doc["margin"], "margin (m)", ctx)
        try:
            margin = check_margin(value, "margin")
        except ArmbridgeError as exc:
            raise ctx.err(str(exc)) from None

    start = vector(doc["start"], n + 1, "start", ctx)
    why = _describe_q(arm, start)
    if why:
        raise ctx.err(f"start configuration is infeasible: {why}")
    hit = checker.first_hit(start)
    if hit is not None:
        raise ctx.err(f"start configuration is in collision: link {hit[1] + 1} is within "
                      f"{fmt(checker.margin)} m (half the link width) of obstacles[{hit[0]}]")

    goal = doc["goal"]
    if not isinstance(goal, dict):
        raise ctx.err("goal must be an object with pose (x, y, phi) and optionally q, e_p, e_phi")
    for key in goal:
        if key not in _GOAL:
            raise ctx.err(f'goal: unknown field "{key}" (allowed: {", ".join(_GOAL)})')
    if "pose" not in goal:
        raise ctx.err('goal: missing field "pose" ([x, y, phi] in m, m, rad)')
    pose = vector(goal["pose"], 3, "goal.pose", ctx)
    e_p = float(vector([goal.get("e_p", E_P)], 1, "goal.e_p", ctx)[0])
    e_phi = float(vector([goal.get("e_phi", E_PHI)], 1, "goal.e_phi", ctx)[0])
    if e_p <= 0 or e_phi <= 0:
        raise ctx.err(f"goal tolerances must be > 0, got e_p = {fmt(e_p)} m, e_phi = {fmt(e_phi)} rad")
    reach = float(np.hypot(pose[0], pose[1]))
    if reach > arm.total_length + e_p:
        raise ctx.err(f"goal pose ({fmt(pose[0])}, {fmt(pose[1])}, {fmt(pose[2])}) is out of reach: "
                      f"{fmt(reach)} m from the base, the arm reaches {fmt(arm.total_length)} m")
    goal_q = None
    if "q" in goal:
        goal_q = vector(goal["q"], n + 1, "goal.q", ctx)
        why = _describe_q(arm, goal_q)
        if why:
            raise ctx.err(f"goal.q is infeasible: {why}")
        clear = float(arm.joint_clearance(goal_q[-1]))
        if not arm.holds_margin(goal_q[-1]):
            raise ctx.err(f"goal.q puts the MA {fmt(clear * 1e3)} mm from a joint, inside the robot's "
                          f"d_margin = {fmt(arm.d_margin * 1e3)} mm (its localisation bound)")
        dp_q, dphi_q = (float(v) for v in arm.span_pose_errors(goal_q, pose))
        if not (dp_q <= e_p and dphi_q <= e_phi):
            raise ctx.err(f"goal.q puts the MA {fmt(dp_q * 1e3)} mm and {fmt(math.degrees(dphi_q))} deg "
                          f"from the goal pose, outside e_p = {fmt(e_p * 1e3)} mm, "
                          f"e_phi = {fmt(math.degrees(e_phi))} deg (eq. 9, for every d within "
                          f"d_margin = {fmt(arm.d_margin * 1e3)} mm)")
        hit = checker.first_hit(goal_q)
        if hit is not None:
            raise ctx.err(f"goal.q is in collision: link {hit[1] + 1} touches obstacles[{hit[0]}]")
    else:
        good, free, dp, dphi = find_goal_configs(arm, pose, checker, e_p=e_p, e_phi=e_phi, extra_starts=start)
        if good.shape[0] == 0:
            raise ctx.err(
                f"goal pose ({fmt(pose[0])}, {fmt(pose[1])}, {fmt(pose[2])}) is out of reach: no configuration "
                f"within the joint limits puts the MA within e_p = {fmt(e_p * 1e3)} mm and "
                f"e_phi = {fmt(math.degrees(e_phi))} deg of it with d at least d_margin = "
                f"{fmt(arm.d_margin * 1e3)} mm from every joint (closest found: {fmt(dp * 1e3)} mm, "
                f"{fmt(math.degrees(dphi))} deg)")
        if not np.any(free):
            raise ctx.err(f"goal pose ({fmt(pose[0])}, {fmt(pose[1])}, {fmt(pose[2])}) is blocked: every "
                          f"configuration found that reaches it ({good.shape[0]}) collides with an obstacle")
        cand = good[free]
        goal_q = cand[int(np.argmin(arm.action_cost(start, cand)))]

    known = None
    if "known_path" in doc:
        kp = doc["known_path"]
        if not isinstance(kp, list) or len(kp) < 2:
            raise ctx.err("known_path must be a list of at least 2 configurations")
        known = np.array([vector(q, n + 1, f"known_path[{k}]", ctx) for k, q in enumerate(kp)])
    prov = doc.get("provenance", {})
    if not isinstance(prov, dict):
        raise ctx.err("provenance must be an object")
    env = Environment(name=name, arm=arm, obstacles=obstacles, start=start, goal_pose=pose, goal_q=goal_q,
                      e_p=e_p, e_phi=e_phi, description=description, known_path=known, provenance=dict(prov),
                      source=Path(source) if source is not None else None, margin=margin)
    env._checkers[(SWEEP_RES, None)] = checker
    return env


def load_environment(path: Any) -> Environment:
    """Read and validate an environment file (or a fixed name E1/E2/E3)."""
    if isinstance(path, str) and path.upper() in FIXED and not Path(path).exists():
        return fixed_environment(path)
    doc = read_json(path, "environment file", f" (fixed environments: {', '.join(FIXED)})")
    return environment_from_dict(doc, Path(path))


def save_environment(env: Environment, path: Any) -> Path:
    path = Path(path)
    doc = env.to_dict()
    environment_from_dict(json.loads(json.dumps(doc)), path)  # never write what we would refuse
    lines = ["{"]
    items = list(doc.items())
    for i, (k, v) in enumerate(items):
        end = "," if i < len(items) - 1 else ""
        if k in ("obstacles", "known_path"):
            inner = ",\n".join("    " + json.dumps(p) for p in v)
            lines.append(f'  "{k}": [\n{inner}\n  ]{end}')
        else:
            lines.append(f"  {json.dumps(k)}: {json.dumps(v)}{end}")
    lines.append("}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def fixed_environment(name: str) -> Environment:
    """One of the shipped environments E1, E2, E3 (host/armbridge/planning/masr/envs/)."""
    key = name.upper()
    if key not in FIXED:
        raise ArmbridgeError(f"unknown fixed environment {name!r} (known: {', '.join(FIXED)})")
    return _fixed(key)


@lru_cache(maxsize=None)
def _fixed(key: str) -> Environment:
    return load_environment(ENV_DIR / f"{key}.json")
