"""Control-function timing of the arduino_pump .elf in simavr while the executor streams
2 ms waypoints at line rate (bench link's throughput case), with a Traj::plan probe;
only the probes' records inside the stream count. Prints JSON (microseconds).

usage: .venv/bin/python firmware/arduino_pump/tests/stream_timing.py ELF [WAYPOINTS]
  EXTRA="rs=PumpBoard::read_sensors,ev=Link::event" adds probes (name=function, <= 16 in all)."""
import json
import os
import sys
from pathlib import Path

import armbridge.emulator.simavr_runner as SR
from armbridge.bench import link as L
from armbridge.emulator.pump_hal import _spread, pump_timing

ELF = Path(sys.argv[1]).resolve()
n = int(sys.argv[2]) if len(sys.argv) > 2 else 1500
EXTRA = dict(kv.split("=") for kv in os.environ.get("EXTRA", "").split(",") if kv)
SR.DEFAULT_PROBES = dict(SR.DEFAULT_PROBES, plan="Traj::plan", **EXTRA)


def _this_elf(folder: Path, elf: str) -> Path:   # run ELF, do not rebuild the checkout's
    return ELF


SR.firmware_elf = _this_elf

b = L.BOARDS["arduino_pump"]
port, client = L._session(b.url, b.robot)
try:
    client.set_rate(0)
    q = L.wave(n, b.stream_step, b.period, b.robot)
    client.execute([L.POSITION_MS], [q[0].tolist()])
    emu = port.emulator
    t0 = client.now()
    client.execute([2] * n, q.tolist())
    t1 = client.now()
    timing = pump_timing(emu, window=(t0, t1))  # the period, the control function, RAM: the stream's alone
    us = 1e6 / timing["hz"]

    def per_call(name: str) -> dict:
        """A probe's calls in the stream, in us, and how many a control period."""
        calls = _spread([d * us for t, d in emu.runner.stats["probes"].get(name, []) if t0 <= t <= t1])
        return dict(calls, per_period=calls["n"] / max(1, timing["control_cycles"]["n"]))

    control = {k: v * us for k, v in timing["control_cycles"].items() if k in ("mean", "min", "max")}
    out = {"elf": str(ELF), "waypoints": n, "stream_s": t1 - t0, "wp_per_s": n / (t1 - t0),
           "period_us": dict(timing["control_period_us"], jitter=timing["control_jitter_us"]),
           "control_us": dict(control, max_cycles=int(timing["control_cycles"]["max"])),
           **{f"{name}_us": per_call(name) for name in ("plan", "parse", "crc", *EXTRA)},
           **{k: timing[k] for k in ("flash_bytes", "static_ram_bytes", "free_ram_bytes")}}
    print(json.dumps(out, indent=1, default=float))
finally:
    port.close()
