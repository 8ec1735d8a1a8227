"""The drawing error of "ROBOTICS" on the emulated arm, on each rig (issue 10 §5).

The paper's sample 9 (Table 3, text "ROBOTICS") is built as `armbridge draw
--sample text-robotics` builds it (fitted to the safe region, vpype-tidied,
closed-form joint plan at the pen speed), then run with `run_plan` on
`emu:esp32` at full emulator speed, once per rig:

* effort: continuous servos with potentiometer feedback, the board's PIDs;
* pca9685: the paper's rig (section 4.1): positional hobby servos behind a
  PCA9685, the servos closing their own loops;

each with the pen-lift servo, once more on the effort rig with
`--cartesian` (the board solving every waypoint with its int8 net + FABRIK),
when the board has its IK weights, and once on the effort rig with the plan's
joints from the paper's ANN + FABRIK + CBF (`armbridge draw --ik paper`). The numbers are the run summary's
`drawing` section (plans/drawing.py): the trace's distance from the strokes and
the reverse, mean and max, and the time per character.
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

RIGS = ("effort", "pca9685")
SAMPLE = "text-robotics"


def robotics_plan(speed: float, ik: str = "closed"):
    """The ROBOTICS sample's drawing plan at pen speed `speed` (m/s), its joints by `ik`
    (closed or paper, as `armbridge draw --ik`)."""
    from armbridge.draw.build import build
    from armbridge.draw.sources import characters
    from armbridge.draw.samples import SAMPLES, sample_lines
    from armbridge.robots import get_robot

    d = build(sample_lines(SAMPLE), get_robot("arm3r"), name=SAMPLE, source=f"sample {SAMPLE}", speed=speed, ik=ik)
    d.plan.provenance["drawing"]["characters"] = characters(SAMPLES[SAMPLE].plot)
    return d.plan


def drawing_runs(speed: float = 0.03, work: Path | None = None, rigs: tuple[str, ...] = RIGS,
                 cartesian: bool = True, paper: bool = True,
                 progress: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """Runs the ROBOTICS plan on each rig (and with the board's IK, and planned by the paper's
    pipeline) -> their drawing reports."""
    import tempfile

    from armbridge.executor.run import RunFailed, run_plan

    plans = {"closed": robotics_plan(speed)}
    plan = plans["closed"]
    runs: list[tuple[str, str, bool, str]] = [(rig, f"emu:esp32?speed=0&servos={rig}", False, "closed")
                                              for rig in rigs]
    if cartesian:
        runs.append(("effort, board IK (--cartesian)", "emu:esp32?speed=0", True, "closed"))
    if paper:
        plans["paper"] = robotics_plan(speed, "paper")
        runs.append(("effort, --ik paper", "emu:esp32?speed=0", False, "paper"))
    out: dict[str, Any] = {"sample": SAMPLE, "speed_m_s": speed, "waypoints": plan.k,
                           "planned_s": plan.total_duration, "runs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(work) if work is not None else Path(tmp)
        for name, url, cart, ik in runs:
            progress(f"drawing ROBOTICS on {name}")
            try:
                s = run_plan(plans[ik], url, folder / f"robotics-{len(out['runs'])}.rrd", progress=False,
                             cartesian=cart)
            except RunFailed as exc:
                out["runs"][name] = {"completed": False, "error": str(exc)}
                continue
            out["runs"][name] = {"completed": s.completed, "pen": s.pen, "ik": s.ik, "plan_ik": ik,
                                 "measured_s": s.measured_duration_s, **(s.drawing or {})}
    return out
