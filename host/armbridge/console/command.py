"""`armbridge board VERB --port P`: the board console's verbs.

    armbridge board info    --port /dev/ttyUSB0    identity, protocol, joints and limits, queue, rate, watchdog
    armbridge board state   --port emu:esp32       state and latch, done/queued, board time
    armbridge board ping    --port socket://h:7000 round-trip times
    armbridge board clear   --port P [--yes]       clear a latched ESTOP/WDOG/FAULT (asks first)
    armbridge board rate 20 --port P               telemetry rate
    armbridge board pen --down 1650 --port P       the pen servo's heights and settle (PENPOS; --save keeps them)
    armbridge board monitor --port P               live telemetry and events until Ctrl-C

Each verb opens a new session (a board's queue is flushed and the arm stops
where it is: a console is never a second host of a run, and the port lock
keeps it off a port a run holds); `--session N` rejoins session N instead (a
resync: the board keeps its queue and done/queued).

Over a `modbus:` port (the pump board in Modbus RTU, docs/modbus.md) the same
verbs run on registers (executor/modbus_client.py): info and state by reads,
clear through the command register, rate sets how often the host polls.

A board that an `armbridge flash` left half-flashed (interrupted, or a file
that failed its hash) is refused with one line saying so (exit 1) until a
flash completes.

Exit codes as `armbridge run` (docs/formats.md §7): 0 done, 1 the board or the
link failed (no answer, refused, busy or lost port), 2 bad input or usage,
128 + the signal when stopped by one, except that `monitor` ends with 0 on
Ctrl-C, its normal end.
"""
from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Optional

import typer
from rich.console import Console
from rich.table import Table

from armbridge.boards import calfile
from armbridge.errors import ArmbridgeError, BoardFailure
from armbridge.executor.signals import Stopped, stop_on_signals
from armbridge.jsonfile import JSON_HELP, emit_json
from armbridge.link.ports import auto_port
from armbridge.link.protodef import COMMANDS, LATCHED_STATES

RATE_MIN, RATE_MAX = COMMANDS["RATE"][0][1], COMMANDS["RATE"][0][2]

board_app = typer.Typer(
    help="Talk to a board without a plan: identity, state, ping, clear a latch, telemetry rate, live monitor.",
    no_args_is_help=True,
)

PORT_HELP = ("Serial device, pyserial URL (socket://, rfc2217://, loop://), emu:DEVICE, or modbus:PORT?addr=N "
             "(Modbus RTU, docs/modbus.md), or auto (the one board plugged in: armbridge ports) (env ARMBRIDGE_PORT).")
SESSION_HELP = "Rejoin session N (the board keeps its queue) instead of opening a new one."


def _port_opt():
    return typer.Option(..., "--port", "-p", envvar="ARMBRIDGE_PORT", callback=auto_port, help=PORT_HELP)


def _session_opt():
    return typer.Option(None, "--session", min=1, max=65535, metavar="N", help=SESSION_HELP)


def _timeout_opt():
    return typer.Option(5.0, "--timeout", min=0.1, metavar="SECONDS", help="How long to wait for the board's answer.")


def _json_opt():
    return typer.Option(None, "--json", metavar="FILE|-", help=JSON_HELP.format(what="the answer") +
                        " With '-' no table is printed.")


@contextmanager
def board_session(port: str, *, session: int | None = None, timeout: float = 5.0, **kw: Any) -> Iterator:
    """open_session without a robot, latch left as it is; a failure once the port
    was tried is a BoardFailure (exit 1), a --port naming no device stays exit 2."""
    from armbridge.executor.session import open_session
    from armbridge.flash.manifest import half_flashed
    from armbridge.link.transport import PortError

    note = half_flashed(port)  # an interrupted `armbridge flash` (docs/flash.md): not a board to talk to
    if note is not None:
        raise BoardFailure(note)
    try:
        with open_session(port, None, latched="allow", session=session, connect_timeout=timeout, **kw) as client:
            yield client
    except (PortError, BoardFailure):
        raise
    except ArmbridgeError as exc:
        raise BoardFailure(str(exc)) from None


@contextmanager
def _verb(ctrl_c_ok: bool = False) -> Iterator[None]:
    """Stop signals end a verb cleanly, with 128 + the signal (monitor: Ctrl-C is 0)."""
    try:
        with stop_on_signals():
            yield
    except Stopped as stop:
        raise typer.Exit(0 if ctrl_c_ok and stop.name == "SIGINT" else stop.exit_code) from None


def _out(as_json: str | None) -> Console:
    return Console(stderr=as_json == "-")


def _print_json(obj: Any, target: str | None) -> bool:
    """`--json TARGET`: the answer there; True when that was stdout (then no table)."""
    if target is None:
        return False
    emit_json(obj, target, "the answer")
    return target == "-"


def _latch_hint(state: str, port: str) -> str:
    return f" (latched: `armbridge board clear --port {port}` clears it)" if state in LATCHED_STATES else ""


# ---------------------------------------------------------------------- info
def calibration_dict(cal) -> dict[str, Any] | None:
    """The board's calibration as `board info` shows it: its chip id, the calibration
    id it holds, how that compares with this host's file (executor/calcheck.py),
    and the file's settings when there is one."""
    if cal is None or cal.uid is None:
        return None
    d = cal.to_json()
    if cal.file:
        try:
            host = calfile.read(Path(cal.file))
            d["settings"] = [[v, *a] for v, a in host.settings]
            d["created"] = host.created
        except ArmbridgeError as exc:
            d["file_error"] = str(exc)
    return d


def info_dict(info, cal=None) -> dict[str, Any]:
    joints = [
        {"joint": j + 1, "min_mrad": lo, "max_mrad": hi, "vmax_mrad_s": vmax,
         "min_rad": lo / 1000, "max_rad": hi / 1000, "vmax_rad_s": vmax / 1000}
        for j, (lo, hi, vmax) in enumerate(info.limits_milli)
    ]
    return {"fw": info.fw, "fw_version": info.version, "protocol": info.proto, "joints": info.n,
            "queue": info.qsize, "rate_hz": info.rate, "watchdog_ms": info.wdog_ms, "state": info.state,
            "limits": joints, "calibration": calibration_dict(cal)}


@board_app.command("info")
def info_cmd(port: str = _port_opt(), session: Optional[int] = _session_opt(), timeout: float = _timeout_opt(),
             as_json: Optional[str] = _json_opt()) -> None:
    """Identity, protocol, joints and their limits, queue size, telemetry rate, watchdog."""
    with _verb(), board_session(port, session=session, timeout=timeout) as client:
        d = info_dict(client.info, client.calibration)
    if _print_json(d, as_json):
        return
    t = Table(title=f"board on {port}", show_header=False)
    t.add_column("", style="bold")
    t.add_column("")
    t.add_row("firmware", f"{d['fw']} {d['fw_version']}")
    t.add_row("protocol", str(d["protocol"]))
    t.add_row("joints", str(d["joints"]))
    t.add_row("queue", f"{d['queue']} waypoints")
    t.add_row("telemetry rate", f"{d['rate_hz']} Hz")
    t.add_row("watchdog", f"{d['watchdog_ms']} ms")
    t.add_row("state", d["state"] + _latch_hint(d["state"], port))
    cal = d["calibration"]
    if cal is not None:
        t.add_row("chip id", cal["uid"])
        held = f"id {cal['id']}" if cal["id"] else "none saved"
        t.add_row("calibration", f"{held}: {cal['status']}" + (f" ({cal['file']})" if cal["file"] else ""))
        for s in cal.get("settings", []):
            t.add_row("", " ".join(map(str, s)))
    lim = Table(title="joint limits", show_header=True, header_style="bold")
    for col in ("joint", "min (rad)", "max (rad)", "vmax (rad/s)"):
        lim.add_column(col, justify="right")
    for j in d["limits"]:
        lim.add_row(str(j["joint"]), f"{j['min_rad']:.3f}", f"{j['max_rad']:.3f}", f"{j['vmax_rad_s']:.3f}")
    out = _out(None)
    out.print(t)
    out.print(lim)


# ---------------------------------------------------------------------- state
@board_app.command("state")
def state_cmd(port: str = _port_opt(), session: Optional[int] = _session_opt(), timeout: float = _timeout_opt(),
              as_json: Optional[str] = _json_opt()) -> None:
    """The board's state and latch, the last done and last queued waypoint, board time."""
    with _verb(), board_session(port, session=session, timeout=timeout) as client:
        state, done, queued, t = client.stat()
        cause = client.fault_reason if state in LATCHED_STATES else None
    d = {"state": state, "latched": state in LATCHED_STATES, "cause": cause, "done": done, "queued": queued,
         "board_time_s": t}
    if _print_json(d, as_json):
        return
    out = _out(None)
    out.print(f"state {state}{f' ({cause})' if cause else ''}{_latch_hint(state, port)}")
    out.print(f"done {'-' if done is None else done}, queued {'-' if queued is None else queued}, "
              f"board time {t:.3f} s", highlight=False)


# ---------------------------------------------------------------------- ping
@board_app.command("ping")
def ping_cmd(port: str = _port_opt(), count: int = typer.Option(4, "--count", "-c", min=1, max=10000,
                                                                 help="How many PINGs."),
             session: Optional[int] = _session_opt(), timeout: float = _timeout_opt(),
             as_json: Optional[str] = _json_opt()) -> None:
    """Round-trip times of PING (wall clock, retransmissions included)."""
    out = _out(as_json)
    rtts: list[float] = []
    with _verb(), board_session(port, session=session, timeout=timeout) as client:
        for i in range(count):
            t0 = time.perf_counter()
            client.command("PING")
            rtts.append((time.perf_counter() - t0) * 1000.0)
            if as_json != "-":
                out.print(f"PING {i + 1}: {rtts[-1]:.2f} ms", highlight=False)
        retrans = client.stats.retransmissions
    d = {"count": count, "rtt_ms": rtts, "min_ms": min(rtts), "mean_ms": statistics.fmean(rtts),
         "max_ms": max(rtts), "retransmissions": retrans}
    if _print_json(d, as_json):
        return
    out.print(f"{count} answered, round trip min/mean/max {d['min_ms']:.2f}/{d['mean_ms']:.2f}/{d['max_ms']:.2f} ms"
              f", {retrans} retransmitted lines", highlight=False)


# ---------------------------------------------------------------------- clear
@board_app.command("clear")
def clear_cmd(port: str = _port_opt(), yes: bool = typer.Option(False, "--yes", "-y",
                                                                  help="Clear without asking."),
              session: Optional[int] = _session_opt(), timeout: float = _timeout_opt()) -> None:
    """Clear a latched ESTOP, WDOG or FAULT (asks first unless --yes).

    After CLR the board is IDLE with an empty queue and holds the arm where it
    is; it accepts motion again. Check the arm first.
    """
    out = _out(None)
    after = None
    with _verb(), board_session(port, session=session, timeout=timeout) as client:
        state = client.stat()[0]
        if state not in LATCHED_STATES:
            out.print(f"nothing to clear: the board is {state}")
            return
        if yes or sys.stdin.isatty():  # else refused below, outside the session: bad input (2), not a board failure
            reason = f" ({client.fault_reason})" if client.fault_reason else ""
            if not yes and not typer.confirm(f"The board is latched in {state}{reason}. Clear it? The arm will "
                                             "accept motion again", default=False):
                out.print("not cleared")
                raise typer.Exit(1)
            client.command("CLR")
            after = client.stat()[0]
    if after is None:
        raise ArmbridgeError(f"the board is latched in {state}: clear asks for confirmation and stdin is not a "
                             "terminal; pass --yes to clear without asking")
    if after in LATCHED_STATES:
        raise BoardFailure(f"the board is still latched in {after} after CLR")
    out.print(f"cleared {state}: the board is {after}")


# ---------------------------------------------------------------------- rate
@board_app.command("rate")
def rate_cmd(hz: int = typer.Argument(..., min=RATE_MIN, max=RATE_MAX, help=f"Telemetry rate in Hz "
                                                                             f"({RATE_MIN} = off)."),
             port: str = _port_opt(), session: Optional[int] = _session_opt(), timeout: float = _timeout_opt()) -> None:
    """Set the board's telemetry rate (kept until the board resets or someone sets another)."""
    with _verb(), board_session(port, session=session, timeout=timeout) as client:
        client.set_rate(hz)
    _out(None).print(f"telemetry rate {hz} Hz" + (" (off)" if hz == 0 else ""))


# ---------------------------------------------------------------------- pen
@board_app.command("pen")
def pen_cmd(up: Optional[int] = typer.Option(None, "--up", metavar="US", help="Pen-up pulse width, us (500..2500)."),
            down: Optional[int] = typer.Option(None, "--down", metavar="US",
                                               help="Pen-down pulse width, us (500..2500)."),
            wait: Optional[int] = typer.Option(None, "--wait", metavar="MS",
                                               help="The board's dwell after a pen change, ms (0..2000)."),
            pen_down: Optional[bool] = typer.Option(None, "--lower/--lift",
                                                    help="Then put the pen down (or up), to see where it lands."),
            save: bool = typer.Option(False, "--save", help="Keep them across a reboot: CALID again under the "
                                                            "calibration id the board holds (armbridge calibrate)."),
            port: str = _port_opt(), session: Optional[int] = _session_opt(),
            timeout: float = _timeout_opt()) -> None:
    """Set the pen-lift servo's heights and settle (PENPOS; the firmware's defaults for those not given)."""
    from armbridge.executor.penpos import board_defaults, pen_pos_options, send_pen_pos

    given = pen_pos_options(up, down, wait, ("--up", "--down", "--wait"))  # bad values: one line, before the port opens
    pos = {**board_defaults(), **given}
    with _verb(), board_session(port, session=session, timeout=timeout) as client:
        send_pen_pos(client, pos)   # refused: one line, exit 1
        if pen_down is not None:
            client.command("PEN", int(pen_down))
        if save:
            cal = client.command("IDENT").payload[1]
            if cal in ("0", 0):
                raise BoardFailure("--save: the board holds no calibration to keep them with (IDENT cal 0); "
                                   "run armbridge calibrate, which saves the pen too")
            client.command("CALID", int(cal))
    _out(None).print(f"pen up {pos['up_us']} us, down {pos['down_us']} us, settle {pos['settle_ms']} ms"
                     + (f", saved with calibration {cal}" if save else " (until the board resets; --save keeps them)"),
                     highlight=False)


# ---------------------------------------------------------------------- monitor
@board_app.command("monitor")
def monitor_cmd(port: str = _port_opt(),
                rate: Optional[int] = typer.Option(None, "--rate", min=RATE_MIN, max=RATE_MAX, metavar="HZ",
                                                   help="Set the telemetry rate first [default: the board's]."),
                seconds: Optional[float] = typer.Option(None, "--for", min=0.0, metavar="SECONDS",
                                                        help="Stop after this long (board time) instead of Ctrl-C."),
                session: Optional[int] = _session_opt(), timeout: float = _timeout_opt()) -> None:
    """Live telemetry and events until Ctrl-C (plain lines when stdout is not a terminal)."""
    from armbridge.console.monitor import Monitor

    out = _out(None)
    mon = Monitor(out, port)
    with _verb(ctrl_c_ok=True):
        try:
            with board_session(port, session=session, timeout=timeout, rate_hz=rate,
                               on_telemetry=mon.on_telemetry, on_event=mon.on_event) as client:
                mon.run(client, seconds, rate if rate is not None else client.info.rate)
        finally:
            mon.close()
