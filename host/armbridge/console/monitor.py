"""`armbridge board monitor`: the board's telemetry and events as they arrive.

On a terminal: a live rich view (state, board time, done, free slots, and per
joint q / set point / error / effort) above the latest events. Elsewhere (a
pipe, a log file): one plain line per event and per telemetry sample, so the
output can be read by a program or grepped.
"""
from __future__ import annotations

from collections import deque

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from armbridge.executor.signals import holding
from armbridge.link import protocol as P
from armbridge.link.protodef import LATCHED_STATES

EVENTS_SHOWN = 12


class Monitor:
    """Collects what the board sends (the session's callbacks) and shows it."""

    def __init__(self, console: Console, port: str) -> None:
        self.console = console
        self.port = port
        self.live_view = console.is_terminal
        self.sample: tuple[float, P.Telemetry] | None = None
        self.events: deque[str] = deque(maxlen=EVENTS_SHOWN)
        self.samples = 0
        self.n_events = 0
        self.header = ""
        self._live: Live | None = None

    # ------------------------------------------------------------ callbacks
    def on_telemetry(self, t: float, m: P.Telemetry) -> None:
        self.sample = (t, m)
        self.samples += 1
        if not self.live_view:
            q = " ".join(f"{x:.3f}" for x in m.q)
            tg = " ".join(f"{x:.3f}" for x in m.target)
            self._line(f"{t:10.3f}  T {m.state} done {'-' if m.done is None else m.done} free {m.free} "
                       f"q {q} target {tg}")

    def on_event(self, t: float | None, ev: P.Event) -> None:
        text = f"{'' if t is None else f'{t:10.3f}'}  EV {' '.join([ev.kind, *ev.args])}"
        self.n_events += 1
        self.events.append(text)
        if not self.live_view:
            self._line(text)

    def _line(self, text: str) -> None:
        # Ctrl-C waits for the line: rich would write a line cut short by it twice.
        with holding():
            self.console.print(text, highlight=False, markup=False, soft_wrap=True)

    # ------------------------------------------------------------ view
    def render(self) -> Group:
        head = Text(self.header + "   Ctrl-C stops", style="bold")
        if self.sample is None:
            body: Table | Text = Text("waiting for telemetry ...")
        else:
            t, m = self.sample
            body = Table(show_header=True, header_style="bold",
                         title=f"board time {t:.3f} s   state {m.state}"
                               f"{' (latched)' if m.state in LATCHED_STATES else ''}   "
                               f"done {'-' if m.done is None else m.done}   free {m.free}")
            for col in ("joint", "q (rad)", "set point (rad)", "error (mrad)", "effort"):
                body.add_column(col, justify="right")
            for j in range(len(m.q)):
                body.add_row(str(j + 1), f"{m.q[j]:.3f}", f"{m.target[j]:.3f}",
                             f"{(m.target[j] - m.q[j]) * 1000:.1f}", f"{m.effort[j]:+.2f}")
        events = Text("\n".join(self.events) if self.events else "(no events yet)")
        return Group(head, body, Text("events", style="bold"), events)

    def run(self, client, seconds: float | None, rate: int) -> None:
        """Until Ctrl-C (a Stopped/KeyboardInterrupt out of here) or `seconds` of board time;
        `rate`: the telemetry rate in force (Hz)."""
        info = client.info
        self.header = f"{info.fw} {info.version} on {self.port}: {info.n} joints, telemetry {rate} Hz, state {info.state}"
        if not self.live_view:
            self._line(self.header)
        if rate == 0:
            self._line("the board sends no telemetry (rate 0): --rate HZ turns it on")
        if self.live_view:
            self._live = Live(get_renderable=self.render, console=self.console, refresh_per_second=8,
                              transient=False)
            self._live.start()
        client.drain(seconds if seconds is not None else float("inf"))

    def close(self) -> None:
        """Stop the live view and say what was seen (also after Ctrl-C)."""
        if self._live is not None:
            try:
                self._live.stop()
            except OSError:
                pass  # the terminal is gone
            self._live = None
        try:
            self.console.print(f"monitor stopped: {self.samples} telemetry samples, {self.n_events} events",
                               highlight=False)
        except OSError:
            pass
