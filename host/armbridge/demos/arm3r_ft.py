"""`armbridge demo --robot arm3r --fault-tolerant`: Fig. 15 on the emulated ESP32 arm.

The scenario of section VI-B/VI-C on the bridge's 3R arm (links 0.19, 0.12,
0.07 m; the joint limits of catalog.ARM3R, which SMMs ignore, so boxes and
recovery use the runs of the SMMs within the limits, see
faulttolerant.branch_boxes):

1. A target appears (FK of a random configuration within the limits, drawn
   from `seed`). Its SMMs are computed ('arm3r' SmmArm; by default by the
   shipped learned model smm-arm3r, found through armbridge.resources, or by
   the nullspace method)
   and the time that takes is the latency.
2. The plan: damped least squares toward the target for the latency (the arm
   does not wait for the SMMs, Fig. 15c), then into the SMM bounding box
   reached soonest, then inside it to the SMM configuration reached soonest
   (faulttolerant.approach), all at VMAX rad/s per joint.
3. The plant stalls the joint that moves most inside the box, STALL_FRACTION
   into that motion (EmulatedBoard.schedule_stall, the emulator's stall fault).
   A candidate target whose inside motion leaves the stalled joint less than
   MIN_TRAVEL to go (a stall nobody would notice) is skipped for the next one.
4. The plan is streamed through the executor's BoardClient. The host watches
   the telemetry: a joint whose set point runs more than STALL_RAD ahead of its
   measured position while the others follow is stalled. The session is opened
   with `open_session` like every run: a board latched from before is refused
   unless the user passed `--clear`. The host sends the
   e-stop byte (the board's own following-error FAULT, 350 mrad for 300 ms,
   would come later and is handled the same way), lets the arm come to rest,
   clears the latch (CLR: set point = measured position) and reads the locked
   joint's value.
5. Recovery (section III-A): the SMM configurations with that value, within
   the limits, the nearest by travel time, corrected by a few Gauss-Newton
   steps on the healthy joints; streamed with the locked joint held where it
   stopped. The tip's distance to the target is measured from telemetry and
   from the plant's true positions.

Everything goes into one Rerun recording (telemetry/recording.py entities, and arm3r_ft_log.py's,
plus): task/target, task/smm (the arm along its SMM within the limits),
task/recovery (the arm at the recovery configuration), joint_space/<a>-<b>/smm,
/box and /q (Fig. 2 style projections on joint planes), joints/<name>/box_lo
and box_hi (the artificial limits while they hold), and host events (target,
SMMs ready, stall detected, recovery, result) in `events`.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from armbridge import resources
from armbridge.demos.arm3r_ft_log import FtLog
from armbridge.errors import ArmbridgeError
from armbridge.link import protocol as P
from armbridge.plans.format import Plan, make_plan
from armbridge.robots.catalog import ARM3R
from armbridge.robots.dh import DHChain
from armbridge.robots.planar import PlanarChain
from armbridge.smm import bbox
from armbridge.smm import faulttolerant as ft
from armbridge.smm.arms import get_smm_arm
from armbridge.smm.manifold import SmmSet
from armbridge.smm.simulate import Scenario, dls_path, refine

VMAX = 1.0  # rad/s per joint for every planned motion (the board allows 3)
WAYPOINT_DT = 0.05  # s between the waypoints of a planned motion
STALL_FRACTION = 0.25  # the stall comes this far into the motion inside the box
MIN_TRAVEL = 0.25  # rad the stalled joint must still have to go after the stall
STALL_RAD = 0.1  # rad of following error the host takes for a stalled joint (tracking at 1 rad/s: < 0.025)
SETTLE_S = 0.3  # s of board time for the arm to come to rest after a stop
TOL_M = 0.003  # m: the tip must end this close to the target
CANDIDATES = 20  # targets tried before giving up on a seed
RATE_HZ = 50  # telemetry rate
START_S = 0.02  # s for the first waypoint of a plan: where the arm already is

SmmMethod = Callable[[DHChain, np.ndarray], SmmSet]


MODEL = "smm-arm3r"  # the shipped learned model (armbridge.resources.model_dir)
CORRECT_ITERS = 3  # eq. (18) steps on the learned SMMs


def nullspace_method(arm: DHChain, x: np.ndarray) -> SmmSet:
    """The ground-truth SMMs (section III-B): seconds per location, the Fig. 16 case."""
    from armbridge.smm import nullspace

    return nullspace.compute(arm, x)


def learned_method(folder: Path | None = None) -> SmmMethod:
    """The learned model in folder (None: the shipped one), loaded here, once, outside the timed
    call: milliseconds, Fig. 15."""
    from armbridge.smm.learned import LearnedSmm

    folder = resources.model_dir(MODEL) if folder is None else folder
    if not (folder / "card.json").is_file():
        raise ArmbridgeError(f"no learned SMM model at {folder}; train it with "
                             "`armbridge train smm-3r --robot arm3r`, or use --smm nullspace")
    model = LearnedSmm.load(folder, robot="arm3r")
    return lambda arm, x: model.compute(x, correct_iters=CORRECT_ITERS)


def smm_method(name: str) -> SmmMethod:
    """'learned' or 'nullspace'."""
    if name == "learned":
        return learned_method()
    if name == "nullspace":
        return nullspace_method
    raise ArmbridgeError(f"--smm {name!r}: choose learned or nullspace")


@dataclass(frozen=True)
class FtScenario:
    """The target, its SMMs and the planned approach with the stall to come."""

    x: np.ndarray  # (2,) target, m
    smm: SmmSet
    latency: float  # s the SMMs took (or the latency asked for)
    approach: ft.Approach
    joint: int  # 0-based joint the plant stalls
    stall_after: float  # s from the plan's start
    plan: Plan


def limits(robot: PlanarChain = ARM3R) -> bbox.Limits:
    return robot.q_min.copy(), robot.q_max.copy()


def _segment(move: ft.Move, dt: float = WAYPOINT_DT) -> tuple[np.ndarray, np.ndarray]:
    """A move as waypoints every <= dt s: (q (k, n), durations (k,)), without its start."""
    k = max(1, math.ceil(move.duration / dt))
    f = np.arange(1, k + 1) / k
    return move.start + f[:, None] * (move.goal - move.start), np.full(k, max(move.duration, 1e-3) / k)


def _dls_waypoints(times: np.ndarray, path: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The DLS path (K+1 samples from its start) as waypoints every ~WAYPOINT_DT."""
    step = max(1, int(round(WAYPOINT_DT / (times[1] - times[0])))) if len(times) > 1 else 1
    idx = np.unique(np.r_[np.arange(step, len(times), step), len(times) - 1])
    idx = idx[idx > 0]
    return path[idx], np.diff(np.r_[0.0, times[idx]])


def plan_scenario(x: np.ndarray, smm: SmmSet, latency: float, q0: np.ndarray,
                  robot: PlanarChain = ARM3R) -> FtScenario | None:
    """The approach plan to x and the stall, or None when the target does not
    suit the demo (no box within limits, or too short a motion inside it)."""
    arm = get_smm_arm(robot.name)
    lims = limits(robot)
    curves = bbox.smm_curves(smm, 0, lims)
    if not curves:
        return None
    sc = Scenario(vmax=VMAX)
    if latency > 0:
        times, path = dls_path(arm, q0[None], x[None], latency, sc, lims)
    else:
        times, path = np.zeros(1), q0[None, None]
    path = path[:, 0]
    ap = ft.approach(path[-1], curves, VMAX, lims)
    delta = ap.inside.goal - ap.inside.start
    j = int(np.argmax(np.abs(delta)))
    if (1 - STALL_FRACTION) * abs(delta[j]) < MIN_TRAVEL:
        return None
    parts = [(q0[None], np.array([START_S]))]
    if latency > 0:
        parts.append(_dls_waypoints(times, path))
    parts += [_segment(ap.entry), _segment(ap.inside)] if ap.entry.duration > 0 else [_segment(ap.inside)]
    q = np.clip(np.concatenate([p[0] for p in parts]), robot.q_min, robot.q_max)
    durations = np.concatenate([p[1] for p in parts])
    prov = {"tool": "armbridge demo --fault-tolerant", "name": "demo-fault-tolerant", "target_m": x.tolist(),
            "latency_s": latency, "joint_speed_rad_s": VMAX}
    plan = make_plan(robot, q, durations, prov)
    stall_after = START_S + latency + ap.entry.duration + STALL_FRACTION * ap.inside.duration
    return FtScenario(x, smm, latency, ap, j, stall_after, plan)


def choose_scenario(seed: int, method: SmmMethod, latency: float | None = None,
                    robot: PlanarChain = ARM3R) -> FtScenario:
    """The first target drawn from `seed` that suits the demo. latency None:
    the measured time of `method` on that target; a number fixes it (tests)."""
    arm = get_smm_arm(robot.name)
    rng = np.random.default_rng(seed)
    q0 = (robot.q_min + robot.q_max) / 2  # where the emulated arm starts
    margin = 0.1 * (robot.q_max - robot.q_min)
    for _ in range(CANDIDATES):
        x = np.asarray(arm.task(rng.uniform(robot.q_min + margin, robot.q_max - margin)))
        t0 = time.perf_counter()
        smm = method(arm, x[None])
        took = time.perf_counter() - t0
        if smm.count[0] == 0:
            continue
        found = plan_scenario(x, smm, took if latency is None else latency, q0, robot)
        if found is not None:
            return found
    raise ArmbridgeError(f"seed {seed}: none of {CANDIDATES} targets suits the fault-tolerant demo; try another seed")


@dataclass
class FtResult:
    """What the demo run did. Joints are numbered 1..n, times are board seconds."""

    target: np.ndarray
    latency: float
    stalled_joint: int  # the joint the plant stalled
    detected_joint: int | None = None  # the joint the host found stalled
    detected_by: str | None = None  # 'host' (telemetry) or 'FAULT' (the board's following-error latch)
    locked_value: float = math.nan  # rad
    recovery_s: float = math.nan  # planned duration of the recovery
    tip_error_m: float = math.nan  # from telemetry (what the host measures)
    tip_error_true_m: float = math.nan  # from the plant's true positions
    rrd: Path | None = None
    events: list[str] = field(default_factory=list)

    @property
    def reached(self) -> bool:
        return self.tip_error_true_m <= TOL_M

    def table(self) -> Any:
        from rich.table import Table

        t = Table(title="fault-tolerant demo", show_header=False)
        t.add_column("", style="bold")
        t.add_column("")
        t.add_row("target", f"({self.target[0]:.3f}, {self.target[1]:.3f}) m")
        t.add_row("SMM latency", f"{self.latency:.3f} s")
        t.add_row("stalled joint (plant)", str(self.stalled_joint))
        t.add_row("detected", "-" if self.detected_joint is None else f"joint {self.detected_joint} by {self.detected_by}")
        t.add_row("locked at", f"{self.locked_value:.3f} rad")
        t.add_row("recovery", f"{self.recovery_s:.2f} s")
        t.add_row("tip error", f"{self.tip_error_m * 1000:.2f} mm measured, {self.tip_error_true_m * 1000:.2f} mm true")
        status = "target reached" if self.reached else "target NOT reached"
        t.add_row("status", status + (" despite the locked joint" if self.reached and self.detected_joint else ""))
        if self.rrd is not None:
            t.add_row("recording", str(self.rrd))
        return t


def _stream(plan: Plan) -> tuple[list[int], list[list[int]]]:
    return [max(1, int(round(d * 1000))) for d in plan.durations], [P.to_milli(row) for row in plan.q]


def plan_recovery(sc: FtScenario, q_lock: np.ndarray, j: int, robot: PlanarChain = ARM3R) -> Plan | None:
    """Section III-A after the failure: joint j is locked at q_lock[j]; the
    healthy joints go to the nearest SMM configuration with that value within
    the limits, corrected onto the target by Gauss-Newton on the healthy joints.
    None when the SMMs never take that value within the limits."""
    lims = limits(robot)
    move = ft.recovery_move(q_lock, j, ft.locked_configurations(sc.smm, 0, j, q_lock[j]), VMAX, lims)
    if move is None:
        return None
    free = np.arange(robot.n) != j
    goal = np.clip(refine(get_smm_arm(robot.name), move.goal, sc.x, free, Scenario().refine_iters),
                   robot.q_min, robot.q_max)
    qr, dr = _segment(ft.synchronised(q_lock, goal - q_lock, VMAX))
    return make_plan(robot, np.vstack([q_lock, qr]), np.r_[START_S, dr],
                     {"tool": "armbridge demo --fault-tolerant", "name": "recovery", "locked_joint": j + 1,
                      "locked_value_rad": float(q_lock[j])})


def run_cli(opts: Any, console: Any) -> None:
    """`armbridge demo --robot arm3r --fault-tolerant` (opts: demos.DemoOptions): run, show, judge."""
    result = run_ft_demo(opts.port, opts.rrd, opts.seed, smm_method(opts.smm), console=console, clear=opts.clear)
    console.print(result.table())
    console.print(f"recording: {result.rrd}   view it with: armbridge view {result.rrd}")
    if not result.reached:
        raise ArmbridgeError("the fault-tolerant demo did not reach its target (see the table above)")


def _one_thread() -> None:
    """One location's SMMs are a small batch: a second torch thread only fights the
    emulator for the CPU (2 threads: 2-8 s per location here, 1 thread: 0.3 s).
    Without torch (the runtime needs none) there is nothing to set."""
    import sys

    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


def run_ft_demo(port_url: str = "emu:esp32", rrd: str | Path | None = None, seed: int = 0,
                method: SmmMethod | None = None, latency: float | None = None, console=None,
                clear: bool = False) -> FtResult:
    """Run the scenario (module docstring) on an emulated board and record it; method None: the
    learned model. A board latched from before is refused unless `clear` (then CLR first)."""
    from armbridge.executor.client import LATCHED_STATES
    from armbridge.executor.session import open_session
    from armbridge.telemetry.recording import Recording, default_rrd_path

    if not port_url.startswith("emu:"):
        raise ArmbridgeError(f"port {port_url!r}: the fault-tolerant demo stalls a joint of the emulated plant, "
                             "so it needs an emu: port (e.g. emu:esp32?speed=4)")
    _one_thread()
    robot = ARM3R
    sc = choose_scenario(seed, method or learned_method(), latency, robot)
    res = FtResult(target=sc.x, latency=sc.latency, stalled_joint=sc.joint + 1)
    res.rrd = Path(rrd) if rrd is not None else default_rrd_path(sc.plan.name)
    say = console.print if console is not None else (lambda *a, **k: None)
    samples: list[tuple[float, np.ndarray]] = []  # (board time, measured q)
    stall: dict[str, Any] = {}

    with ExitStack() as stack:
        rec = stack.enter_context(Recording(res.rrd, robot, sc.plan, layout=FtLog.layout(robot)))
        log = FtLog(rec, robot, sc, limits(robot))

        def note(t: float | None, text: str, level: str = "info") -> None:
            res.events.append(text)
            rec.event(t, "host: " + text, level)
            say(text)

        def on_telemetry(t: float, m: P.Telemetry) -> None:
            samples.append((t, m.q))
            rec.telemetry(t, m.q, m.target, m.effort, m.done)
            log.q(t, m.q)
            err = np.abs(m.target - m.q)
            if m.state == "RUN" and not stall and err.max() > STALL_RAD:  # the host's own stall detector
                stall.update(joint=int(np.argmax(err)), t=t, by="host")
                client.estop()

        def on_event(t: float | None, ev: P.Event) -> None:
            rec.event(t, " ".join([ev.kind, *ev.args]), "error" if ev.kind in LATCHED_STATES else "info")
            if ev.kind == "FAULT" and not stall:
                stall.update(joint=int(ev.args[0]) - 1, t=t, by="FAULT")

        def settle() -> np.ndarray:
            """Let the arm come to rest: the mean measured q over the last 0.1 s."""
            client.drain(SETTLE_S)
            return np.mean([q for t, q in samples if t >= samples[-1][0] - 0.1], axis=0)

        def finish(q_end: np.ndarray) -> FtResult:
            res.tip_error_m = float(np.linalg.norm(robot.fk(q_end)[:2] - sc.x))
            res.tip_error_true_m = float(np.linalg.norm(robot.fk(emu.positions())[:2] - sc.x))
            note(samples[-1][0], f"target {'reached' if res.reached else 'NOT reached'}: tip error "
                                 f"{res.tip_error_true_m * 1000:.2f} mm (measured {res.tip_error_m * 1000:.2f} mm)",
                 "info" if res.reached else "error")
            return res

        client = stack.enter_context(open_session(
            port_url, robot, latched="clear" if clear else "refuse", rate_hz=RATE_HZ, on_telemetry=on_telemetry,
            on_event=on_event, on_error=lambda t, text: rec.error(t, text)))
        emu = client.port.emulator
        client.drain(0.1)
        t0 = samples[-1][0]
        note(t0, f"target appears at ({sc.x[0]:.3f}, {sc.x[1]:.3f}) m; SMMs take {sc.latency:.3f} s, "
                 f"damped least squares meanwhile")
        emu.schedule_stall(sc.joint + 1, emu.now() + sc.stall_after)
        try:
            client.execute(*_stream(sc.plan))
        except ArmbridgeError:
            if not stall:
                raise
        t_smm = client.start_times.get(0, t0) + sc.latency
        note(t_smm, f"SMMs ready: {int(sc.smm.count[0])} branch(es); into box {sc.approach.curve + 1} in "
                    f"{sc.approach.entry.duration:.2f} s, then {sc.approach.inside.duration:.2f} s inside it")
        log.box(t_smm, on=True)
        if not stall:  # the stalled joint had nowhere left to go: did the tip get there?
            note(None, "no stall detected", "warn")
            return finish(settle())
        j = stall["joint"]
        res.detected_joint, res.detected_by = j + 1, stall["by"]
        log.box(stall["t"], on=True)
        note(stall["t"], f"joint {j + 1} ({robot.joint_names[j]}) stalled (detected by {stall['by']}); arm stopped",
             "error")
        client.drain(SETTLE_S, until=lambda: client.state in LATCHED_STATES)
        settle()
        client.command("CLR")  # set point = measured position; the other joints can drive again
        client.stat()
        q_lock = np.clip(settle(), robot.q_min, robot.q_max)
        res.locked_value = float(q_lock[j])
        log.box(samples[-1][0], on=False)
        recovery = plan_recovery(sc, q_lock, j, robot)
        if recovery is None:
            note(None, f"no SMM configuration has joint {j + 1} at {q_lock[j]:.3f} rad within the limits", "error")
            return res
        res.recovery_s = recovery.total_duration - START_S
        log.recovery(samples[-1][0], recovery.q[-1], recovery)
        note(samples[-1][0], f"joint {j + 1} locked at {q_lock[j]:.3f} rad; recovering to "
                             f"{np.round(recovery.q[-1], 3).tolist()} in {res.recovery_s:.2f} s with the other joints")
        client.execute(*_stream(recovery))
        return finish(settle())
