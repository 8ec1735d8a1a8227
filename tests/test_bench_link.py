"""`armbridge bench link` in a reduced size, so the benchmark cannot rot.

Correctness only (no wall-clock targets: CI machines are noisy): every
waypoint arrives, the soak loses, repeats and alters nothing, v2 lets no
damaged line through, the JSON is complete and its numbers agree with each
other.
"""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from armbridge.bench import link
from armbridge.cli import build_app
from armbridge.link import protocol as P
from require import missing


@pytest.mark.hil
def test_bench_link_quick_cli_writes_json(tmp_path, monkeypatch):
    monkeypatch.setattr(link, "QUICK", link.LinkBenchSize(damaged_lines=5000, waypoints=200, throughput_runs=1,
                                                          pings=20, estops=3, soak_s=6, reset_every_s=3))
    out = tmp_path / "link.json"
    result = CliRunner().invoke(build_app(), ["bench", "link", "--quick", "--json", str(out)])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    tp, so, es, ud = data["throughput"], data["soak"], data["estop"], data["undetected"]

    # Undetected errors: both versions judged at least the damaged lines asked for; v2 lets none through.
    for v in ("v1", "v2"):
        assert ud[v]["damaged"] >= 5000 and ud[v]["lines"] * ud[v]["copies_per_line"] > ud[v]["damaged"]
        assert ud[v]["rate"] == ud[v]["undetected"] / ud[v]["damaged"]
    assert ud["v2"]["undetected"] == 0 and ud["v2"]["examples"] == []
    assert ud["v2"]["rate_upper_95"] == pytest.approx(3 / ud["v2"]["damaged"])

    # Throughput: every byte the host wrote is accounted for by verb, W lines carry 4 more CRC digits than v1's.
    assert tp["waypoints"] == 200 and len(tp["waypoints_per_s_each"]) == 1
    assert 0 < tp["line_capacity_used"] <= 1.0
    assert sum(tp["bytes_by_verb"].values()) == pytest.approx(tp["bytes_per_waypoint"] * 200)
    assert tp["w_line_bytes"] - tp["v1_w_line_bytes"] == 4
    assert tp["line_rate_ceiling_wps"] == pytest.approx(11520 / tp["w_line_bytes"])
    assert tp["waypoints_per_s"] <= tp["line_rate_ceiling_wps"] * 1.001, "faster than the line can carry"
    assert tp["retransmitted"] >= 0 and tp["pings"] >= 0

    assert es["trials"] == 3 and es["byte_to_outputs_off"]["n"] == 3
    assert data["round_trip"]["n"] == 20
    assert so["plans"] >= 1 and so["executed"] == so["waypoints"]
    assert (so["lost"], so["duplicated"], so["wrong_value"], so["in_order"]) == (0, 0, 0, True)
    assert so["resets"] >= 1 and so["resyncs"] >= 1
    assert data["targets"]["v2 undetected == 0"] is True
    assert data["targets"]["soak 0 lost / 0 duplicated / 0 wrong, in order"] is True
    assert "undetected errors" in result.output and "targets:" in result.output


def test_judge_counts_lost_duplicated_and_wrong_values():
    sent = [(0, (1, 2, 3)), (1, (4, 5, 6)), (2, (7, 8, 9))]
    assert link.judge(sent, sent) == {"lost": 0, "duplicated": 0, "wrong_value": 0, "in_order": True}
    assert link.judge(sent, sent[:2])["lost"] == 1
    v = link.judge(sent, [sent[0], sent[1], sent[1], sent[2]])
    assert (v["duplicated"], v["wrong_value"], v["in_order"]) == (1, 0, False)
    v = link.judge(sent, [sent[0], (1, (4, 5, 60)), sent[2]])  # right id, a wrong value
    assert (v["lost"], v["duplicated"], v["wrong_value"], v["in_order"]) == (0, 0, 1, True)
    v = link.judge(sent, [sent[0], sent[2], sent[1]])
    assert (v["lost"], v["duplicated"], v["wrong_value"], v["in_order"]) == (0, 0, 0, False)
    # Ids that wrap: the same id sent twice with different values, each once.
    wrapped = [(5, (1, 1, 1)), (5, (2, 2, 2))]
    assert link.judge(wrapped, wrapped)["wrong_value"] == 0
    assert link.judge(wrapped, [(5, (1, 1, 1)), (5, (1, 1, 1))])["wrong_value"] == 1


def test_undetected_errors_reaches_the_count_the_same_for_any_workers():
    """Counting only: v1's rate (about 2.4e-6) needs the full size to show
    (docs/benchmarks.md); damage.py's own tests check the judgement."""
    r = link.undetected_errors(3000, version=1, workers=1, copies=20)
    assert r["damaged"] >= 3000 and r["lines"] * 20 > r["damaged"]
    assert len(r["examples"]) == min(5, r["undetected"]) and r["crc"].startswith("CRC-16")
    again = link.undetected_errors(3000, version=1, workers=2, copies=20)
    assert (again["lines"], again["damaged"], again["undetected"]) == (r["lines"], r["damaged"], r["undetected"])


def test_counting_port_counts_by_verb_and_forwards():
    class Fake:
        timeout = None

        def write(self, data):
            return len(data)

    port = link.CountingPort(Fake())
    w = P.encode(7, "W", 1, 2, 3, 4, 5, epoch=9)
    port.write(w)
    port.write(P.encode(8, "PING", epoch=9))
    port.write(P.ESTOP_BYTE)
    port.timeout = 0.5
    assert port.written == len(w) + len(P.encode(8, "PING", epoch=9)) + 1
    assert port.by_verb["W"] == len(w) and port.by_verb["ESTOP"] == 1 and "PING" in port.by_verb
    assert port._port.timeout == 0.5


def test_wave_respects_step_and_limits():
    from armbridge.robots.catalog import get_robot

    q = link.wave(1000, step_mrad=4.0)
    robot = get_robot("arm3r")
    assert np.abs(np.diff(q, axis=0)).max() <= 5  # 4 mrad, plus rounding
    assert robot.within_limits(q / 1000.0).all()


@pytest.mark.hil
def test_bench_link_quick_on_the_pump_board(tmp_path, monkeypatch):
    """`--board arduino_pump`: the same measurements on the .elf in simavr (lockstep, sim
    time), the soak judged from the board's own log, and the Modbus round trip; no damage
    model (the codec's, not the board's)."""
    if shutil.which("avr-gcc") is None or not Path("/usr/include/simavr/sim_avr.h").is_file():
        missing("the AVR toolchain or libsimavr-dev is missing (scripts/setup.sh as root installs them)")
    monkeypatch.setattr(link, "QUICK", link.LinkBenchSize(damaged_lines=1, waypoints=100, throughput_runs=1,
                                                          pings=10, estops=2, soak_s=5, reset_every_s=3))
    out = tmp_path / "pump.json"
    result = CliRunner().invoke(build_app(), ["bench", "link", "--quick", "--board", "arduino_pump",
                                              "--json", str(out)])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert data["board"] == "arduino_pump" and data["clock"].startswith("emulator") and "undetected" not in data
    tp, so, es, mb = data["throughput"], data["soak"], data["estop"], data["modbus"]
    assert tp["waypoints"] == 100 and sum(tp["bytes_by_verb"].values()) == pytest.approx(tp["bytes_per_waypoint"] * 100)
    assert tp["waypoints_per_s"] <= tp["line_rate_ceiling_wps"] * 1.001, "faster than the line can carry"
    assert es["trials"] == 2 and es["byte_to_outputs_off"]["n"] == 2
    assert es["byte_to_outputs_off"]["max_ms"] <= 10.0          # within one control period, in sim time
    assert data["round_trip"]["n"] == 10
    assert mb["n"] == 10 and mb["clock"] == "emulator" and mb["read_one"]["min_ms"] >= mb["wire_read_ms"] - 1.0
    assert so["plans"] >= 1 and so["resets"] >= 1 and so["resyncs"] >= 1
    assert (so["lost"], so["duplicated"], so["wrong_value"], so["in_order"]) == (0, 0, 0, True), so
    assert "v2 undetected == 0" not in data["targets"]
    assert "Modbus one register" in result.output and "targets:" in result.output
