"""How a run ends when it cannot finish (executor/run.py): the e-stop and its confirmation, for a stop
signal (`stop_run`) and for any other failure while the arm may move (`fail_run`)."""
from __future__ import annotations

from armbridge.errors import ArmbridgeError
from armbridge.executor.client import LATCHED_STATES, BoardClient
from armbridge.executor.summary import Summary

ESTOP_CONFIRM_S = 0.5  # board time the run waits, after sending the e-stop, for the board to report ESTOP


def send_estop(client: BoardClient, summary: Summary, rec=None, why: str | None = None) -> None:
    """The e-stop, then a bounded wait (ESTOP_CONFIRM_S of board time) for the board to
    report ESTOP (its `EV ESTOP` or a telemetry line; over Modbus its status register),
    as a G-code sender waits for the controller's alarm report: the host keeps reading
    meanwhile (a board in lockstep with its host, the emulator at speed 0, only takes
    the byte in while it is read), the recording gets the event, and the run says
    whether the board confirmed the stop instead of hoping the byte landed. Every stop
    and failure of every board's run takes this one path (`stop_run`, `fail_run`). `why`:
    logged to the recording's errors as the byte goes out ("stopped by SIGINT, e-stop
    sent"), and the outcome after the wait."""
    try:
        client.estop()
        summary.estop_sent = True
    except Exception:  # noqa: BLE001 - the port may be gone; the board's watchdog stops the arm
        pass
    if rec is not None and why is not None:
        rec.error(None, f"{why}, " + ("e-stop sent" if summary.estop_sent else "e-stop could not be sent"), "error")
    if not summary.estop_sent:
        return
    try:
        client.drain(ESTOP_CONFIRM_S, until=lambda: client.state == "ESTOP", resync=False)
    except (Exception, KeyboardInterrupt):  # noqa: BLE001 - the port went away; a signal: the byte is sent
        pass
    summary.estop_confirmed = client.state == "ESTOP"
    if not summary.estop_confirmed:
        try:
            client.estop()  # once more: the board may have been booting when the first came
        except Exception:  # noqa: BLE001 - the port may be gone; the board's watchdog stops the arm
            pass
    if rec is not None and why is not None:
        rec.error(None, estop_note(summary), "info" if summary.estop_confirmed else "error")


def estop_note(summary: Summary) -> str:
    """What became of the e-stop, as the run's messages say it."""
    if summary.estop_confirmed:
        return "e-stop sent and confirmed by the board"
    if summary.estop_sent:
        return f"e-stop sent, not confirmed by the board within {ESTOP_CONFIRM_S * 1000:.0f} ms"
    return "e-stop could not be sent"


def stop_run(client: BoardClient, summary: Summary, rec, stop: KeyboardInterrupt) -> None:
    """A stop signal mid-run: the e-stop byte at once and its confirmation awaited, so
    the recording holds the ESTOP event and the last samples."""
    summary.stopped_by_user = True
    summary.stopped_by = getattr(stop, "name", "SIGINT")
    send_estop(client, summary, rec, f"stopped by {summary.stopped_by}")
    summary.final_state = client.state


def fail_run(client: BoardClient, summary: Summary, rec, exc: BaseException) -> None:
    """Any other failure while the arm may move: e-stop unless the board stopped itself."""
    if client.state not in LATCHED_STATES:
        send_estop(client, summary)
    summary.error = str(exc) or type(exc).__name__
    if summary.estop_sent and isinstance(exc, ArmbridgeError):
        check = "" if summary.estop_confirmed else "check the arm; "
        summary.error += f"; {estop_note(summary)} ({check}the next run needs --clear)"
    summary.final_state = client.state
    summary.fault = client.fault_reason
    if rec is not None:
        rec.error(None, f"run failed: {summary.error}", "error")
