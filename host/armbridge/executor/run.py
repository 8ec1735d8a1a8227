"""Run a plan on a board: validate, connect, stream, record, summarise.

    summary = run_plan("square.json", "emu:esp32", "runs/x.rrd")
    summary.table()      # a rich Table
    summary.to_dict()    # JSON-ready

The plan is validated before the port is opened: a bad plan sends nothing
and writes nothing (ArmbridgeError). The session is opened with
`open_session` (refusing a board latched from before unless `clear`).

Ctrl-C, SIGTERM and SIGHUP (executor/signals.py) all take one path: the e-stop
byte at once, a bounded wait for the board's ESTOP, the recording closed (it
verifies), and a Summary with `stopped_by_user` and `stopped_by` set. Any
other failure while the arm may move also sends the e-stop byte (unless the
board has stopped itself) and waits the same way, closes the recording, and
raises `RunFailed`, which carries the Summary (`error`, `final_state`, and
`fault` for a FAULT). The one line says whether the board confirmed the e-stop
(`estop_confirmed`) or not within estop.ESTOP_CONFIRM_S (executor/estop.py; what a run
prepares before it streams is executor/prepare.py).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError, BoardFailure
from armbridge.executor import penpos
from armbridge.executor.calcheck import CalibrationMismatch
from armbridge.executor.client import LATCHED_STATES, BoardClient
from armbridge.executor.estop import fail_run, stop_run
from armbridge.executor.prepare import PEN_MODES, cartesian_rows, check_board_ik, pen_flags, safety_filter
from armbridge.executor.settle import resting, still
from armbridge.executor.signals import holding, stop_on_signals
from armbridge.executor.summary import JointTracking, Summary
from armbridge.executor.tracking import fill, fill_settle, goal_check, held_between, plan_error
from armbridge.link import protocol as P
from armbridge.plans.format import Plan, load_plan, validate

RATE_MIN, RATE_MAX = 1, 100
SETTLE_WAIT_S = 3.0  # board time the run waits, after the last DONE, for a board with a dead band to come to rest

__all__ = ["RATE_MAX", "RATE_MIN", "JointTracking", "RunFailed", "Summary", "plan_error", "run_plan"]


class RunFailed(BoardFailure):
    """The run was tried and failed (a board fault or refusal, a lost port, no
    answer): exit code 1. `summary` is the Summary of what happened, already
    complete (recording closed)."""

    def __init__(self, message: str, summary: Summary) -> None:
        super().__init__(message)
        self.summary = summary


def run_plan(
    plan: Plan | str | Path,
    port_url: str,
    rrd_path: str | Path | None = None,
    rate_hz: int = 50,
    progress: bool = True,
    *,
    clear: bool = False,
    session: int | None = None,
    console=None,
    timeout: float | None = None,
    cartesian: bool = False,
    pen: str = "auto",
    home: bool = False,
    calibration: str = "check",
    pause_keys: bool = False,
    pen_pos: dict | None = None,
) -> Summary:
    """Validate the plan, then connect, stream it, record telemetry and return a Summary.

    `calibration`: "check" refuses a board whose calibration is not the one this
    host made for it (executor/calcheck.py), "ignore" does not ask.

    `clear`: send CLR first when the board is latched (ESTOP/WDOG/FAULT) from
    before; without it a latched board fails the run.

    `cartesian`: send the waypoints as `X id dur x y theta` (the tip's pose by FK)
    and let the board solve its IK; the board must have it (else the run fails
    on the first waypoint naming the missing capability). `pen` (plans with pen
    flags): "auto" uses the board's pen-lift servo when it has one (PEN lines),
    "on" requires one, "off" never sends PEN (pen-up moves are only marked).
    `pen_pos` (drawing plans): the pen's up_us, down_us, settle_ms (any of them), over the
    plan's own (`drawing.pen_pos`), sent as one PENPOS before the first waypoint
    (executor/penpos.py); a board that refuses it stops the run there (PenRefused).
    `home` (MASR plans): a HOME action first, for a board that does not know where
    its MA is (UNHOMED after a power on).

    `pause_keys`: on a terminal, space or p holds and resumes the arm while the plan
    streams (the protocol's HOLD / RESUME, executor/pause.py); the summary counts the
    holds and the time held, which the measured duration leaves out.

    Outcomes: a Summary (completed, or `stopped_by_user` after SIGINT/SIGTERM/
    SIGHUP: e-stop sent, `stopped_by` names the signal); `RunFailed` carrying
    the Summary for a run that failed once the port was tried; a plain
    ArmbridgeError for bad input (the plan, the rate, a port that names no
    serial device), before anything was sent and with nothing written.
    """
    # 1. Validate before anything touches a port.
    from armbridge.executor.masr import masr_commands, planned_time

    if isinstance(plan, (str, Path)):
        plan = load_plan(plan)
    masr: Any = None
    commands = None
    if plan.masr is not None:  # a MASR plan: its steps as the MA's actions
        if cartesian:
            raise ArmbridgeError("--cartesian is for the drawing arm; a MASR plan's actions are MV and ROT")
        masr = plan
        plan, commands = masr_commands(masr, home=home)
    elif home:
        raise ArmbridgeError("--home is for MASR plans (it drives the mobile actuator to the base first)")
    plan = validate(plan)
    plan, safety = safety_filter(plan)
    if not isinstance(rate_hz, int) or not RATE_MIN <= rate_hz <= RATE_MAX:
        raise ArmbridgeError(f"telemetry rate {rate_hz} Hz is outside [{RATE_MIN}, {RATE_MAX}]")
    if pen not in PEN_MODES:
        raise ArmbridgeError(f"pen mode {pen!r}: use one of {', '.join(PEN_MODES)}")
    pen_set = penpos.resolve((plan.provenance.get("drawing") or {}).get("pen_pos") if plan.pen is not None else None,
                             penpos.check_pen_pos(pen_pos, "pen_pos"))
    if pen_pos and (plan.pen is None or pen == "off"):
        raise ArmbridgeError("--pen-up, --pen-down and --pen-wait set the pen-lift servo: "
                             + ("the plan has no pen flags" if plan.pen is None else "not with --pen off"))
    from armbridge.executor.session import open_session
    from armbridge.link.transport import PortError
    from armbridge.telemetry.recording import Recording, default_rrd_path

    robot = plan.robot
    names = list(robot.joint_names)
    from armbridge.boards import boards_of_robot

    kind = (boards_of_robot(robot.name) or (robot.name,))[0]  # the board's kind (its own columns): its fw once known
    rrd = Path(rrd_path) if rrd_path is not None else default_rrd_path(plan.name)
    durs_ms = [max(1, int(round(d * 1000))) for d in plan.durations]
    verb, rows = ("X", cartesian_rows(plan)) if cartesian else ("W", [P.to_milli(row) for row in plan.q])
    summary = Summary(
        plan=str(plan.source) if plan.source is not None else plan.name,
        port=port_url,
        rrd=None,
        robot=robot.name,
        waypoints_total=plan.k,
        planned_duration_s=plan.total_duration,
        ik="board" if cartesian else "host",
    )
    if masr is not None:
        summary.planned_duration_s = planned_time(masr)  # the steps with the board's ramps
    summary.safety_filter = safety

    samples: list[tuple[float, str, np.ndarray, np.ndarray, int]] = []  # t, state, q, target, active seg
    sample_ms: list[int] = []  # each sample's board time (ms)
    rec: Recording | None = None
    client: BoardClient | None = None
    last_state: list[str | None] = [None]
    from armbridge.executor.pause import PauseView

    pause = PauseView(console, pause_keys)  # hold / resume: the keys, the bar's status, the summary's count

    def on_telemetry(t: float, m: P.Telemetry) -> None:
        if m.q.shape != (robot.dof,):
            return  # not this robot's board (connect() is about to say so)
        active = client.done_index + 1 if client is not None else 0
        if masr is not None:  # the board's d is an estimate (+- its bound): a mm past an end is the MA at that end
            m.q[-1] = min(max(float(m.q[-1]), 0.0), masr.robot.total_length)
        samples.append((t, m.state, m.q, m.target, active))
        sample_ms.append(m.ms)
        pause.on_telemetry(t)
        if rec is not None:
            rec.telemetry(t, m.q, m.target, m.effort, m.done, active=active)
            if m.extra:  # the board's own columns, named by its kind (telemetry.layout.BOARD_COLUMNS)
                rec.board(t, client.info.fw if client is not None and client.info is not None else kind, m.extra)
            if m.state != last_state[0]:
                rec.event(t, f"state {m.state}")
        last_state[0] = m.state

    def on_event(t: float | None, ev: P.Event) -> None:
        summary.events += 1
        pause.on_event(t, ev)
        if rec is not None:
            level = "error" if ev.kind in LATCHED_STATES else "warn" if ev.kind in ("SLOW", "BOOT") else "info"
            rec.event(t, " ".join([ev.kind, *ev.args]), level)

    def on_error(t: float | None, text: str) -> None:
        if rec is not None:
            rec.error(t, text, "error" if text.startswith("resync") else "warn")

    failure: BaseException | None = None
    bar = None
    with stop_on_signals():
        rec = _recording(rrd, robot, plan, masr, kind)  # an unwritable --rrd is bad input: nothing sent yet
        summary.rrd = str(rrd)
        try:
            with open_session(port_url, robot, latched="clear" if clear else "refuse", rate_hz=rate_hz,
                              session=session, calibration=calibration, on_telemetry=on_telemetry, on_event=on_event, on_error=on_error,
                              on_stop=lambda c, stop: stop_run(c, summary, rec, stop)) as c:
                client = c
                assert c.info is not None  # open_session yields a connected client
                summary.fw, summary.fw_version = c.info.fw, c.info.version
                summary.calibration = c.calibration.to_json() if c.calibration is not None else None
                if cartesian:
                    check_board_ik(c)
                if pen_set is not None and pen != "off":  # before the PEN probe and the first waypoint
                    hint = ("run without --pen-up/--pen-down/--pen-wait" if pen_pos else
                            "the plan carries them (drawing.pen_pos, from armbridge draw): run with --pen off")
                    if penpos.send_pen_pos(c, pen_set, required=bool(pen_pos) or pen == "on", hint=hint):
                        summary.pen_pos = pen_set
                flags = pen_flags(c, plan, pen, summary)
                band = c.settle_tolerance(robot.dof)  # None: the board has no dead band
                bar = pause.bar = _progress_bar(plan, console) if progress else None
                try:
                    with pause.keys(c):  # space or p: HOLD / RESUME at the streaming loop's next turn
                        c.execute(durs_ms, rows, on_progress=bar.update if bar else None, timeout=timeout,
                                  verb=verb, pen=flags, commands=commands)
                    if flags is not None:
                        c.command("PEN", 0)  # the drawing is done: lift the pen
                    # Let the last samples (the arm settling on the final waypoint) arrive.
                    c.drain(min(0.2, 2.0 / rate_hz))  # on the client clock (board time scale)
                    if band is not None:  # a board with a dead band: until the arm rests in it (bounded)
                        c.drain(SETTLE_WAIT_S, until=lambda: resting(samples, plan.q[-1], band[0]) and still(samples))
                    summary.final_state = c.stat()[0]
                except KeyboardInterrupt as stop:  # Ctrl-C, SIGTERM, SIGHUP
                    stop_run(c, summary, rec, stop)
                except BaseException as exc:
                    failure = exc
                    fail_run(c, summary, rec, exc)
                finally:
                    if bar is not None:
                        bar.stop()
                    pause.close(summary)
                    fill(summary, c, plan, samples, names, held=pause.intervals)
                    if band is not None:
                        fill_settle(summary, c, plan, samples, names, *band)
                    if plan.pen is not None:
                        summary.drawing = _drawing(plan, samples, summary.measured_duration_s, _touched(c, sample_ms))
                    if masr is not None:
                        from armbridge.executor.masr import masr_report

                        executed = summary.measured_duration_s
                        if home:  # the plan's own time starts when HOME and the MV to its start are DONE
                            d = c.done_times
                            s0 = int(plan.provenance["masr_plan"]["setup"]) - 1
                            executed = (d[plan.k - 1] - d[s0] - held_between(pause.intervals, d[s0], d[plan.k - 1])
                                        if s0 in d and plan.k - 1 in d else float("nan"))
                        summary.masr = masr_report(masr, samples[-1][2] if samples else None, executed)
                    summary.goal = _goal(plan, masr, summary, samples)
        except (CalibrationMismatch, penpos.PenRefused):  # nothing moved: one line, no summary, no recording
            _discard(rec, rrd)
            summary.rrd = None
            raise
        except PortError as exc:
            if exc.usage:  # the --port value names no serial device: bad input, nothing ran
                _discard(rec, rrd)
                summary.rrd = None
                raise
            failure = exc
            summary.error = str(exc)
            if client is None:  # the board was never reached: no recording of nothing
                _discard(rec, rrd)
                rec, summary.rrd = None, None
        except KeyboardInterrupt as stop:  # outside streaming: connecting (e-stop sent by on_stop), or opening
            if not summary.stopped_by_user:
                summary.stopped_by_user = True
                summary.stopped_by = getattr(stop, "name", "SIGINT")
                if rec is not None:
                    rec.error(None, f"stopped by {summary.stopped_by}", "error")
        except ArmbridgeError as exc:  # handshake: no answer, another board, latched, refused
            if failure is None:
                failure = exc
                summary.error = str(exc)
                # The state the board showed while connecting (HELLO's telemetry), if any.
                summary.final_state = client.state if client is not None else last_state[0]
                if client is None and summary.final_state is None:  # no answer at all: no recording of nothing
                    _discard(rec, rrd)
                    rec, summary.rrd = None, None
                elif rec is not None:
                    rec.error(None, f"run failed: {exc}", "error")
        finally:
            with holding():
                if rec is not None:
                    rec.summary(summary.to_dict())  # the run's summary in its recording (`armbridge report`)
                    rec.close()
    if failure is not None:
        raise RunFailed(summary.error or str(failure), summary) from failure
    return summary


def _recording(rrd: Path, robot, plan: Plan, masr, kind: str):
    """The run's recording; the views of the board kind's own columns (the MA's series, the
    pump's syringe positions) beside the arm, and a MASR plan's obstacles or a soft plan's scene
    (obstacles, planned tip path, poses) in the arm view."""
    from armbridge.telemetry.layout import board_views, run_layout
    from armbridge.telemetry.recording import Recording

    from armbridge.plans import masr as M
    from armbridge.plans.soft import recording_layers

    views = board_views(kind)
    layers = recording_layers(plan) if masr is None else None  # a soft plan's scene (its soft section)
    if masr is None and layers is None and (not views or plan.pen is not None):
        return Recording(rrd, robot, plan)
    spatial = ["world/obstacles"] if masr is not None else list(layers or ())
    layout = run_layout(robot, spatial=spatial, views=views)
    rec = Recording(rrd, robot, plan, layout=layout)
    if masr is not None and M.obstacles(masr):
        rec.obstacles(M.obstacles(masr))
    if layers:
        rec.layers(layers)
    return rec


def _progress_bar(plan: Plan, console):
    """A rich progress bar over the waypoints: .update(done), .stop()."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    bar = Progress(TextColumn("[bold]{task.fields[status]}[/bold] {task.description}"), BarColumn(),
                   MofNCompleteColumn(), TextColumn("waypoints"), TimeElapsedColumn(), console=console, transient=False)
    task = bar.add_task(plan.name, total=plan.k, status="running")
    bar.start()

    class _Bar:
        @staticmethod
        def update(done: int) -> None:
            bar.update(task, completed=done)

        @staticmethod
        def status(text: str) -> None:  # "running", or "held (space resumes)" (executor/pause.py)
            bar.update(task, status=text)

        @staticmethod
        def stop() -> None:
            try:
                bar.stop()
            except OSError:
                pass  # the terminal is gone (SIGHUP)

    return _Bar()


def _goal(plan: Plan, masr, summary: Summary, samples) -> dict | None:
    """The plan's goal against the last sample (Summary.goal): a MASR plan's goal pose (its
    environment's e_p, e_phi), a soft plan's tip goal (its scene's point and tolerance); None
    for a plan without a goal, or a run without telemetry."""
    if not samples or summary.waypoints_done != summary.waypoints_total:
        return None
    m = summary.masr
    if masr is not None and m and m.get("dp_mm") is not None and m.get("e_p_mm") is not None:
        return goal_check("MA pose", m["dp_mm"] / 1000.0, m["e_p_mm"] / 1000.0, np.radians(m["dphi_deg"]),
                          np.radians(m["e_phi_deg"]))
    from armbridge.plans.soft import soft_info, to_base_frame

    info = soft_info(plan)
    if info is None:
        return None
    tip = np.asarray(plan.robot.ee_point(samples[-1][2]), float).reshape(-1)[:2]  # the arm's base frame
    goal = to_base_frame(info.goal_point, info.base)
    return goal_check("tip", float(np.linalg.norm(tip - goal)), float(info.goal_tol))


def _discard(rec, path: Path) -> None:
    if rec is not None:
        rec.close()
    try:
        path.unlink()
    except OSError:
        pass


def _drawing(plan: Plan, samples, duration_s: float, touched=None) -> dict:
    """A drawing plan's summary section (plans/drawing.py) from the telemetry samples."""
    from armbridge.plans.drawing import run_drawing_report

    q = np.array([x[2] for x in samples]).reshape(-1, plan.n)
    return run_drawing_report(plan, q, np.array([x[4] for x in samples], int), duration_s, touched)


def _touched(client, sample_ms: list[int]) -> np.ndarray | None:
    """An emulated board's answer, per sample, to whether its pen touched the paper (its hidden
    physics: simhal.py, pcahal.py); None for a real board, which cannot know."""
    emu = getattr(getattr(client, "port", None), "emulator", None)
    hal: Any = getattr(emu, "hal", None)
    if not hasattr(hal, "pen_touch_at_ms") or not getattr(hal, "has_pen", False):
        return None
    return np.asarray(hal.pen_touch_at_ms(np.array(sample_ms, np.int64)), bool)
