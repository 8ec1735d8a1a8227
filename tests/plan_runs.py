"""What the end-to-end tests share: a smooth test plan for the emulated arm3r,
a fixture (and its context manager, for module-scoped fixtures) that keeps the
ports run_plan opens (to look at the emulator after a run), the board's own completion log against the plan, and a firmware that
raises (to see how each runner reports a crash)."""
from __future__ import annotations

import math
import shutil
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest

import armbridge.link.transport as transport
from armbridge.link.protocol import to_milli
from armbridge.plans.format import make_plan
from armbridge.resources import firmware_dir
from armbridge.robots import ARM3R

MID = np.array([math.pi / 2, -math.pi / 2, 0.0])  # the emulator's start pose: mid-range


def wave_plan(k: int = 200, dt: float = 0.05, amp=(0.4, 0.3, 0.4), freq: float = 0.5):
    """k waypoints dt apart on q = MID + amp (1 - cos(2 pi f t)) / 2: starts at rest at MID.

    Peak joint speed amp * pi * f (0.63 rad/s for 0.4 rad at 0.5 Hz)."""
    t = dt * np.arange(1, k + 1)
    q = MID + np.outer((1 - np.cos(2 * np.pi * freq * t)) / 2, amp)
    return make_plan(ARM3R, q, dt, {"tool": "armbridge tests", "shape": "wave"})


@contextmanager
def _spied_ports(opener) -> Iterator[list]:
    """transport.open_port replaced by `opener(real_open_port, url, ...)` inside the block; the
    ports it opens in a list (filled as they open), closed on leaving."""
    opened: list = []
    real = transport.open_port

    def spy(url, *a, **kw):
        port = opener(real, url, *a, **kw)
        opened.append(port)
        return port

    mp = pytest.MonkeyPatch()
    mp.setattr(transport, "open_port", spy)
    try:
        yield opened
    finally:
        mp.undo()
        for p in opened:
            p.close()


def opened_ports():
    """The ports `transport.open_port` opens inside the block, in a list (filled as they
    open), so a test can look at the emulator after a run; closed on leaving. A
    context manager, so a module-scoped fixture can keep one emulator for its tests."""
    return _spied_ports(lambda real, url, *a, **kw: real(url, *a, **kw))


def lockstep_ports():
    """As `opened_ports`, but every `emu:` url (speed 0) opens as a lockstep port
    (emulator/lockstep.py: host and board take turns in one thread), so a run repeats
    bit for bit and a fault can be timed from an earlier run of the same plan and seed."""
    from armbridge.emulator.url import open_lockstep_port

    return _spied_ports(lambda real, url, *a, **kw: open_lockstep_port(url) if url.startswith("emu:")
                        else real(url, *a, **kw))


@pytest.fixture
def ports():
    """Record the ports run_plan opens, so a test can look at the emulator afterwards."""
    with opened_ports() as opened:
        yield opened


def sent_values(plan) -> list[tuple[int, ...]]:
    """The joint values of each waypoint as the host puts them on the wire (milli-units)."""
    return [tuple(to_milli(q)) for q in plan.q]


def assert_executed_once_with_values(emu, plan) -> None:
    """Every waypoint exactly once, in order, with the values the host sent (the board's own log)."""
    ids = [wid for _, wid, _ in emu.executed]
    assert ids == list(range(len(plan.q))), ids
    assert [tuple(v) for _, _, v in emu.executed] == sent_values(plan)


def crashing_firmware(root) -> None:
    """An esp32 firmware folder under `root` whose Board raises on its sixth poll."""
    (root / "esp32").mkdir()
    shutil.copytree(firmware_dir() / "common", root / "common")
    shutil.copy(firmware_dir() / "esp32" / "config.py", root / "esp32")
    (root / "esp32" / "arm.py").write_text(
        "class Board:\n"
        "    def __init__(self, hal, cfg):\n"
        "        self.state = 'IDLE'\n"
        "        self.polls = 0\n"
        "    def poll(self):\n"
        "        self.polls += 1\n"
        "        if self.polls > 5:\n"
        "            raise RuntimeError('boom')\n"
    )
