"""Control-function timing of the arduino_pump .elf in simavr while the executor streams
2 ms waypoints at line rate (bench link's throughput case), with a Traj::plan probe;
only the probes' records inside the stream count. Prints JSON (microseconds).

usage: .venv/bin/python firmware/arduino_pump/tests/stream_timing.py ELF [WAYPOINTS]
  EXTRA="rs=PumpBoard::read_sensors,ev=Link::event" adds probes (name=function, <= 16 in all)."""
import json
import os
import sys
from pathlib import Path

import numpy as np

import armbridge.emulator.simavr_runner as SR
from armbridge.bench import link as L

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
    hz = float(emu.runner.harness.hz)
    pr = emu.runner.stats["probes"]

    def win(name):
        return [(t, d) for t, d in pr.get(name, []) if t0 <= t <= t1]
    ctl = win("control")
    ent = [t for t, _ in ctl]
    per = np.diff(ent) * 1e6
    cus = np.array([d for _, d in ctl]) / hz * 1e6
    plan = np.array([d for _, d in win("plan")]) / hz * 1e6
    parse = np.array([d for _, d in win("parse")]) / hz * 1e6
    crc = np.array([d for _, d in win("crc")]) / hz * 1e6
    out = {"elf": str(ELF), "waypoints": n, "stream_s": t1 - t0, "wp_per_s": n / (t1 - t0),
           "period_us": {"n": int(per.size), "mean": per.mean(), "min": per.min(), "max": per.max(),
                         "jitter": per.max() - per.min()},
           "control_us": {"n": int(cus.size), "mean": cus.mean(), "max": cus.max(),
                          "max_cycles": int(max(d for _, d in ctl))},
           "plan_us": {"n": int(plan.size), "mean": plan.mean(), "max": plan.max(), "min": plan.min(),
                       "per_period": plan.size / max(1, cus.size)},
           "parse_us": {"n": int(parse.size), "mean": parse.mean(), "max": parse.max()},
           "crc_us": {"n": int(crc.size), "mean": crc.mean(), "max": crc.max()},
           "extra_us": {k: (lambda a: {"n": int(a.size), "per_period": a.size / max(1, cus.size), "mean": float(a.mean()) if a.size else None, "max": float(a.max()) if a.size else None})(np.array([d for _, d in win(k)]) / hz * 1e6) for k in EXTRA},
           "flash_bytes": emu.runner.elf.flash_bytes, "static_ram_bytes": emu.runner.elf.static_ram_bytes,
           "free_ram_bytes": (emu.runner.stats["min_sp"] or 0) - emu.runner.elf.ram_end_of_statics}
    print(json.dumps(out, indent=1, default=float))
finally:
    port.close()
