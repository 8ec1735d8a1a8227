"""MASR plans for the planning tools: written by the planners, read back with their environment.

A MASR plan is an ordinary plan file (plans/format.py) whose `masr` section holds
the MA's actions, tau and goal (plans/masr.py: what the executor reads, checked
from the robot alone). The planning tools also want the environment back, and
the path checked against its obstacles again (along the motion convention):
`load_masr_plan` does both on top of the plan's own checks.

    save_masr_plan(env, path, "plan.json", provenance={...})   # path (K, n+1) from the planner
    plan = load_masr_plan("plan.json")                          # -> MasrPlan, validated
    plan.q, plan.tau, plan.actions, plan.steps(), plan.env, plan.plan (the Plan)

Each action k -> k+1 lists the steps of MasrArm.action_sequence with their
durations (move |d_to - d_from| / d-dot, rotate |theta_to - theta_from| /
theta-dot); the durations of an action sum to its cost c(a), eq. (8), and all
of them to tau, eq. (7). The last waypoint must be executable by a real MA: its
d at least the robot's d_margin (the MA's localisation bound) from every joint,
and, with a goal, the goal check (eq. 9) must hold for every d within that
margin (MasrArm.span_pose_errors: exact by checking the interval's ends).
Files of the old sibling format (`armbridge-masr-plan`, version 1) load too.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.jsonfile import read_json
from armbridge.planning.masr.environment import Environment, environment_from_dict
from armbridge.plans import masr as M
from armbridge.plans.format import DURATION_MIN, Plan, plan_from_dict, plan_to_dict, save_plan, validate
from armbridge.robots.masr import MasrArm


@dataclass
class MasrPlan:
    """A validated MASR plan (its Plan, and its environment rebuilt): q (K, n+1), tau (K,)
    cumulative action time in s."""

    plan: Plan
    env: Optional[Environment] = None

    @property
    def arm(self) -> MasrArm:
        return self.plan.robot  # type: ignore[return-value]

    @property
    def q(self) -> np.ndarray:
        return self.plan.q

    @property
    def tau(self) -> np.ndarray:
        return M.tau(self.plan)

    @property
    def actions(self) -> list:
        return self.plan.masr["actions"]  # type: ignore[index]

    @property
    def provenance(self) -> dict:
        return self.plan.provenance

    @property
    def source(self) -> Optional[Path]:
        return self.plan.source

    @property
    def total_time(self) -> float:
        """tau of the whole path, eq. (7), in s."""
        return M.total_time(self.plan)

    def steps(self) -> list[dict]:
        """Every MA step of the plan in order (move / rotate dicts with durations)."""
        return M.steps(self.plan)


def _unchecked(env: Environment, path: Any, provenance: Optional[dict]) -> Plan:
    """The Plan along `path` for `env`, not yet checked (masr_plan_document hands out a document
    a test may damage before plan_from_document checks it)."""
    from datetime import datetime, timezone

    from armbridge.robots.catalog import is_registered

    arm = env.arm
    P = arm._q(np.asarray(path, dtype=float), "path")
    if P.ndim != 2 or P.shape[0] < 1:
        raise ArmbridgeError(f"a MASR plan needs a path of shape (K, {arm.n + 1}), K >= 1; got {P.shape}")
    costs = arm.action_cost(P[:-1], P[1:]) if P.shape[0] > 1 else np.zeros(0)
    envdoc = env.to_dict()
    envdoc.pop("known_path", None)
    section = M.masr_section(arm, P, envdoc, {"pose": env.goal_pose, "e_p": env.e_p, "e_phi": env.e_phi})
    prov = dict(provenance or {})
    prov.setdefault("tool", "armbridge.planning")
    prov.setdefault("created", datetime.now(timezone.utc).isoformat(timespec="seconds"))
    return Plan(robot=arm, q=P, durations=M.path_durations(costs, DURATION_MIN), provenance=prov,
                inline_robot=not is_registered(arm), masr=section)


def masr_plan(env: Environment, path: Any, provenance: Optional[dict] = None) -> Plan:
    """The Plan along `path` (K, n+1) for `env`, checked: the configuration path, each waypoint's
    duration the action into it, and the masr section (actions, tau, the goal, the environment)."""
    return validate(_unchecked(env, path, provenance))


def masr_plan_document(env: Environment, path: Any, provenance: Optional[dict] = None) -> dict:
    """The JSON document of a plan for env along path (K, n+1), not checked yet."""
    return plan_to_dict(_unchecked(env, path, provenance))


def save_masr_plan(env: Environment, path: Any, out: Any, provenance: Optional[dict] = None) -> Path:
    """Write a MASR plan file (validated first, also against the environment's obstacles)."""
    out = Path(out)
    plan = masr_plan(env, path, provenance)
    _with_environment(plan, out)  # never write what we would refuse
    try:
        return save_plan(plan, out)
    except OSError as exc:
        raise ArmbridgeError(f"{out}: cannot write the plan: {exc.strerror}") from None


def _with_environment(plan: Plan, source: Any) -> MasrPlan:
    """The plan with its environment rebuilt and the path checked against the obstacles again."""
    name = str(source) if source is not None else "<masr plan>"
    if plan.masr is None:
        raise ArmbridgeError(f"{name}: not a MASR plan (no masr section)")
    env = None
    doc = plan.masr.get("environment")
    if doc is not None:
        try:
            env = environment_from_dict(doc, f"{name}: environment")
        except ArmbridgeError as exc:
            raise ArmbridgeError(str(exc)) from None
        if env.arm != plan.robot:
            raise ArmbridgeError(f"{name}: environment: its robot differs from the plan's robot")
        problem = env.checker().path_problem(plan.q)
        if problem:
            raise ArmbridgeError(f"{name}: path collides: {problem}")
    return MasrPlan(plan=plan, env=env)


def plan_from_document(doc: Any, source: Any = None) -> MasrPlan:
    """Validate a parsed MASR plan document (version 2, or the old sibling format), its
    environment rebuilt and its path checked against it; ArmbridgeError names the first problem."""
    return _with_environment(plan_from_dict(doc, source), source)


def load_masr_plan(path: Any) -> MasrPlan:
    """Read and validate a MASR plan file."""
    return plan_from_document(read_json(path, "plan file"), Path(path))
