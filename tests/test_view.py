"""`armbridge view FILE` (telemetry/command.py): the native viewer where there is a display, else
Rerun's web viewer served for the file, its address printed; a file that is not a recording is
refused in one line. The web viewer in a real browser: tests/test_view_web.py."""
from __future__ import annotations

import os
import re
import select
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
import typer

from armbridge.plans.format import make_plan
from armbridge.robots import ARM3R
from armbridge.telemetry import command as view
from armbridge.telemetry.recording import Recording

ARMBRIDGE = str(Path(sys.executable).parent / "armbridge")
ADDRESS = re.compile(r"serves .* at (http://\S+)")


def recording(path: Path) -> Path:
    plan = make_plan(ARM3R, [[1.4, -1.5, 0.0], [1.7, -1.3, 0.2], [1.5, -1.6, 0.1]], 0.5)
    with Recording(path, ARM3R, plan, flush_every=10) as rec:
        for i in range(60):
            q = plan.q[min(i // 20, 2)]
            rec.telemetry(0.02 * i, q, q, [0, 0, 0], done=i // 20)
        rec.event(0.0, "START 0")
        rec.summary({"plan": "three", "robot": "arm3r", "completed": True})
    return path


def headless_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")}


class Served:
    """`armbridge view FILE ...` running headless; .url once it printed its address."""

    def __init__(self, *argv: str, wait_s: float = 240.0) -> None:
        self.p = subprocess.Popen([ARMBRIDGE, "view", *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  stdin=subprocess.DEVNULL, env=headless_env(), start_new_session=True)
        self.out = ""
        end = time.monotonic() + wait_s
        while (m := ADDRESS.search(self.out)) is None or "Ctrl-C stops it" not in self.out:
            left = end - time.monotonic()
            assert left > 0 and self.p.poll() is None, (self.out, self.p.stderr.read() if self.p.poll() else "")
            ready, _, _ = select.select([self.p.stdout], [], [], min(left, 1.0))
            if ready:  # the fd itself: a buffered readline could keep a second line from select
                self.out += os.read(self.p.stdout.fileno(), 65536).decode()
        self.url = m.group(1)

    def stop(self, sig: int = signal.SIGTERM) -> int:
        if self.p.poll() is None:
            self.p.send_signal(sig)
        try:
            return self.p.wait(timeout=120)
        finally:
            if self.p.poll() is None:
                os.killpg(self.p.pid, signal.SIGKILL)


def port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(5)
        return s.connect_ex(("127.0.0.1", port)) == 0


def test_view_refuses_what_is_not_a_recording(tmp_path):
    text = tmp_path / "notes.rrd"
    text.write_text("hello\n")
    empty = tmp_path / "empty.rrd"
    empty.write_bytes(b"")
    for path, says in ((text, "is not a Rerun recording"), (empty, "is empty"), (tmp_path / "no.rrd", "no such")):
        r = subprocess.run([ARMBRIDGE, "view", str(path)], capture_output=True, text=True, timeout=300,
                           env=headless_env())
        lines = [x for x in r.stderr.splitlines() if x.strip()]
        assert r.returncode == 2 and len(lines) == 1 and says in lines[0], (path, r.stderr)
        assert r.stdout == ""


def test_a_display_is_x_or_wayland_on_linux():
    assert not view.has_display({}, "linux")
    assert view.has_display({"DISPLAY": ":0"}, "linux")
    assert view.has_display({"WAYLAND_DISPLAY": "wayland-0"}, "linux")
    assert view.has_display({}, "darwin") and view.has_display({}, "win32")


def test_the_web_viewer_is_asked_for_with_the_port_and_bind(tmp_path):
    argv = view.web_argv("rerun", tmp_path / "r.rrd", 9099, "127.0.0.1", open_browser=False)
    assert argv == ["rerun", "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", "9099", "--port", "0",
                    str(tmp_path / "r.rrd")]
    assert view.web_argv("rerun", Path("x"), 0, "0.0.0.0", open_browser=True)[1] == "--web-viewer"
    assert view.ports_of("http://127.0.0.1:41643?url=rerun%2Bhttp%3A%2F%2Flocalhost%3A39075%2Fproxy") == (41643, 39075)


def test_a_failed_native_viewer_says_how_to_get_the_web_one(tmp_path, monkeypatch, capsys):
    rrd = recording(tmp_path / "r.rrd")

    class Failed:
        returncode = 1

    monkeypatch.setattr(view, "has_display", lambda: True)
    monkeypatch.setattr(view.subprocess, "run", lambda argv, check: Failed())
    with pytest.raises(typer.Exit):
        view.view_cmd(rrd, web=False, port=None, bind="127.0.0.1", no_open=False)
    assert f"armbridge view --web {rrd}" in capsys.readouterr().err


@pytest.mark.hil
def test_without_a_display_view_serves_the_web_viewer_and_prints_its_address(tmp_path):
    rrd = recording(tmp_path / "r.rrd")
    served = Served(str(rrd))
    try:
        web, grpc = view.ports_of(served.url)
        assert web and grpc and served.url.startswith("http://127.0.0.1:")
        assert f"ssh -L {web}:127.0.0.1:{web} -L {grpc}:127.0.0.1:{grpc}" in served.out
        with urllib.request.urlopen(served.url, timeout=120) as page:
            assert page.status == 200 and "re_viewer" in page.read().decode()
        assert port_open(grpc)
    finally:
        rc = served.stop()
    assert rc == 0, served.p.stderr.read().decode()
    assert not port_open(web) and not port_open(grpc)  # rerun went with it


@pytest.mark.hil
def test_port_sets_the_web_viewers_port(tmp_path):
    with socket.socket() as s:  # a port free a moment ago
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    served = Served(str(recording(tmp_path / "r.rrd")), "--port", str(port), "--no-open")
    try:
        assert view.ports_of(served.url)[0] == port
    finally:
        assert served.stop(signal.SIGINT) == 0


@pytest.mark.hil
def test_a_busy_port_is_one_line(tmp_path):
    rrd = recording(tmp_path / "r.rrd")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        r = subprocess.run([ARMBRIDGE, "view", str(rrd), "--port", str(s.getsockname()[1])], capture_output=True,
                           text=True, timeout=300, env=headless_env())
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert lines[0].startswith("error: the rerun web viewer did not start") and "in use" in lines[0]


def test_a_silent_viewer_process_cannot_hang_view(tmp_path, monkeypatch):
    """A rerun that starts and says nothing (no address, no exit) is stopped after SERVE_WAIT_S with
    one line: view never waits on it for ever (one run hung 300 s on a loaded machine)."""
    import stat

    from armbridge.errors import ArmbridgeError
    from armbridge.telemetry import command as C

    silent = tmp_path / "rerun"
    silent.write_text("#!/bin/sh\nexec sleep 60\n")
    silent.chmod(silent.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setattr(C, "rerun_executable", lambda: str(silent))
    monkeypatch.setattr(C, "SERVE_WAIT_S", 1.0)
    with pytest.raises(ArmbridgeError, match="said nowhere it serves within 1 s"):
        C.serve_web(recording(tmp_path / "r.rrd"), 0, "127.0.0.1", open_browser=False)
