"""`armbridge view` without a display, looked at in a real headless browser: Debian's chromium
(scripts/setup.sh installs it; missing, the test skips here and fails under ARMBRIDGE_REQUIRE_HIL=1)
driven over the DevTools protocol on a pipe (tests/cdp_pipe.py), software GL (SwiftShader).

The page must load Rerun's viewer (its wasm), open the recording's stream from the gRPC proxy the
command started (the `url=` of the printed address) and receive the recording over it, and the
screenshot must show a drawn viewer, not a blank or uniform page. Generous limits, polled: a
loaded 2-core machine compiles the viewer's wasm slowly; nothing is timed.
"""
from __future__ import annotations

import io
import time

import numpy as np
import pytest

from cdp_pipe import Browser, find_chromium
from require import missing
from test_view import Served, recording

from armbridge.telemetry import command as view

pytestmark = pytest.mark.hil

LOAD_S = 300.0  # at most this long for the viewer to load and take the recording in


def colours(png: bytes) -> tuple[int, float]:
    """Distinct colours in the screenshot, and the share of its commonest one."""
    from PIL import Image

    with Image.open(io.BytesIO(png)) as im:
        px = np.asarray(im.convert("RGB")).reshape(-1, 3)
    _, counts = np.unique(px, axis=0, return_counts=True)
    return len(counts), float(counts.max() / counts.sum())


def test_the_web_viewer_shows_the_recording_in_a_headless_browser(tmp_path):
    exe = find_chromium()
    if exe is None:
        missing("chromium is not installed (scripts/setup.sh as root installs it: apt-get install chromium)")
    rrd = recording(tmp_path / "run.rrd")
    served = Served(str(rrd))
    browser = Browser(exe)
    try:
        _web, grpc = view.ports_of(served.url)
        browser.open(served.url)
        stream: list[str] = []
        got = 0
        shot = b""
        end = time.monotonic() + LOAD_S
        while time.monotonic() < end:
            browser.pump(3.0)
            stream = [rid for rid, url in browser.requests().items()
                      if f":{grpc}/" in url and url.endswith("/ReadMessages")]
            got = browser.received(stream)
            shot = browser.screenshot()
            n, top = colours(shot)
            if got >= 0.5 * rrd.stat().st_size and n > 300 and top < 0.97:
                browser.pump(3.0)  # a last frame with the data in it
                shot = browser.screenshot()
                break
        (tmp_path / "viewer.png").write_bytes(shot)
        urls = list(browser.requests().values())
        assert any(u.endswith("re_viewer_bg.wasm") for u in urls), urls       # the viewer itself
        assert stream, f"the page never opened the recording's stream on :{grpc}: {urls}"
        assert got >= 0.5 * rrd.stat().st_size, (got, rrd.stat().st_size)  # ... and the recording came over it
        n, top = colours(shot)
        assert n > 300 and top < 0.97, (n, top, tmp_path / "viewer.png")     # a drawn viewer, not a blank page
    finally:
        browser.close()
        assert served.stop() == 0
