"""`armbridge bench load`: runs on a busy machine, and a host whose caller is busy too.

The load harness (issue: runs that hold): N busy processes per core beside the
run (`Busy`), and the main thread of the host process kept busy on purpose
(`BusyCaller`: some pure-Python work for every telemetry sample, and every
HOG_EVERY_S one call that holds the GIL for HOG_S, longer than any board's
watchdog period: `ctypes.PyDLL`'s usleep keeps the GIL for exactly that long,
whatever the machine's speed).

Two measurements:

* sessions: one slow plan (the board in RUN, its watchdog armed, the host
  sending mostly keep-alives) per (board kind, where the session runs, load):
  the keep-alive period, the longest the host was quiet (its lateness is that
  minus the period), the longest gap between host lines at the board (the
  emulator's own record: what its watchdog sees), timeouts and spurious
  timeouts on the clean link, watchdog trips. Board kinds: `emu` (the
  emulator paced in this process) and `pty` (`armbridge emulate` in another
  process, on its pseudo-terminal: a board whose time never stops). Where the
  session runs: "inline" (the caller's thread, as before the link engine),
  "thread", "process" (executor/engine.py; "auto" is thread for emu, process
  for pty).
* demos: `armbridge demo --robot R --json` as a user runs it, N times per
  robot at a load, on its emulated board in the demo's own process (emu) or on
  a fresh `armbridge emulate` (pty): completed, watchdog trips, timeouts,
  spurious timeouts, resyncs, the emulator's pace.
"""
from __future__ import annotations

import ctypes
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import typer

from armbridge.bench.command import write_json

HOG_S = 1.5  # one GIL-holding call: longer than the 1 s watchdog of every board
HOG_EVERY_S = 4.0
SPIN_PER_SAMPLE_S = 0.002  # pure-Python work per telemetry sample (a recording, a plot)
ROBOT_OF = {"esp32": "arm3r", "arduino_pump": "soft3", "masr_ma": "masr5"}
DEMO_BOARD = {"arm3r": "esp32", "masr": "masr_ma", "soft": "arduino_pump"}


def armbridge_exe() -> list[str]:
    """How to start this armbridge as a process (the script beside this Python, else -m)."""
    exe = Path(sys.executable).with_name("armbridge")
    return [str(exe)] if exe.is_file() else [sys.executable, "-m", "armbridge.cli"]


@contextmanager
def Busy(per_core: float) -> Iterator[int]:
    """`per_core` x the cores of busy-loop processes for the block; yields how many."""
    n = int(round(per_core * (os.cpu_count() or 1)))
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"], stdin=subprocess.DEVNULL)
             for _ in range(n)]
    try:
        time.sleep(0.2 if n else 0.0)
        yield n
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()


def hold_gil(seconds: float) -> None:
    """Hold the GIL for `seconds` of wall time: a C call made through PyDLL keeps it."""
    ctypes.PyDLL(None).usleep(int(seconds * 1e6))


class BusyCaller:
    """Telemetry callbacks that keep the caller's thread busy (module docstring)."""

    def __init__(self, on: bool = True) -> None:
        self.on = on
        self.next_hog = time.monotonic() + 1.0
        self.hogs = 0

    def __call__(self, t: float, msg: Any) -> None:
        if not self.on:
            return
        end = time.perf_counter() + SPIN_PER_SAMPLE_S
        x = 0
        while time.perf_counter() < end:
            x += 1
        if time.monotonic() >= self.next_hog:
            hold_gil(HOG_S)
            self.hogs += 1
            self.next_hog = time.monotonic() + HOG_EVERY_S


@contextmanager
def emulate(board: str, *extra: str) -> Iterator[tuple[str, Callable[[], str]]]:
    """`armbridge emulate BOARD -q` on a pty: (its path, a function that stops it and returns
    what it printed)."""
    p = subprocess.Popen([*armbridge_exe(), "emulate", board, "-q", *extra], stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL)
    assert p.stdout is not None
    first = p.stdout.readline()
    m = re.search(r"emulator on (\S+)", first)
    if m is None:
        p.kill()
        raise RuntimeError(f"armbridge emulate {board} said {first!r}{p.stdout.read()[-500:]}")
    out: list[str] = [first]

    def stop() -> str:
        if p.poll() is None:
            p.terminate()
        rest, _ = p.communicate(timeout=30)
        out.append(rest)
        return "".join(out)

    try:
        yield m.group(1), stop
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()


def _emulate_report(text: str) -> dict[str, Any]:
    gap = re.search(r"longest gap between host lines at the board: ([0-9.]+) s", text)
    pace = re.search(r"pace: ([0-9.]+)x", text)
    return {"board_line_gap_s": float(gap.group(1)) if gap else None,
            "emulator_pace": float(pace.group(1)) if pace else None,
            "emulator_warned": "cannot keep up" in text}


def slow_plan(robot_name: str, seconds: float, step_s: float = 0.5) -> tuple[list[int], list[list[int]]]:
    """Durations (ms) and targets (milli-units): small steps around the middle of the ranges."""
    from armbridge.robots.catalog import get_robot

    robot = get_robot(robot_name)
    lo, hi = np.asarray(robot.q_min, float), np.asarray(robot.q_max, float)
    mid, amp = (lo + hi) / 2, np.minimum((hi - lo) / 8, np.asarray(robot.v_max, float) * step_s / 2)
    k = int(seconds / step_s)
    q = [[int(round(1000 * (mid[j] + amp[j] * np.sin(i / 3 + j)))) for j in range(robot.dof)] for i in range(k)]
    return [int(step_s * 1000)] * k, q


def session_trial(board: str, where: str, engine: str, load: float, busy_caller: bool, seconds: float,
                  realtime: bool = False) -> dict:
    """One slow plan at `load` (module docstring); where: "emu" or "pty" (`realtime`:
    `armbridge emulate --realtime`)."""
    from armbridge.errors import ArmbridgeError
    from armbridge.executor.session import open_session
    from armbridge.robots.catalog import get_robot

    robot = get_robot(ROBOT_OF[board])
    durations, q = slow_plan(robot.name, seconds)
    caller = BusyCaller(busy_caller)
    row: dict[str, Any] = {"board": board, "where": where, "engine": engine, "load": load, "busy_caller": busy_caller,
                           "realtime": realtime and where == "pty"}
    board_proc = emulate(board, *(["--realtime"] if realtime else [])) if where == "pty" else _no_emulator(board)
    with Busy(load) as n, board_proc as (url, stop):
        row["busy_processes"] = n
        error = None
        notes: list[str] = []
        try:
            with open_session(url, robot, latched="clear", rate_hz=50, on_telemetry=caller, engine=engine,
                              on_error=lambda t, text: notes.append(text)) as c:
                assert c.info is not None  # open_session yields a connected client
                row["keepalive_s"] = min(0.25, c.info.wdog_ms / 8000.0)
                try:
                    c.execute(durations, q)
                except ArmbridgeError as exc:
                    error = str(exc)
                state = c.stat()[0]
                emu = getattr(c.port, "emulator", None)
                if emu is not None:
                    row["board_line_gap_s"] = emu.counters["host_line_gap_s"]
                    row["emulator_pace"] = emu.pace()["achieved"]
                s = c.stats
        except ArmbridgeError as exc:
            error, state, s = str(exc), None, None
        report = stop()
    if where == "pty":
        row.update(_emulate_report(report))
    row["timeout_notes"] = [n for n in notes if n.startswith("no answer")][:10]
    row.update({"completed": error is None, "error": error, "final_state": state,
                "watchdog": state == "WDOG" or (error is not None and "watchdog" in error),
                "hogs": caller.hogs})
    if s is not None:
        row.update({"timeouts": s.timeouts, "spurious_timeouts": s.spurious_timeouts,
                    "retransmissions": s.retransmissions, "resyncs": s.resyncs,
                    "longest_quiet_s": s.longest_quiet_s})
    return row


@contextmanager
def _no_emulator(board: str) -> Iterator[tuple[str, Callable[[], str]]]:
    yield f"emu:{board}", lambda: ""


def demo_trial(robot: str, where: str, load: float, seed: int, tmp: Path, realtime: bool = False) -> dict:
    """`armbridge demo --robot ROBOT --json` as a user runs it, at `load`."""
    js, rrd = tmp / f"{robot}-{where}-{seed}.json", tmp / f"{robot}-{where}-{seed}.rrd"
    row: dict[str, Any] = {"robot": robot, "where": where, "load": load, "seed": seed,
                           "realtime": realtime and where == "pty"}
    board = DEMO_BOARD[robot]
    board_proc = emulate(board, *(["--realtime"] if realtime else [])) if where == "pty" else _no_emulator(board)
    with Busy(load), board_proc as (url, stop):
        port = ["--port", url] if where == "pty" else []
        t0 = time.monotonic()
        r = subprocess.run([*armbridge_exe(), "demo", "--robot", robot, *port, "--json", str(js), "--rrd", str(rrd),
                            "--seed", str(seed)], capture_output=True, text=True, stdin=subprocess.DEVNULL)
        row["wall_s"] = time.monotonic() - t0
        report = stop()
    if where == "pty":
        row.update(_emulate_report(report))
    row["exit_code"] = r.returncode
    try:
        s = json.loads(js.read_text())
    except (OSError, ValueError):
        row.update({"completed": False, "error": (r.stderr or r.stdout)[-400:], "watchdog": "watchdog" in r.stderr})
        return row
    pace = s.get("emulator_pace") or {}
    row.update({"completed": bool(s.get("completed")), "error": s.get("error"), "final_state": s.get("final_state"),
                "watchdog": s.get("final_state") == "WDOG" or "watchdog" in (s.get("error") or ""),
                "timeouts": s.get("timeouts"), "spurious_timeouts": s.get("spurious_timeouts"),
                "retransmitted": s.get("waypoints_retransmitted"), "resyncs": s.get("resyncs"),
                "longest_quiet_s": s.get("longest_quiet_s"),
                "emulator_pace": row.get("emulator_pace", pace.get("achieved"))})
    return row


def run_sessions(boards: list[str], wheres: list[str], engines: list[str], loads: list[float], busy_caller: bool,
                 seconds: float, progress: Callable[[str], None], realtime: bool = False) -> list[dict]:
    rows = []
    for board in boards:
        for where in wheres:
            for engine in engines:
                if where == "emu" and engine == "process":
                    continue  # an in-process emulator lives where the session is opened
                for load in loads:
                    progress(f"session {board} on {where}, engine {engine}, load {load:g}/core")
                    rows.append(session_trial(board, where, engine, load, busy_caller, seconds, realtime))
    return rows


def run_demos(robots: list[str], wheres: list[str], loads: list[float], runs: int,
              progress: Callable[[str], None], realtime: bool = False) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory(prefix="armbridge-bench-load-") as tmp:
        for robot in robots:
            for where in wheres:
                for load in loads:
                    for seed in range(runs):
                        progress(f"demo {robot} on {where}, load {load:g}/core, run {seed + 1} of {runs}")
                        rows.append(demo_trial(robot, where, load, seed, Path(tmp), realtime))
    return rows


def summarize_demos(rows: list[dict]) -> list[dict]:
    """Per (robot, where, load): runs, completed, watchdog trips, timeouts, spurious, resyncs."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["robot"], r["where"], r["load"]), []).append(r)
    out = []
    for (robot, where, load), rs in groups.items():
        paces = [r["emulator_pace"] for r in rs if r.get("emulator_pace") is not None]
        out.append({"robot": robot, "where": where, "load": load, "runs": len(rs),
                    "completed": sum(bool(r["completed"]) for r in rs),
                    "watchdog": sum(bool(r.get("watchdog")) for r in rs),
                    "timeouts": sum(r.get("timeouts") or 0 for r in rs),
                    "spurious_timeouts": sum(r.get("spurious_timeouts") or 0 for r in rs),
                    "resyncs": sum(r.get("resyncs") or 0 for r in rs),
                    "pace_min": min(paces) if paces else None,
                    "wall_s_median": float(np.median([r["wall_s"] for r in rs if "wall_s" in r] or [np.nan]))})
    return out


def print_result(result: dict, console: Any) -> None:
    from rich.table import Table

    def f(x: Any, nd: int = 3) -> str:
        return "-" if x is None else f"{x:.{nd}f}" if isinstance(x, float) else str(x)

    t = Table(title=f"sessions under load ({result['cores']} cores; caller: {result['spin_per_sample_s'] * 1000:g} ms "
                    f"per sample, GIL held {result['hog_s']:g} s every {result['hog_every_s']:g} s)")
    for col in ("board", "where", "engine", "load/core", "keep-alive s", "host quiet max s", "board line gap s",
                "timeouts", "spurious", "watchdog", "completed", "pace"):
        t.add_column(col, justify="right")
    for r in result["sessions"]:
        t.add_row(r["board"], r["where"], r["engine"], f(r["load"], 0), f(r.get("keepalive_s")),
                  f(r.get("longest_quiet_s")), f(r.get("board_line_gap_s")), f(r.get("timeouts")),
                  f(r.get("spurious_timeouts")), "yes" if r["watchdog"] else "no",
                  "yes" if r["completed"] else "no", f(r.get("emulator_pace"), 2))
    console.print(t)
    if result.get("demos"):
        d = Table(title="demos as a user runs them")
        for col in ("robot", "where", "load/core", "runs", "completed", "watchdog", "timeouts", "spurious",
                    "resyncs", "slowest pace", "median wall s"):
            d.add_column(col, justify="right")
        for r in result["demos"]:
            d.add_row(r["robot"], r["where"], f(r["load"], 0), str(r["runs"]), str(r["completed"]),
                      str(r["watchdog"]), str(r["timeouts"]), str(r["spurious_timeouts"]), str(r["resyncs"]),
                      f(r["pace_min"], 2), f(r["wall_s_median"], 1))
        console.print(d)


def load_cmd(
    loads: str = typer.Option("0,1,3", "--loads", metavar="L,L,...",
                              help="Busy-loop processes per core beside the runs, one measurement each."),
    boards: str = typer.Option("esp32,arduino_pump", "--boards", help="Boards of the session measurement."),
    where: str = typer.Option("emu,pty", "--where", help="emu: the emulator paced in this process; pty: "
                              "`armbridge emulate` in another process, on its pseudo-terminal."),
    engines: str = typer.Option("inline,auto", "--engines", help="Where the session runs: inline (the caller's "
                                "thread), thread, process, auto (thread for emu, process for pty)."),
    busy_caller: bool = typer.Option(True, "--busy-caller/--idle-caller",
                                     help="Keep the caller's thread busy: pure-Python work per telemetry sample "
                                          "and a 1.5 s call holding the GIL every 4 s."),
    seconds: float = typer.Option(12.0, "--seconds", min=2.0, help="Length of each session's plan (board time)."),
    demos: str = typer.Option("", "--demos", metavar="R,R,...",
                              help="Also run these demos (arm3r, masr, soft) as a user does, --runs times each, "
                                   "on emu and pty, at the highest load; empty: none."),
    runs: int = typer.Option(20, "--runs", min=1, help="Runs of each demo."),
    demo_loads: str = typer.Option(None, "--demo-loads", help="Loads of the demo runs [default: the highest "
                                                               "of --loads]."),
    realtime: bool = typer.Option(False, "--realtime", help="Run the pty boards with `armbridge emulate "
                                  "--realtime` (the board as a chip of its own, not slowed by the load)."),
    json_out: Path = typer.Option(Path("runs/bench-load.json"), "--json", help="Where to write the results ('-': stdout)."),
) -> None:
    """Runs under load (docs/benchmarks.md, "Runs under load"): keep-alive lateness, timeouts,
    spurious timeouts and watchdog trips with N busy processes per core and the caller's thread
    kept busy, the session in the caller's thread or in the link engine; and the demos as a
    user runs them, on the in-process emulator and on `armbridge emulate`'s pty."""
    from rich.console import Console

    def floats(text: str, name: str) -> list[float]:
        try:
            return [float(x) for x in text.split(",") if x.strip()]
        except ValueError:
            raise typer.BadParameter(f"{text!r}: numbers separated by commas", param_hint=name) from None

    def names(text: str, allowed, name: str) -> list[str]:
        out = [x.strip() for x in text.split(",") if x.strip()]
        bad = [x for x in out if x not in allowed]
        if bad:
            raise typer.BadParameter(f"{', '.join(bad)}: use {', '.join(allowed)}", param_hint=name)
        return out

    load_list = floats(loads, "--loads")
    console = Console(width=160)
    progress = lambda text: console.print(f"[dim]bench load: {text}[/]")  # noqa: E731
    result: dict = {"cores": os.cpu_count(), "hog_s": HOG_S, "hog_every_s": HOG_EVERY_S,
                    "spin_per_sample_s": SPIN_PER_SAMPLE_S, "realtime": realtime}
    result["sessions"] = run_sessions(names(boards, ROBOT_OF, "--boards"), names(where, ("emu", "pty"), "--where"),
                                      names(engines, ("inline", "thread", "process", "auto"), "--engines"),
                                      load_list, busy_caller, seconds, progress, realtime)
    if demos:
        robots = names(demos, DEMO_BOARD, "--demos")
        dl = floats(demo_loads, "--demo-loads") if demo_loads else [max(load_list)]
        rows = run_demos(robots, names(where, ("emu", "pty"), "--where"), dl, runs, progress, realtime)
        result["demo_runs"] = rows
        result["demos"] = summarize_demos(rows)
    write_json(result, json_out)
    print_result(result, console)
    console.print(f"wrote {json_out}")
