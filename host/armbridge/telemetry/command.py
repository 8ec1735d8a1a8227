"""`armbridge view FILE`: open a run's .rrd recording in the Rerun viewer (rerun-sdk 0.41).

With a display (Linux: DISPLAY or WAYLAND_DISPLAY set; macOS and Windows always) the native
viewer opens. Without one, or with --web, --port or --no-open, rerun serves its web viewer
(`rerun --serve-web` / `--web-viewer`, bound to --bind, 127.0.0.1 by default) and the command
prints its address and serves until Ctrl-C; the browser opens by itself only where there is a
display and not --no-open. Rerun's own log lines are kept back (its warnings and errors pass).
A file that is not a recording is refused in one line before rerun sees it.
"""
from __future__ import annotations

import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Optional

import typer

from armbridge.errors import ArmbridgeError
from armbridge.telemetry.rrdfile import check_rrd

#: how long rerun may take to load the file and say where it serves (s; a loaded machine is slow)
SERVE_WAIT_S = 120.0
_URL = re.compile(r"connect at (https?://\S+)")
_HOSTING = re.compile(r"Hosting a web-viewer at (https?://\S+)")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def rerun_executable() -> str:
    """The `rerun` viewer of this environment: beside the Python running us, else on PATH."""
    here = Path(sys.executable).parent / "rerun"
    if here.is_file():
        return str(here)
    found = shutil.which("rerun")
    if found is None:
        raise ArmbridgeError("the rerun viewer is not installed: pip install rerun-sdk==0.41.0")
    return found


def has_display(environ: dict[str, str] | None = None, platform: str = sys.platform) -> bool:
    """Whether a native window can open: on Linux (and the BSDs) an X or Wayland display."""
    env = os.environ if environ is None else environ
    if not (platform.startswith("linux") or "bsd" in platform):
        return True
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY") or env.get("WAYLAND_SOCKET"))


def web_argv(exe: str, file: Path, port: int, bind: str, open_browser: bool) -> list[str]:
    """rerun serving its web viewer for `file` on `port` (0: a free one), its gRPC proxy on a free port."""
    return [exe, "--web-viewer" if open_browser else "--serve-web", "--bind", bind, "--web-viewer-port", str(port),
            "--port", "0", str(file)]


def _line(raw: bytes) -> str:
    return _ANSI.sub("", raw.decode("utf-8", "replace")).rstrip()


def _relay(line: str) -> None:
    """Rerun's warnings and errors pass, its INFO lines do not."""
    if " WARN " in line or " ERROR " in line or line.startswith("Error"):
        typer.echo(line, err=True)


def _stop(proc: subprocess.Popen) -> None:
    """End rerun and what it started: the `rerun` on PATH is a Python wrapper around the real
    binary, so the whole process group goes (rerun runs in a session of its own)."""
    for sig, wait in ((signal.SIGTERM, 10), (signal.SIGKILL, 10)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        try:
            proc.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
        time.sleep(0.2)  # the group's other members leave with it


def serve_web(file: Path, port: int, bind: str, open_browser: bool) -> int:
    """Serve the web viewer until rerun ends or a stop signal; prints the address at once."""
    exe = rerun_executable()
    argv = web_argv(exe, file, port, bind, open_browser)
    try:
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True)
    except OSError as exc:
        raise ArmbridgeError(f"cannot start the rerun viewer ({exe}): {exc.strerror}") from None
    assert proc.stdout is not None
    previous = {s: signal.signal(s, _raise_interrupt) for s in (signal.SIGTERM, signal.SIGHUP)}
    last = ""
    lines: queue.Queue[bytes] = queue.Queue()  # rerun's output, read by a thread: a silent rerun cannot hang us
    threading.Thread(target=_pump_lines, args=(proc.stdout, lines), daemon=True).start()
    try:
        deadline = time.monotonic() + SERVE_WAIT_S
        url = None
        while url is None:
            try:
                raw = lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                _stop(proc)
                raise ArmbridgeError(f"the rerun web viewer said nowhere it serves within {SERVE_WAIT_S:.0f} s"
                                     + (f": {last}" if last else "")) from None
            if not raw:  # rerun ended before it served
                rc = proc.wait()
                raise ArmbridgeError(f"the rerun web viewer did not start (exit {rc}): {last or 'no output'}")
            line = _line(raw)
            last = line or last
            m = _URL.search(line) or _HOSTING.search(line)
            if m:
                url = m.group(1)
            elif time.monotonic() > deadline:
                _stop(proc)
                raise ArmbridgeError(f"the rerun web viewer said nowhere it serves within {SERVE_WAIT_S:.0f} s")
            elif not line.startswith("Error"):  # rerun's own error line is the one line said if it stops
                _relay(line)
        typer.echo(f"the Rerun web viewer serves {file} at {url}")
        w, grpc = ports_of(url)
        if bind in ("127.0.0.1", "localhost", "::1") and w and grpc:
            typer.echo(f"(open it in a browser here; from another machine: ssh -L {w}:127.0.0.1:{w} "
                       f"-L {grpc}:127.0.0.1:{grpc} THIS-HOST, then the same address; Ctrl-C stops it)")
        else:
            typer.echo("(Ctrl-C stops it)")
        while raw := lines.get():
            _relay(_line(raw))
        return proc.wait()
    except KeyboardInterrupt:
        return 0
    finally:
        _stop(proc)
        for s, h in previous.items():
            signal.signal(s, h)


def _pump_lines(stream: Any, out: "queue.Queue[bytes]") -> None:
    """Every line of `stream` into `out`, then b"" at its end."""
    try:
        for raw in stream:
            out.put(raw)
    finally:
        out.put(b"")


def ports_of(url: str) -> tuple[int | None, int | None]:
    """The web viewer's HTTP port and its gRPC proxy's, from the address rerun prints
    (http://HOST:PORT?url=rerun+http://HOST:GRPC/proxy)."""
    from urllib.parse import parse_qs, urlsplit

    try:
        web = urlsplit(url)
        proxy = parse_qs(web.query).get("url", [""])[0]
        return web.port, urlsplit(proxy.replace("rerun+", "", 1)).port if proxy else None
    except ValueError:
        return None, None


def _raise_interrupt(signum, _frame) -> None:
    raise KeyboardInterrupt


def view_cmd(
    file: Path = typer.Argument(..., help="A recording (.rrd) written by `armbridge run`."),
    web: bool = typer.Option(False, "--web", help="Serve Rerun's web viewer even where a display is "
                                                  "(without a display it is always the web viewer)."),
    port: Optional[int] = typer.Option(None, "--port", min=0, max=65535, metavar="N",
                                       help="The web viewer's HTTP port [default: a free one]; implies --web."),
    bind: str = typer.Option("127.0.0.1", "--bind", metavar="ADDRESS", help="The address the web viewer listens on "
                                                         "(0.0.0.0: every interface)."),
    no_open: bool = typer.Option(False, "--no-open", help="Serve the web viewer and print its address; open "
                                                          "no browser (implies --web)."),
) -> None:
    """Open a recording in the Rerun viewer: the native one where there is a display, else
    (or with --web) Rerun's web viewer, served here; the command prints its address."""
    check_rrd(file)
    display = has_display()
    if web or no_open or port is not None or not display:
        rc = serve_web(file, port or 0, bind, open_browser=display and not no_open)
        if rc not in (0, -signal.SIGTERM):
            raise typer.Exit(rc)
        return
    exe = rerun_executable()
    try:
        rc = subprocess.run([exe, str(file)], check=False).returncode
    except OSError as exc:
        raise ArmbridgeError(f"cannot start the rerun viewer ({exe}): {exc.strerror}") from None
    except KeyboardInterrupt:
        rc = 0
    if rc != 0:
        typer.secho(f"the native viewer failed (exit {rc}); `armbridge view --web {file}` serves the web "
                    "viewer instead", fg="yellow", err=True)
        raise typer.Exit(rc)
