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
board has stopped itself), closes the recording, and raises `RunFailed`, which
carries the Summary (`error`, `final_state`, and `fault` for a FAULT).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError, BoardFailure
from armbridge.executor.client import LATCHED_STATES, BoardClient
from armbridge.executor.signals import holding, stop_on_signals
from armbridge.link import protocol as P
from armbridge.plans.format import Plan, load_plan, validate

RATE_MIN, RATE_MAX = 1, 100


@dataclass
class JointTracking:
    rms: float = math.nan  # rad
    max: float = math.nan  # rad, largest |error|
    samples: int = 0


@dataclass
class Summary:
    """What a run did. Errors are in rad; times in s of board time."""

    plan: str
    port: str
    rrd: str | None
    robot: str
    waypoints_total: int
    waypoints_done: int = 0
    waypoints_sent: int = 0  # distinct waypoints sent at least once
    waypoints_acked: int = 0  # distinct waypoints the board answered OK
    waypoints_retransmitted: int = 0  # W lines sent beyond the first of each waypoint
    lines_sent: int = 0
    line_errors: int = 0  # damaged lines, both directions (board ER framing + host decode errors)
    board_lines_lost: int = 0  # gaps in the board's line counter
    timeouts: int = 0
    seq_errors: int = 0
    resyncs: int = 0
    slow_events: int = 0
    telemetry_samples: int = 0
    events: int = 0
    planned_duration_s: float = math.nan
    measured_duration_s: float = math.nan
    tracking_setpoint: dict[str, JointTracking] = field(default_factory=dict)  # q vs board set point, RUN
    tracking_plan: dict[str, JointTracking] = field(default_factory=dict)  # q vs the plan's linear path
    final_state: str | None = None
    stopped_by_user: bool = False
    stopped_by: str | None = None  # SIGINT, SIGTERM or SIGHUP
    estop_sent: bool = False
    error: str | None = None
    fault: str | None = None  # a latched FAULT: the joint and the reason, from the board's event
    fw: str | None = None
    fw_version: str | None = None

    @property
    def completed(self) -> bool:
        return self.waypoints_done == self.waypoints_total and not self.stopped_by_user and self.error is None

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["completed"] = self.completed

        def clean(x):
            if isinstance(x, float) and not math.isfinite(x):
                return None
            if isinstance(x, dict):
                return {k: clean(v) for k, v in x.items()}
            if isinstance(x, list):
                return [clean(v) for v in x]
            return x

        return clean(d)

    def table(self):
        """The summary as a rich Table."""
        from rich.table import Table

        t = Table(title=f"run of {self.plan}", show_header=True, header_style="bold")
        t.add_column("", style="bold")
        t.add_column("value", justify="right")
        status = "completed" if self.completed else (f"stopped by {self.stopped_by or 'user'}" if
                                                      self.stopped_by_user else
                                                      f"failed: {self.error}" if self.error else "incomplete")
        t.add_row("status", status)
        if self.final_state:
            t.add_row("final board state", self.final_state + (", e-stop sent" if self.estop_sent else ""))
        if self.fault:
            t.add_row("fault", self.fault)
        t.add_row("board", f"{self.fw} {self.fw_version}" if self.fw else "-")
        t.add_row("waypoints done / total", f"{self.waypoints_done} / {self.waypoints_total}")
        t.add_row("waypoints sent / acknowledged", f"{self.waypoints_sent} / {self.waypoints_acked}")
        t.add_row("waypoints retransmitted", str(self.waypoints_retransmitted))
        t.add_row("line errors (damaged lines)", str(self.line_errors))
        t.add_row("board lines lost", str(self.board_lines_lost))
        t.add_row("timeouts / ER SEQ", f"{self.timeouts} / {self.seq_errors}")
        t.add_row("resyncs", str(self.resyncs))
        if self.slow_events:
            t.add_row("segments slowed by the board", str(self.slow_events))
        t.add_row("duration planned / measured", f"{_f(self.planned_duration_s, 3)} s / {_f(self.measured_duration_s, 3)} s")
        for name, tr in self.tracking_setpoint.items():
            tp = self.tracking_plan.get(name, JointTracking())
            t.add_row(
                f"tracking {name} (rms / max)",
                f"set point {_mrad(tr.rms)} / {_mrad(tr.max)}; plan {_mrad(tp.rms)} / {_mrad(tp.max)} mrad",
            )
        t.add_row("telemetry samples", str(self.telemetry_samples))
        if self.rrd:
            t.add_row("recording", self.rrd)
        return t


def _f(x: float, nd: int) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{nd}f}"


def _mrad(x: float) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x * 1000:.1f}"


def _tracking(err: np.ndarray, names: list[str]) -> dict[str, JointTracking]:
    out = {}
    for j, name in enumerate(names):
        e = err[:, j] if err.size else np.zeros(0)
        if e.size:
            out[name] = JointTracking(float(np.sqrt(np.mean(e**2))), float(np.max(np.abs(e))), int(e.size))
        else:
            out[name] = JointTracking()
    return out


def plan_error(plan: Plan, t: np.ndarray, q: np.ndarray, seg: np.ndarray, seg_start: dict[int, float]) -> np.ndarray:
    """q minus the plan's piecewise-linear path, for samples in segments >= 1 whose
    start on the board's clock is known; rows of other samples are dropped.

    seg[s]: the plan index of the segment active at sample s. seg_start[i]: board
    time at which segment i began (the DONE of waypoint i-1, else the START of i;
    both are stamped at the control tick, so the anchor is within one control
    period of the true start). Within segment i the plan moves linearly from
    q[i-1] to q[i] over durations[i] and then holds q[i] (a segment the board
    stretched shows as error).
    """
    rows = []
    for s in range(len(t)):
        i = int(seg[s])
        if i < 1 or i >= plan.k or i not in seg_start:
            continue
        f = min(1.0, max(0.0, (t[s] - seg_start[i]) / plan.durations[i]))
        want = plan.q[i - 1] + f * (plan.q[i] - plan.q[i - 1])
        rows.append(q[s] - want)
    return np.array(rows).reshape(-1, plan.n)


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
) -> Summary:
    """Validate the plan, then connect, stream it, record telemetry and return a Summary.

    `clear`: send CLR first when the board is latched (ESTOP/WDOG/FAULT) from
    before; without it a latched board fails the run.

    Outcomes: a Summary (completed, or `stopped_by_user` after SIGINT/SIGTERM/
    SIGHUP: e-stop sent, `stopped_by` names the signal); `RunFailed` carrying
    the Summary for a run that failed once the port was tried; a plain
    ArmbridgeError for bad input (the plan, the rate, a port that names no
    serial device), before anything was sent and with nothing written.
    """
    # 1. Validate before anything touches a port.
    if isinstance(plan, Plan):
        plan = validate(plan)
    else:
        plan = load_plan(plan)
    if not isinstance(rate_hz, int) or not RATE_MIN <= rate_hz <= RATE_MAX:
        raise ArmbridgeError(f"telemetry rate {rate_hz} Hz is outside [{RATE_MIN}, {RATE_MAX}]")
    from armbridge.executor.session import open_session
    from armbridge.link.transport import PortError
    from armbridge.telemetry.recording import Recording, default_rrd_path

    robot = plan.robot
    names = list(robot.joint_names)
    rrd = Path(rrd_path) if rrd_path is not None else default_rrd_path(plan.name)
    durs_ms = [max(1, int(round(d * 1000))) for d in plan.durations]
    q_milli = [P.to_milli(row) for row in plan.q]
    summary = Summary(
        plan=str(plan.source) if plan.source is not None else plan.name,
        port=port_url,
        rrd=None,
        robot=robot.name,
        waypoints_total=plan.k,
        planned_duration_s=plan.total_duration,
    )

    samples: list[tuple[float, str, np.ndarray, np.ndarray, int]] = []  # t, state, q, target, active seg
    rec: Recording | None = None
    client: BoardClient | None = None
    last_state: list[str | None] = [None]

    def on_telemetry(t: float, m: P.Telemetry) -> None:
        if m.q.shape != (robot.dof,):
            return  # not this robot's board (connect() is about to say so)
        active = client.done_index + 1 if client is not None else 0
        samples.append((t, m.state, m.q, m.target, active))
        if rec is not None:
            rec.telemetry(t, m.q, m.target, m.effort, m.done)
            if m.state != last_state[0]:
                rec.event(t, f"state {m.state}")
        last_state[0] = m.state

    def on_event(t: float | None, ev: P.Event) -> None:
        summary.events += 1
        if rec is not None:
            level = "error" if ev.kind in LATCHED_STATES else "warn" if ev.kind in ("SLOW", "BOOT") else "info"
            rec.event(t, " ".join([ev.kind, *ev.args]), level)

    def on_error(t: float | None, text: str) -> None:
        if rec is not None:
            rec.error(t, text, "error" if text.startswith("resync") else "warn")

    failure: BaseException | None = None
    bar = None
    with stop_on_signals():
        try:
            rec = Recording(rrd, robot, plan)
            summary.rrd = str(rrd)
            with open_session(port_url, robot, latched="clear" if clear else "refuse", rate_hz=rate_hz,
                              session=session, on_telemetry=on_telemetry, on_event=on_event,
                              on_error=on_error) as c:
                client = c
                summary.fw, summary.fw_version = c.info.fw, c.info.version
                bar = _progress_bar(plan, console) if progress else None
                try:
                    c.execute(durs_ms, q_milli, on_progress=bar.update if bar else None, timeout=timeout)
                    # Let the last samples (the arm settling on the final waypoint) arrive.
                    c.drain(min(0.2, 2.0 / rate_hz))  # on the client clock (board time scale)
                    summary.final_state = c.stat()[0]
                except KeyboardInterrupt as stop:  # Ctrl-C, SIGTERM, SIGHUP
                    _stop(c, summary, rec, stop)
                except BaseException as exc:
                    failure = exc
                    _fail(c, summary, rec, exc)
                finally:
                    if bar is not None:
                        bar.stop()
                    _fill(summary, c, plan, samples, names)
        except PortError as exc:
            if exc.usage:  # the --port value names no serial device: bad input, nothing ran
                _discard(rec, rrd)
                summary.rrd = None
                raise
            failure = exc
            summary.error = str(exc)
        except KeyboardInterrupt as stop:  # outside streaming (connecting): nothing sent moves the arm
            summary.stopped_by_user = True
            summary.stopped_by = getattr(stop, "name", "SIGINT")
            if rec is not None:
                rec.error(None, f"stopped by {summary.stopped_by}", "error")
        except ArmbridgeError as exc:  # handshake: no answer, another board, latched, refused
            if failure is None:
                failure = exc
                summary.error = str(exc)
                summary.final_state = client.state if client is not None else None
                if rec is not None:
                    rec.error(None, f"run failed: {exc}", "error")
        finally:
            with holding():
                if rec is not None:
                    rec.close()
    if failure is not None:
        raise RunFailed(summary.error or str(failure), summary) from failure
    return summary


def _progress_bar(plan: Plan, console):
    """A rich progress bar over the waypoints: .update(done), .stop()."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    bar = Progress(TextColumn("[bold]running[/bold] {task.description}"), BarColumn(), MofNCompleteColumn(),
                   TextColumn("waypoints"), TimeElapsedColumn(), console=console, transient=False)
    task = bar.add_task(plan.name, total=plan.k)
    bar.start()

    class _Bar:
        @staticmethod
        def update(done: int) -> None:
            bar.update(task, completed=done)

        @staticmethod
        def stop() -> None:
            try:
                bar.stop()
            except OSError:
                pass  # the terminal is gone (SIGHUP)

    return _Bar()


def _estop(client: BoardClient, summary: Summary) -> None:
    try:
        client.estop()
        summary.estop_sent = True
    except Exception:  # noqa: BLE001 - the port may be gone; the board's watchdog stops the arm
        pass


def _stop(client: BoardClient, summary: Summary, rec, stop: KeyboardInterrupt) -> None:
    """A stop signal mid-run: the e-stop byte at once, then wait (bounded) for the
    board to confirm it, so the recording holds the ESTOP event and the last samples."""
    _estop(client, summary)
    summary.stopped_by_user = True
    summary.stopped_by = getattr(stop, "name", "SIGINT")
    if rec is not None:
        rec.error(None, f"stopped by {summary.stopped_by}" + (", e-stop sent" if summary.estop_sent else
                                                              ", e-stop could not be sent"), "error")
    try:
        client.drain(1.0, until=lambda: client.state == "ESTOP")
    except (ArmbridgeError, KeyboardInterrupt):
        pass
    summary.final_state = client.state


def _fail(client: BoardClient, summary: Summary, rec, exc: BaseException) -> None:
    """Any other failure while the arm may move: e-stop unless the board stopped itself."""
    if client.state not in LATCHED_STATES:
        _estop(client, summary)
    summary.error = str(exc) or type(exc).__name__
    if summary.estop_sent and isinstance(exc, ArmbridgeError):
        summary.error += "; e-stop sent (the next run needs --clear)"
    summary.final_state = client.state
    summary.fault = client.fault_reason
    if rec is not None:
        rec.error(None, f"run failed: {summary.error}", "error")


def _discard(rec, path: Path) -> None:
    if rec is not None:
        rec.close()
    try:
        path.unlink()
    except OSError:
        pass


def _fill(summary: Summary, client, plan: Plan, samples, names: list[str]) -> None:
    s = client.stats
    summary.waypoints_done = client.done_index + 1
    summary.waypoints_sent = s.waypoints_sent
    summary.waypoints_acked = s.waypoints_acked
    summary.waypoints_retransmitted = s.waypoints_retransmitted
    summary.lines_sent = s.lines_sent
    summary.line_errors = s.line_errors
    summary.board_lines_lost = s.board_lines_lost
    summary.timeouts = s.timeouts
    summary.seq_errors = s.seq_errors
    summary.resyncs = s.resyncs
    summary.slow_events = s.slow_events
    summary.telemetry_samples = len(samples)
    # Duration on the board's clock: START of waypoint 0 to DONE of the last one.
    last = plan.k - 1
    t0 = client.start_times.get(0)
    if t0 is None and client.done_times:  # START 0 was lost: back from the first DONE seen
        i = min(client.done_times)
        t0 = client.done_times[i] - float(np.sum(plan.durations[: i + 1]))
    t1 = client.done_times.get(last) if client.done_index >= last else None
    if t0 is not None and t1 is not None:
        summary.measured_duration_s = float(t1 - t0)
    run = [x for x in samples if x[1] == "RUN"]
    if run:
        t = np.array([x[0] for x in run])
        q = np.stack([x[2] for x in run])
        tg = np.stack([x[3] for x in run])
        seg = np.array([x[4] for x in run])
        summary.tracking_setpoint = _tracking(tg - q, names)
        # Segment i begins at the DONE of i-1 when the board went straight on
        # (same control tick as the START of i), at the START of i after a pause.
        seg_start = dict(client.start_times)
        for i, td in client.done_times.items():
            ts = client.start_times.get(i + 1)
            if ts is None or ts - td <= 0.011:
                seg_start[i + 1] = td
        summary.tracking_plan = _tracking(plan_error(plan, t, q, seg, seg_start), names)
    else:
        summary.tracking_setpoint = _tracking(np.zeros((0, len(names))), names)
        summary.tracking_plan = _tracking(np.zeros((0, len(names))), names)
