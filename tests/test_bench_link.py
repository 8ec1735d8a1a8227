"""`armbridge bench link` in a reduced size, so the benchmark cannot rot.

Correctness only (no wall-clock targets: CI machines are noisy): every
waypoint arrives, the soak loses and repeats nothing, the JSON is complete.
"""
import json

import pytest
from typer.testing import CliRunner

from armbridge.bench import link
from armbridge.cli import build_app

pytestmark = pytest.mark.hil


def test_bench_link_quick_cli_writes_json(tmp_path, monkeypatch):
    monkeypatch.setattr(link, "QUICK", link.LinkBenchSize(waypoints=200, pings=20, estops=3, soak_s=6,
                                                          reset_every_s=3))
    out = tmp_path / "link.json"
    result = CliRunner().invoke(build_app(), ["bench", "link", "--quick", "--json", str(out)])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    tp, so, es = data["throughput"], data["soak"], data["estop"]
    assert tp["waypoints"] == 200 and tp["retransmitted"] == 0
    assert 0 < tp["line_capacity_used"] <= 1.0
    assert es["trials"] == 3 and es["byte_to_outputs_off"]["n"] == 3
    assert data["round_trip"]["n"] == 20
    assert so["plans"] >= 1 and so["executed"] == so["waypoints"]
    assert (so["lost"], so["duplicated"], so["wrong_value"], so["in_order"]) == (0, 0, 0, True)
    assert so["resets"] >= 1 and so["resyncs"] >= 1
    assert "sustained waypoints/s" in result.output


def test_counting_port_counts_and_forwards():
    class Fake:
        timeout = None

        def write(self, data):
            return len(data)

    port = link.CountingPort(Fake())
    port.write(b"abc")
    port.timeout = 0.5
    assert port.written == 3 and port._port.timeout == 0.5


def test_wave_respects_step_and_limits():
    import numpy as np

    from armbridge.robots.catalog import get_robot

    q = link.wave(1000, step_mrad=4.0)
    robot = get_robot("arm3r")
    assert np.abs(np.diff(q, axis=0)).max() <= 5  # 4 mrad, plus rounding
    assert robot.within_limits(q / 1000.0).all()
