"""The fault-tolerant demo's additions to the run's Rerun recording (demos/arm3r_ft.py).

task/target, task/smm (the arm along its SMM within the limits), task/recovery,
recovery/path, joint_space/<a>-<b>/smm, /limits, /box and /q (Fig. 2 style
projections on joint planes), joints/<name>/box_lo and box_hi while the
artificial limits hold. The recording opens in `FtLog.layout`: the run's layout with
these in the arm view and the joint planes under it.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr

from armbridge.plans.format import Plan
from armbridge.robots.planar import PlanarChain
from armbridge.smm import bbox
from armbridge.telemetry.recording import Recording

if TYPE_CHECKING:
    from armbridge.demos.arm3r_ft import FtScenario


def _pair(robot: PlanarChain, a: int, b: int) -> str:
    return f"joint_space/{robot.joint_names[a]}-{robot.joint_names[b]}"


class FtLog:
    """The demo's additions to the run's Rerun recording."""

    PAIRS = ((0, 1), (1, 2), (0, 2))

    def __init__(self, rec: Recording, robot: PlanarChain, sc: FtScenario, lims: bbox.Limits) -> None:
        self.rec = rec
        self.stream = rec.rec
        self.robot = robot
        self.sc = sc
        self.lims = lims
        self._static()

    def _pair(self, a: int, b: int) -> str:
        return _pair(self.robot, a, b)

    @classmethod
    def layout(cls, robot: PlanarChain) -> Any:
        """The recording's layout: the run's (telemetry.layout.run_layout) with the task, the SMMs and
        the recovery in the arm view and one view per joint plane under it."""
        from rerun import blueprint as rrb

        from armbridge.telemetry.layout import run_layout

        planes = [rrb.Spatial2DView(origin=_pair(robot, a, b), name=_pair(robot, a, b).split("/")[1])
                  for a, b in cls.PAIRS]
        return run_layout(robot, spatial=("task/**", "recovery/**"), views=planes)

    def _static(self) -> None:
        s, robot = self.stream, self.robot
        s.log("task/target", rr.Points2D([self.sc.x], colors=[(0, 200, 0)], radii=0.006), static=True)
        curves = bbox.smm_curves(self.sc.smm, 0, self.lims)
        arms = [robot.joint_points(c[i]) for c in curves for i in np.linspace(0, len(c) - 1, 6).astype(int)]
        s.log("task/smm", rr.LineStrips2D(arms, colors=[(200, 160, 255)], radii=0.0006), static=True)
        for a, b in self.PAIRS:
            strips = []
            for br in self.sc.smm.branches(0):  # whole branches, cut where they wrap
                cut = np.nonzero(np.abs(np.diff(br[:, [a, b]], axis=0)).max(axis=1) > np.pi)[0] + 1
                strips += [p for p in np.split(br[:, [a, b]], cut) if len(p) > 1]
            s.log(f"{self._pair(a, b)}/smm", rr.LineStrips2D(strips, colors=[(150, 90, 220)], radii=0.01),
                  static=True)
            lo, hi = robot.q_min[[a, b]], robot.q_max[[a, b]]
            s.log(f"{self._pair(a, b)}/limits", rr.Boxes2D(mins=[lo], sizes=[hi - lo], colors=[(90, 90, 90)]),
                  static=True)

    def at(self, t: float) -> None:
        self.stream.set_time("board_time", duration=float(t))

    def box(self, t: float, on: bool) -> None:
        """The artificial joint limits: shown from the SMMs' arrival, released at the failure."""
        self.at(t)
        box = self.sc.approach.box
        lo = bbox.lift(box.lo, self.lims)
        for a, b in self.PAIRS:
            path = f"{self._pair(a, b)}/box"
            if on:
                self.stream.log(path, rr.Boxes2D(mins=[lo[[a, b]]], sizes=[box.width[[a, b]]], colors=[(255, 80, 200)]))
            else:
                self.stream.log(path, rr.Clear(recursive=False))
        if on:  # the joint plots show the box as two lines while it holds
            for j, name in enumerate(self.robot.joint_names):
                for key, v in (("box_lo", lo[j]), ("box_hi", lo[j] + box.width[j])):
                    self.stream.log(f"joints/{name}/{key}", rr.Scalars(float(v)))

    def q(self, t: float, q: np.ndarray) -> None:
        self.at(t)
        for a, b in self.PAIRS:
            self.stream.log(f"{self._pair(a, b)}/q", rr.Points2D([q[[a, b]]], colors=[(255, 140, 0)], radii=0.03))

    def recovery(self, t: float, q_goal: np.ndarray, plan: Plan) -> None:
        self.at(t)
        self.stream.log("task/recovery", rr.LineStrips2D([self.robot.joint_points(q_goal)], colors=[(255, 60, 60)],
                                                         radii=0.002))
        self.stream.log("recovery/path", rr.LineStrips2D([plan.ee_path()], colors=[(255, 60, 60)], radii=0.001))
