"""The control period's timing of the arduino_pump .elf in simavr, cycle-exact, under load:
the executor streams 2 ms waypoints at line rate (bench link's throughput case), then
e-stop bytes come at drifting phases of the period (some while its interrupt runs); or
(MODE=modbus) the same stream over Modbus RTU, one FC16 a waypoint, with FC4 reads
between. Only the probes' records inside the load count. Prints JSON (microseconds;
`*_cycles` at 16 MHz). The period's start (isr_period_us) is the entry of the period proper
(ctl_period: from the Timer5 interrupt after its alignment wait) where the image has one;
period_us is between entries of PumpBoard::control (before the timer: the micros()
schedule of the main loop). pass_us: each main-loop pass less the periods inside it.

usage: .venv/bin/python firmware/arduino_pump/tests/stream_timing.py ELF [WAYPOINTS [ESTOPS]]
  MODE=modbus  over Modbus RTU (no e-stop byte there: ESTOPS is ignored)
  RATE=25      telemetry lines a second during the stream (default 0, as bench link)
  EXTRA="rs=PumpBoard::read_sensors,ev=Link::event" adds probes (name=function, <= 16 in all)."""
import json
import os
import sys
from pathlib import Path

import armbridge.emulator.simavr_chip as CH
import armbridge.emulator.simavr_runner as SR
from armbridge.bench import link as L
from armbridge.emulator.pump_hal import _spread, pump_timing

EXTRA = dict(kv.split("=") for kv in os.environ.get("EXTRA", "").split(",") if kv)


def run(elf: Path, n: int = 1500, estops: int = 20, mode: str = "line", rate: int = 0) -> dict:
    """The measurement of ELF (tests/test_pump_timer.py calls it with a shorter load)."""
    saved = SR.DEFAULT_PROBES, CH.firmware_elf
    SR.DEFAULT_PROBES = dict(SR.DEFAULT_PROBES, plan="Traj::plan", **EXTRA)
    CH.firmware_elf = lambda folder, name: Path(elf).resolve()   # run ELF, do not rebuild the checkout's
    try:
        return _run(Path(elf).resolve(), n, estops, mode, rate)
    finally:
        SR.DEFAULT_PROBES, CH.firmware_elf = saved


def _run(ELF: Path, n: int, estops: int, mode: str, rate: int) -> dict:
    b = L.BOARDS["arduino_pump"]
    url = L.MODBUS_URL if mode == "modbus" else b.url
    if mode == "modbus":   # the board in Modbus mode (the url switches it), the executor's Modbus client
        from armbridge.executor.modbus_client import ModbusClient
        from armbridge.link.transport import open_port
        from armbridge.robots.catalog import get_robot

        port = open_port(url)
        client = ModbusClient(port, get_robot(b.robot))
        client.connect()
    else:
        port, client = L._session(url, b.robot)
    try:
        if mode != "modbus":
            client.set_rate(rate)
        q = L.wave(n, b.stream_step, b.period, b.robot)
        client.execute([L.POSITION_MS], [q[0].tolist()])
        emu = port.emulator
        t0 = client.now()
        if mode == "modbus":
            master = port.master
            for i in range(0, n, 50):   # a waypoint an FC16, and 10 FC4 reads every 50
                client.execute([2] * len(q[i:i + 50]), q[i:i + 50].tolist())
                for _ in range(10):
                    master.read_input(0, 12)
        else:
            client.execute([2] * n, q.tolist())
        t1 = client.now()
        lat = []
        for k in range(0 if mode == "modbus" else estops):   # the byte at drifting phases of the period
            client.command("CLR")
            for i in range(4):   # from end to end of the wave: the pumps drive
                client.command("W", i, 400, *(q.max(axis=0) if (i + k) % 2 else q.min(axis=0)))
            L._wait(lambda: emu.state == "RUN" and any(emu.hal.duties), 3.0, pump=lambda: client.drain(0.002))
            client.drain(0.020 + 0.00037 * k)
            L._wait(lambda: any(emu.hal.duties), 3.0, pump=lambda: client.drain(0.0005))   # a pump drives
            before = len(emu.outputs_off_at)
            client.estop()
            L._wait(lambda: len(emu.outputs_off_at) > before, 2.0, pump=lambda: client.drain(0.002))
        t2 = client.now()
        timing = pump_timing(emu, window=(t0, t1))   # the stream's alone
        stops = pump_timing(emu, window=(t1, t2)) if estops and mode != "modbus" else None
    finally:
        port.close()
    us = 1e6 / timing["hz"]

    def per_call(name: str) -> dict:
        """A probe's calls in the stream, in us, and how many a control period."""
        calls = _spread([d * us for t, d in emu.runner.stats["probes"].get(name, []) if t0 <= t <= t1])
        return dict(calls, per_period=calls["n"] / max(1, timing["control_cycles"]["n"]))

    def cyc(s: dict) -> dict:
        return {k: (v * us if k in ("mean", "min", "max", "std") else v) for k, v in s.items()}

    out = {"elf": str(ELF), "mode": mode, "rate": rate, "waypoints": n, "stream_s": t1 - t0, "wp_per_s": n / (t1 - t0),
           "period_us": dict(timing["control_period_us"], jitter=timing["control_jitter_us"]),
           "isr_period_us": dict(cyc(timing["isr_period_cycles"]), jitter=timing["isr_jitter_us"]),
           "isr_us": dict(cyc(timing["isr_cycles"]), max_cycles=timing["isr_cycles"].get("max")),
           "overruns": timing["overruns"],
           "pass_us": dict(cyc(timing["pass_cycles"]), max_cycles=timing["pass_cycles"].get("max")),
           "control_us": dict(cyc(timing["control_cycles"]), max_cycles=timing["control_cycles"].get("max")),
           **{f"{name}_us": per_call(name) for name in ("plan", "parse", "crc", *EXTRA)},
           **{k: timing[k] for k in ("flash_bytes", "static_ram_bytes", "free_ram_bytes", "uart_bytes_lost")}}
    if stops is not None:
        out["estop_latency_us"] = stops["estop_latency_us"]
        out["estop_in_isr_us"] = stops["estop_in_isr_us"]
        out["estop_phase"] = {k: stops[k] for k in ("isr_jitter_us", "overruns", "free_ram_bytes")}
        out["estop_phase"]["pass_max_us"] = stops["pass_cycles"].get("max", 0) * us
    return out


if __name__ == "__main__":
    print(json.dumps(run(Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 1500,
                         int(sys.argv[3]) if len(sys.argv) > 3 else 20, os.environ.get("MODE", "line"),
                         int(os.environ.get("RATE", "0"))), indent=1, default=float))
