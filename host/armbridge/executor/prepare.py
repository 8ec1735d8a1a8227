"""What a run prepares before it streams (executor/run.py): the drawing's safety filter on the commands,
the Cartesian rows of `--cartesian` and the board's IK probe, and the pen flags the board can take."""
from __future__ import annotations

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.executor.client import BoardClient
from armbridge.executor.summary import Summary
from armbridge.link import protocol as P
from armbridge.plans.format import Plan

PEN_MODES = ("auto", "on", "off")


def safety_filter(plan: Plan) -> tuple[Plan, dict | None]:
    """The discrete CBF (ik/cbf_filter.py) on what a drawing streams, whoever made
    the plan (issue 23 section 3: the barrier acts on the commands, not only on
    the plan): a plan with pen flags for the 3R drawing arm gets its waypoints
    filtered onto the safe disc less the margin its pen needs (the margin its
    drawing recorded, else `margin_for` its fastest pen-down segment). A plan
    `armbridge draw` made is filtered already and filtering twice is filtering
    once, so it streams as it is; a hand-written one that leaves the disc is
    pulled in, and its summary reports the executed pen against the disc.
    -> (the plan to stream, the filter's report or None)."""
    from armbridge.robots.planar import PlanarChain

    if plan.pen is None or plan.robot.name != "arm3r" or not isinstance(plan.robot, PlanarChain):
        return plan, None
    from dataclasses import replace

    from armbridge.ik.cbf_filter import filter_joints
    from armbridge.ik.region import margin_for, safe_region

    robot = plan.robot
    margin = (plan.provenance.get("drawing") or {}).get("margin")
    if not isinstance(margin, (int, float)):
        xy = np.asarray(robot.ee_point(plan.q))[:, :2]
        seg = np.hypot(*np.diff(xy, axis=0).T) / np.asarray(plan.durations[1:], float)
        down = np.asarray(plan.pen[1:], bool)
        margin = margin_for(float(seg[down].max(initial=0.0)))
    reg = safe_region(robot)
    q, report = filter_joints(robot, reg, plan.q, float(margin))
    drawing = dict(plan.provenance.get("drawing") or {})
    drawing.setdefault("safe_region", {"center": list(reg.center), "radius": reg.radius})  # the summary reports it
    plan = replace(plan, q=q, provenance={**plan.provenance, "drawing": drawing})
    return plan, {**report.to_dict(), "margin_m": float(margin)}


def cartesian_rows(plan: Plan) -> list[list[int]]:
    """The plan's waypoints as X arguments: the tip's x, y (um) and theta = the sum
    of the joint angles (mrad, unwrapped) by FK. Only a planar chain has them."""
    robot = plan.robot
    if not hasattr(robot, "ee_point") or getattr(robot, "kind", "planar") != "planar":
        raise ArmbridgeError(f"--cartesian needs a planar arm; the plan's robot {robot.name!r} is not one")
    xy = np.asarray(robot.ee_point(plan.q), dtype=float).reshape(-1, 2)
    theta = plan.q.sum(axis=1)
    rows = np.column_stack([np.rint(xy * 1e6), np.rint(theta * 1e3)]).astype(int)
    return rows.tolist()


def check_board_ik(client: BoardClient) -> None:
    """--cartesian needs a board that solves X itself. Asked with an X far outside any
    arm's safe region, which moves nothing: REACH says the board has its IK, VERB that
    it has none (no weights on its filesystem, or a firmware without the verb)."""
    ans = client.ask("X", 0, 1, -1000000, -1000000, 0)
    if isinstance(ans, P.Er) and ans.code == P.REACH:
        return
    if isinstance(ans, P.Er) and ans.code == P.VERB:
        raise ArmbridgeError("--cartesian: the board cannot solve Cartesian waypoints (it refused X with VERB: "
                             "no IK weights on its filesystem, or a firmware without the board IK)")
    raise ArmbridgeError(f"--cartesian: the board answered a probe X outside its safe region with {ans}; "
                         "expected REACH")


def pen_flags(client: BoardClient, plan: Plan, mode: str, summary: Summary) -> list[int] | None:
    """The pen flags to stream as PEN lines, or None (no flags, no servo, or --pen off).
    Asking the board `PEN 0` lifts the pen before the first move: harmless, and the answer
    says whether it has the servo."""
    if plan.pen is None:
        return None
    if mode != "off" and client.can("PEN", 0):
        summary.pen = "servo"
        return [int(x) for x in plan.pen]
    if mode == "on":
        raise ArmbridgeError("the board has no pen-lift servo (it refused PEN with VERB); "
                             "run with --pen auto or off to draw with pen-up moves only marked")
    summary.pen = "marked"
    return None
