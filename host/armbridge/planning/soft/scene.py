"""Planar-chain planning scenes: a robot at a base pose among polygons, a start and a tip goal (JSON).

    scene = fixed_scene("three-arm")                  # or load_scene("mine.json"), horn_scene(7)
    result = planners.plan(scene, "wjrrt", seed=0)    # planning.soft.planners
    save_scene(scene, "mine.json")

File format (docs/planning-soft.md): `"format": "armbridge-chain-env"`,
version 1; lengths in m, angles in rad. A scene carries its planner
defaults in "params" (the WJRRT paper's iterations, C1, C2, lambda, k, P_G)
and may carry "margin" (m): the clearance its plans keep from every
obstacle, else the robot's execution margin (margin.execution_margin: the
pump controller's joint tolerance through the chain). `scene.checker()` is
the touch check (margin 0); `scene.planning_checker()` and
`scene.problem()` keep the margin.
Loading validates and stops at the first problem with one ArmbridgeError
naming the file, the field and the allowed range.
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
from armbridge.planning.base import Problem
from armbridge.planning.envfile import Ctx, fmt, header, number, obstacle, vector
from armbridge.planning.soft.ik import goal_configs
from armbridge.planning.margin import MARGIN_MAX_M
from armbridge.planning.soft.margin import execution_margin
from armbridge.planning.soft.space import EDGE_RES, FREE, LIMITS, ChainChecker, ChainSpace
from armbridge.robots.catalog import get_robot, is_registered, robot_from_dict, robot_to_dict
from armbridge.robots.planar import PlanarChain

FORMAT = "armbridge-chain-env"
VERSION = 1
SCENE_DIR = Path(__file__).with_name("scenes")
FIXED = ("two-arm", "three-arm", "seven-tube", "horn")
#: Random starts of the goal search (ik.goal_configs) when a file gives no goal.q.
IK_STARTS = 64

_TOP = ("format", "version", "name", "description", "robot", "base", "link_width", "margin", "obstacles", "start",
        "goal", "params", "provenance")
_GOAL = ("point", "tol", "q")
#: params key -> (lowest, highest, integer?): the planner defaults a scene may carry (docs/planning-soft.md).
PARAM_RANGES: dict[str, tuple[float, float, bool]] = {
    "iterations": (1, 1_000_000, True),
    "p_goal": (0.0, 1.0, False),
    "C1": (0.0, math.inf, False),
    "C2": (0.0, math.inf, False),
    "lambda": (0.0, math.inf, False),
    "k": (0.0, 1.0, False),
    "dx": (1e-6, 10.0, False),
    "step": (1e-6, math.pi, False),
    "d_min": (0.0, 1.0, False),
    "goal_tries": (1, 1000, True),
}


@dataclass(eq=False)
class TipGoal:
    """Arrived when the tip is within tol (m) of point: the goal of WJRRT's Algorithm 2 (X_G and its radius)."""

    checker: ChainChecker
    point: np.ndarray
    tol: float

    def distance(self, q: np.ndarray) -> float:
        return float(np.linalg.norm(self.checker.tip(q) - self.point))

    def is_satisfied(self, q: np.ndarray) -> bool:
        return self.distance(q) <= self.tol


@dataclass(eq=False)
class Scene:
    """A validated planning scene (module doc). obstacles: (k, 2) vertex arrays, a 2-vertex one a wall."""

    name: str
    robot: PlanarChain
    base: np.ndarray
    link_width: float
    obstacles: list
    start: np.ndarray
    goal_point: np.ndarray
    goal_tol: float
    goal_q: Optional[np.ndarray] = None
    params: dict = field(default_factory=dict)
    description: str = ""
    provenance: dict = field(default_factory=dict)
    source: Optional[Path] = None
    goal_states: Optional[np.ndarray] = field(default=None, repr=False)
    margin: Optional[float] = None
    _goals: dict = field(default_factory=dict, repr=False, init=False)

    @property
    def planning_margin(self) -> float:
        """The clearance plans keep from every obstacle (m): the scene's margin, else the robot's
        execution margin (margin.execution_margin)."""
        return float(self.margin) if self.margin is not None else execution_margin(self.robot)

    def checker(self, res: float = EDGE_RES, link_width: Optional[float] = None, certified: bool = True,
                margin: float = 0.0) -> ChainChecker:
        """A fresh checker (its own `checks` count): certified edges (space.py), probing at res (m); with
        certified=False edges are only checked at resolution res. margin (m): the clearance every link
        must keep (0: the touch check; planning_checker() keeps the scene's)."""
        w = self.link_width if link_width is None else link_width
        return ChainChecker.create(self.robot, self.obstacles, base=self.base, link_width=w, res=res,
                                   certified=certified, margin=margin)

    def planning_checker(self, res: float = EDGE_RES, certified: bool = True,
                         margin: Optional[float] = None) -> ChainChecker:
        """checker() keeping the planning margin (or `margin`, m): what planners and smoothing check with."""
        return self.checker(res, certified=certified, margin=self.planning_margin if margin is None else margin)

    def space(self) -> ChainSpace:
        return ChainSpace(np.array(self.robot.q_min), np.array(self.robot.q_max))

    def find_goal_states(self, checker: Optional[ChainChecker] = None) -> np.ndarray:
        """goal_q (if valid for `checker`) and the goal configurations the tip descent finds valid for it
        (ik.py); cached per link width and margin. Default: the planning checker."""
        chk = checker or self.planning_checker()
        key = (round(chk.link_width, 12), round(chk.margin, 12))
        if key not in self._goals:
            if self.goal_states is not None and key == (round(self.link_width, 12), 0.0):
                self._goals[key] = self.goal_states  # what loading found with the touch check
            else:
                found, _ = goal_configs(chk, self.goal_point, self.goal_tol, starts=IK_STARTS, extra=self.start)
                known = [] if self.goal_q is None or not chk.is_valid(self.goal_q) else [self.goal_q]
                self._goals[key] = np.array(known + list(found)).reshape(-1, self.robot.n)
        return self._goals[key]

    def problem(self, res: float = EDGE_RES, margin: Optional[float] = None) -> Problem:
        """The planning query: the space, planning_checker(res, margin=margin), the start, the tip goal and
        the goal configurations valid with that margin. ArmbridgeError when the start keeps less."""
        checker = self.planning_checker(res, margin=margin)
        if not checker.is_valid(self.start):
            raise ArmbridgeError(f"{self.name}: the start keeps {checker.clearance(self.start) * 1000:.1f} mm from "
                                 f"the obstacles, less than the {checker.margin * 1000:g} mm clearance margin "
                                 f"({checker.describe(checker.code(self.start))}); plan with a smaller margin")
        return Problem(self.space(), checker, self.start.copy(), TipGoal(checker, self.goal_point, self.goal_tol),
                       self.find_goal_states(checker).copy(), name=self.name)

    def to_dict(self) -> dict[str, Any]:
        goal: dict[str, Any] = {"point": [float(v) for v in self.goal_point], "tol": float(self.goal_tol)}
        if self.goal_q is not None:
            goal["q"] = [float(v) for v in self.goal_q]
        d: dict[str, Any] = {"format": FORMAT, "version": VERSION, "name": self.name}
        if self.description:
            d["description"] = self.description
        d["robot"] = self.robot.name if is_registered(self.robot) else robot_to_dict(self.robot)
        d["base"] = [float(v) for v in self.base]
        d["link_width"] = float(self.link_width)
        if self.margin is not None:
            d["margin"] = float(self.margin)
        d["obstacles"] = [[[float(x), float(y)] for x, y in p] for p in self.obstacles]
        d["start"] = [float(v) for v in self.start]
        d["goal"] = goal
        d["params"] = dict(self.params)
        if self.provenance:
            d["provenance"] = dict(self.provenance)
        return d


# ------------------------------------------------------------------ validation
def _robot(spec: Any, ctx: Ctx) -> PlanarChain:
    try:
        robot = get_robot(spec) if isinstance(spec, str) else robot_from_dict(spec)
    except ArmbridgeError as exc:
        raise ctx.err(f"robot: {exc}") from None
    if not isinstance(robot, PlanarChain):
        raise ctx.err(f"robot: {robot.name!r} is a {robot.kind} robot; a chain scene needs a planar chain")
    return robot


def _params(doc: Any, ctx: Ctx) -> dict[str, Any]:
    if not isinstance(doc, dict):
        raise ctx.err("params must be an object of planner defaults")
    out: dict[str, Any] = {}
    for key, v in doc.items():
        if key not in PARAM_RANGES:
            raise ctx.err(f'params: unknown field "{key}" (allowed: {", ".join(PARAM_RANGES)})')
        lo, hi, integer = PARAM_RANGES[key]
        x = number(v, f"params.{key}", ctx)
        if integer and x != int(x):
            raise ctx.err(f"params.{key} must be a whole number, got {v}")
        if not lo <= x <= hi:
            raise ctx.err(f"params.{key} = {fmt(x) if abs(x) >= 1e-4 else x} is outside [{lo}, {hi}]")
        out[key] = int(x) if integer else x
    return out


def _config(v: Any, robot: PlanarChain, where: str, ctx: Ctx, checker: ChainChecker) -> np.ndarray:
    """A configuration inside the joint limits and free of collisions."""
    q = vector(v, robot.n, where, ctx)
    code = checker.code(q)
    if code == LIMITS:
        j = int(np.flatnonzero((q < robot.q_min) | (q > robot.q_max))[0])
        lo, hi = robot.q_min[j], robot.q_max[j]
        raise ctx.err(f"{where}[{j}] = {fmt(q[j])} rad is outside {robot.joint_names[j]}'s range "
                      f"[{fmt(lo)}, {fmt(hi)}] rad ({fmt(math.degrees(lo))} to {fmt(math.degrees(hi))} deg)")
    if code != FREE:
        raise ctx.err(f"{where} is in collision: {checker.describe(code)} (obstacles[] counts from 0; link width "
                      f"{fmt(checker.link_width)} m)")
    return q


def scene_from_dict(doc: Any, source: Any = None) -> Scene:
    """Validate a parsed scene document; ArmbridgeError names the first problem."""
    ctx = Ctx(source, "scene")
    name, description = header(doc, ctx, FORMAT, VERSION, _TOP, ("robot", "obstacles", "start", "goal"), "scene")
    robot = _robot(doc["robot"], ctx)
    base = vector(doc.get("base", [0.0, 0.0, 0.0]), 3, "base ([x, y, heading] in m, m, rad)", ctx)
    width = number(doc.get("link_width", 0.0), "link_width", ctx)
    if width < 0:
        raise ctx.err(f"link_width = {fmt(width)} m is outside [0, inf)")
    margin = None
    if "margin" in doc:
        margin = number(doc["margin"], "margin", ctx)
        if not 0 <= margin <= MARGIN_MAX_M:
            raise ctx.err(f"margin = {margin * 1000:g} mm is outside [0, {MARGIN_MAX_M * 1000:g}] mm")
    if not isinstance(doc["obstacles"], list):
        raise ctx.err("obstacles must be a list of polygons and walls")
    obstacles = [obstacle(p, i, ctx, walls=True) for i, p in enumerate(doc["obstacles"])]
    checker = ChainChecker.create(robot, obstacles, base=base, link_width=width)
    start = _config(doc["start"], robot, "start", ctx, checker)

    goal = doc["goal"]
    if not isinstance(goal, dict):
        raise ctx.err("goal must be an object with point ([x, y], m), tol (m) and optionally q")
    for key in goal:
        if key not in _GOAL:
            raise ctx.err(f'goal: unknown field "{key}" (allowed: {", ".join(_GOAL)})')
    for key in ("point", "tol"):
        if key not in goal:
            raise ctx.err(f'goal: missing field "{key}"')
    point = vector(goal["point"], 2, "goal.point", ctx)
    tol = number(goal["tol"], "goal.tol", ctx)
    if not 0 < tol <= robot.reach:
        raise ctx.err(f"goal.tol = {fmt(tol) if tol >= 1e-4 else tol} m is outside (0, {fmt(robot.reach)}] "
                      "(the robot's reach)")
    far = float(np.hypot(*(point - base[:2])))
    if far > robot.reach + tol:
        raise ctx.err(f"goal.point ({fmt(point[0])}, {fmt(point[1])}) is out of reach: {fmt(far)} m from the "
                      f"base, the arm reaches {fmt(robot.reach)} m")
    goal_q = None
    if "q" in goal:
        goal_q = _config(goal["q"], robot, "goal.q", ctx, checker)
        miss = float(np.linalg.norm(checker.tip(goal_q) - point))
        if miss > tol:
            raise ctx.err(f"goal.q puts the tip {fmt(miss)} m from goal.point, outside goal.tol = {fmt(tol)} m")
    params = _params(doc.get("params", {}), ctx)
    prov = doc.get("provenance", {})
    if not isinstance(prov, dict):
        raise ctx.err("provenance must be an object")
    scene = Scene(name, robot, base, width, obstacles, start, point, tol, goal_q, params, description, dict(prov),
                  Path(source) if source is not None else None, margin=margin)
    if goal_q is None:
        found, best = goal_configs(checker, point, tol, starts=IK_STARTS, extra=start)
        if found.shape[0] == 0:
            raise ctx.err(f"goal.point ({fmt(point[0])}, {fmt(point[1])}): the tip descent from {IK_STARTS} random "
                          f"starts found no collision-free configuration within goal.tol = {fmt(tol)} m of it "
                          f"(closest tip: {fmt(best)} m, in collision or outside the joint limits); if the goal is "
                          "reachable, give one as goal.q")
        scene.goal_states = found
    return scene


def load_scene(path: Any) -> Scene:
    """Read and validate a scene file (or a fixed scene's name, see FIXED)."""
    if isinstance(path, str) and path in FIXED and not Path(path).exists():
        return fixed_scene(path)
    doc = read_json(path, "scene file", f" (fixed scenes: {', '.join(FIXED)})")
    return scene_from_dict(doc, Path(path))


def save_scene(scene: Scene, path: Any) -> Path:
    """Write scene as JSON (one obstacle per line); refuses what load_scene would refuse."""
    path = Path(path)
    doc = scene.to_dict()
    scene_from_dict(json.loads(json.dumps(doc)), path)
    lines = []
    for k, v in doc.items():
        if k == "obstacles":
            inner = ",\n".join("    " + json.dumps(p) for p in v)
            lines.append(f'  "{k}": [\n{inner}\n  ]' if v else f'  "{k}": []')
        else:
            lines.append(f"  {json.dumps(k)}: {json.dumps(v)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("{\n" + ",\n".join(lines) + "\n}\n", encoding="utf-8")
    return path


def fixed_scene(name: str) -> Scene:
    """One of the shipped scenes (FIXED; host/armbridge/planning/soft/scenes/)."""
    if name not in FIXED:
        raise ArmbridgeError(f"unknown fixed scene {name!r} (known: {', '.join(FIXED)})")
    return _fixed(name)


@lru_cache(maxsize=None)
def _fixed(name: str) -> Scene:
    return load_scene(SCENE_DIR / f"{name}.json")


# ------------------------------------------------------------------ OMPL's horn
def horn_walls(n: int, eps: float) -> list[np.ndarray]:
    """The 2 (n - 1) wall segments of OMPL's createHornEnvironment(n, eps) (demos/KinematicChain.h).

    Two walls start at (1/n, -eps) and (1/n, +eps) and turn by pi/n per
    segment, as the start configuration's chain does; the outer (lower) one
    has segments of (1/n)(1 + pi eps), the inner one (1/n)(1 - pi eps), so
    the passage between them narrows along the horn.
    """
    walls = []
    w = 1.0 / n
    for y0, scale in ((-eps, w * (1.0 + math.pi * eps)), (eps, w * (1.0 - math.pi * eps))):
        x, y, th = w, y0, 0.0
        for _ in range(n - 1):
            th += math.pi / n
            xn, yn = x + math.cos(th) * scale, y + math.sin(th) * scale
            walls.append(np.array([[x, y], [xn, yn]]))
            x, y = xn, yn
    return walls


#: Tip tolerance of the horn's goal (its chain reaches 1): OMPL asks for the goal state itself.
HORN_TOL = 0.01


def horn_scene(n: int = 7, params: Optional[dict] = None) -> Scene:
    """OMPL's kinematic-chain benchmark (demos/KinematicChainBenchmark.cpp) as a scene.

    n links of 1/n (limits [-pi, pi], width 0: OMPL's segments), walls
    horn_walls(n, log(n)/n), start [0, pi/n, ..., pi/n] (curled inside the
    horn), goal q [pi - 0.001, 0, ..., 0] (straight out behind the base);
    the goal point is that q's tip, within HORN_TOL.
    """
    if not (isinstance(n, int) and 2 <= n <= 64):
        raise ArmbridgeError(f"horn_scene: n = {n!r} links is outside [2, 64]")
    robot = PlanarChain(name=f"horn{n}", link_lengths=np.full(n, 1.0 / n), q_min=np.full(n, -math.pi),
                        q_max=np.full(n, math.pi), v_max=np.ones(n), joint_names=tuple(f"j{i + 1}" for i in range(n)))
    start = np.full(n, math.pi / n)
    start[0] = 0.0
    goal_q = np.zeros(n)
    goal_q[0] = math.pi - 0.001
    doc = {"format": FORMAT, "version": VERSION, "name": "horn" if n == 7 else f"horn-{n}",
           "description": f"OMPL's horn (KinematicChainBenchmark) for {n} links of 1/{n}: out of a narrowing "
                          "curved passage",
           "robot": robot_to_dict(robot), "base": [0.0, 0.0, 0.0], "link_width": 0.0,
           "obstacles": [p.tolist() for p in horn_walls(n, math.log(n) / n)], "start": start.tolist(),
           "goal": {"point": robot.ee_point(goal_q).tolist(), "tol": HORN_TOL, "q": goal_q.tolist()},
           "params": dict(params or {}),
           "provenance": {"tool": "armbridge.planning.soft.scene.horn_scene", "n": n,
                          "after": "OMPL demos/KinematicChain.h createHornEnvironment(n, log(n)/n)"}}
    return scene_from_dict(doc, f"horn_scene({n})")
