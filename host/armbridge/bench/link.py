"""`armbridge bench link`: the line protocol, v1 beside v2 where both can run.

* undetected errors (pure computation, bench/damage.py): random valid `W`
  lines damaged by the UART fault mix (1 % drop, 1 % bit flip, 1 % duplicate
  per byte), framed with v1's CRC-16 and with v2's CRC-32 from the epoch; the
  damaged lines that would still execute as another command, and for a count
  of 0 the rate it implies (95 % upper bound, 3/N).

The rest runs the real ESP32 firmware in the emulator, paced to the wall
clock, behind a real pseudo-terminal whose UART is paced at 115200 baud 8N1,
with the real executor client on the host (protocol v2 only: no v1 firmware
is left to run):

* throughput: 3-joint waypoints streamed under credit flow control, short
  enough (2 ms) that the board is never the bottleneck; waypoints/s, the
  share of the 11,520 bytes/s the host->board direction carries, the bytes
  per waypoint and what else the host wrote (PINGs, retransmissions);
* acknowledgement round trip: PING -> OK, timed on the host;
* e-stop latency: with a full queue of moving waypoints, from the host writing
  the 0x98 byte to the board switching its outputs off (the emulator's record,
  mapped to the host clock) and to the ESTOP event reaching the host;
* soak: plans back to back under the fault mix in both directions plus a
  board reset at a fixed period; the board's own log of completed waypoints
  (id and values) must hold every waypoint once, in order, with the values
  the host sent.

`--board arduino_pump` runs the same pty measurements on the syringe-pump
board's .elf in simavr (`BOARDS`: the soft arm's waypoints, under its 0.5 rad/s)
in lockstep, timed on the emulator's clock (cycle-exact, whatever the host's
load), plus the Modbus round trip (bench/modbus.py); the undetected-error
count is the codec's, the same for every board, and is not repeated there.
"""
from __future__ import annotations

import time
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import typer

from armbridge.bench import damage
from armbridge.bench.command import write_json
from armbridge.bench.link_table import TARGET_ESTOP_MS, TARGET_WPS
from armbridge.executor.client import BoardClient
from armbridge.link import protocol as P
from armbridge.link.transport import open_port
from armbridge.robots.catalog import get_robot

LINE_BYTES_PER_S = 115200 / 10  # 8N1: ten bit times a byte
ROBOT = "arm3r"


@dataclass(frozen=True)
class BenchBoard:
    """A board the pty measurements run on: its emu: url, the robot it drives, and the
    waypoint steps (mrad) each measurement streams, under the robot's vmax."""

    url: str
    robot: str
    lockstep: bool  # speed=0: times on the emulator's clock; else paced, on the wall clock
    stream_step: float  # per 2 ms waypoint (throughput)
    soak_step: float  # per 20 ms waypoint (soak)
    estop_step: float  # per 100 ms waypoint (e-stop)
    period: int  # waypoints per period of the wave


BOARDS = {
    "esp32": BenchBoard("emu:esp32", "arm3r", False, 4.0, 20.0, 20.0, 400),  # arm3r: 3 rad/s
    "arduino_pump": BenchBoard("emu:arduino_pump?speed=0", "soft3", True, 0.9, 8.0, 10.0, 100),  # 0.5 rad/s
}
V1_CRC_DIGITS, V2_CRC_DIGITS = 4, 8
POSITION_MS = 1000  # the untimed move to a stream's start (the board stretches it to its vmax)


class CountingPort:
    """Counts the bytes the host writes, per verb (the session layer writes one
    line per call; the e-stop byte is `ESTOP`); everything else goes to the port."""

    def __init__(self, port):
        self._port = port
        self.written = 0
        self.by_verb: Counter[str] = Counter()

    def write(self, data: bytes) -> int:
        self.written += len(data)
        if data == P.ESTOP_BYTE:
            verb = "ESTOP"
        else:
            parts = bytes(data).split(b" ", 2)
            verb = parts[1].split(b"*")[0].decode("ascii", "replace") if len(parts) > 1 else "?"
        self.by_verb[verb] += len(data)
        return self._port.write(data)

    def __getattr__(self, name):
        return getattr(self._port, name)

    def __setattr__(self, name, value):
        if name in ("_port", "written", "by_verb"):
            object.__setattr__(self, name, value)
        else:
            setattr(self._port, name, value)


def wave(k: int, step_mrad: float, period: int = 400, robot_name: str = ROBOT) -> np.ndarray:
    """(k, 3) mrad: a smooth back-and-forth around the middle of the robot's ranges,
    at most `step_mrad` per waypoint on any joint."""
    robot = get_robot(robot_name)
    mid = (robot.q_min + robot.q_max) / 2 * 1000
    amp = step_mrad * period / (2 * np.pi)
    phase = np.sin(2 * np.pi * np.arange(k)[:, None] / period + np.array([0.0, 1.0, 2.0]))
    return np.rint(mid + amp * phase).astype(int)


def percentiles(samples_s: list[float]) -> dict:
    a = np.asarray(samples_s) * 1000.0
    return {"n": int(a.size), "median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)),
            "max_ms": float(a.max())}


# ---------------------------------------------------------------- undetected errors

def undetected_errors(damaged_lines: int, version: int, seed: int = 2024, workers: int = 2,
                      copies: int = 100) -> dict:
    """Damage random valid W lines until at least `damaged_lines` damaged copies
    were judged; count those that would execute as another command. Rounds of
    `damage.undetected` with seeds seed, seed+1, ... (each sized from the damaged
    share seen so far), so the result is the same for any number of workers."""
    total = damage.Result(version)
    share, round_seed = 0.6, seed  # the damaged share of a line's copies: ~0.65-0.75 for these lines
    while total.damaged < damaged_lines:
        need = damaged_lines - total.damaged
        lines = max(1, int(np.ceil(need / (copies * share) * 1.02)))
        part = damage.undetected(lines, round_seed, version, copies=copies, workers=workers)
        total.add(part)
        share = max(0.05, total.damaged / (total.lines * copies))
        round_seed += 1
    return {"version": version, "crc": "CRC-16/CCITT-FALSE" if version == 1 else "CRC-32/ISO-HDLC from the epoch",
            "lines": total.lines, "copies_per_line": copies, "damaged": total.damaged,
            "undetected": total.undetected, "rate": total.rate, "rate_upper_95": total.rate_upper_95,
            "examples": [{"sent": s, "executed_as": r} for s, r in total.examples[:5]]}


# ---------------------------------------------------------------- over the pty

def _session(url: str, robot: str = ROBOT, **client_kw) -> tuple[CountingPort, BoardClient]:
    port = CountingPort(open_port(url))
    client = BoardClient(port, get_robot(robot), **client_kw)
    client.connect()
    return port, client


def _clock(board: BenchBoard, client: BoardClient) -> Callable[[], float]:
    return client.now if board.lockstep else time.monotonic


def throughput_once(waypoints: int, board: BenchBoard = BOARDS["esp32"]) -> dict:
    port, client = _session(board.url, board.robot)
    now = _clock(board, client)
    try:
        client.set_rate(0)  # the board->host lane carries only acks and events
        q = wave(waypoints, board.stream_step, board.period, board.robot)  # arm3r: 4 mrad in 2 ms = 2 rad/s
        # The arm to the wave's start first, untimed: from rest its first waypoint is a
        # long move the board stretches to the robot's vmax (the soft arm's 0.5 rad/s:
        # about 1 s), which is the plant's time, not the link's.
        client.execute([POSITION_MS], [q[0].tolist()])
        before, verbs_before, st0 = port.written, Counter(port.by_verb), _stats(client)
        t0 = now()
        client.execute([2] * waypoints, q.tolist())
        elapsed = now() - t0
        sent = port.written - before
        by_verb = dict(port.by_verb - verbs_before)
        st = {k: v - st0[k] for k, v in _stats(client).items()}
        w_lines = st["waypoint_lines"]
        w_line = by_verb.get("W", 0) / max(1, w_lines)  # mean bytes of one W line
        return {"waypoints": waypoints, "seconds": elapsed, "waypoints_per_s": waypoints / elapsed,
                "host_bytes_per_s": sent / elapsed, "line_capacity_used": sent / elapsed / LINE_BYTES_PER_S,
                "bytes_per_waypoint": sent / waypoints, "w_line_bytes": w_line,
                "line_rate_ceiling_wps": LINE_BYTES_PER_S / w_line,
                "v1_w_line_bytes": w_line - (V2_CRC_DIGITS - V1_CRC_DIGITS),
                "v1_line_rate_ceiling_wps": LINE_BYTES_PER_S / (w_line - (V2_CRC_DIGITS - V1_CRC_DIGITS)),
                "bytes_by_verb": by_verb, "retransmitted": st["waypoint_lines"] - st["waypoints_sent"],
                "pings": st["pings"], "timeouts": st["timeouts"], "spurious_timeouts": st["spurious_timeouts"],
                "window_cuts": st["window_cuts"],
                "slow_events": st["slow_events"]}
    finally:
        port.close()


def _stats(client: BoardClient) -> dict[str, int]:
    s = client.stats
    return {k: getattr(s, k) for k in ("waypoint_lines", "waypoints_sent", "pings", "timeouts", "spurious_timeouts",
                                       "window_cuts", "slow_events")}


def throughput(waypoints: int, runs: int = 1, board: BenchBoard = BOARDS["esp32"]) -> dict:
    """`runs` separate sessions of `waypoints` each; the run of median rate is the
    result, every run's rate beside it (the machine is shared: one slow run
    should not be the number, nor the fastest)."""
    each = [throughput_once(waypoints, board) for _ in range(runs)]
    ranked = sorted(each, key=lambda r: r["waypoints_per_s"])
    result = dict(ranked[(len(ranked) - 1) // 2])
    result["runs"] = runs
    result["waypoints_per_s_each"] = [r["waypoints_per_s"] for r in each]
    return result


def round_trip(pings: int, board: BenchBoard = BOARDS["esp32"]) -> dict:
    port, client = _session(board.url, board.robot)
    now = client.now if board.lockstep else time.perf_counter
    try:
        client.set_rate(0)
        samples = []
        for _ in range(pings):
            t0 = now()
            client.command("PING")
            samples.append(now() - t0)
        return percentiles(samples)
    finally:
        port.close()


def estop_latency(trials: int, bench_board: BenchBoard = BOARDS["esp32"]) -> dict:
    """Lockstep: the byte's time is the host's write on the emulator's clock, the outputs'
    the HAL's record in sim time; paced: both on the wall clock (emu.wall_time)."""
    events: list[float] = []
    now: list[Callable[[], float]] = [time.monotonic]

    def on_event(_t, ev: P.Event) -> None:
        if ev.kind == "ESTOP":
            events.append(now[0]())

    port, client = _session(bench_board.url, bench_board.robot, on_event=on_event)
    now[0] = _clock(bench_board, client)
    emu = port.emulator
    board, host = [], []
    try:
        q = wave(40, bench_board.estop_step, bench_board.period, bench_board.robot)
        for _ in range(trials):
            client.command("CLR")
            for i in range(32):  # fill the queue: 32 waypoints of 100 ms
                client.command("W", i, 100, *q[i])
            _wait(lambda: emu.state == "RUN", 2.0, pump=lambda: client.drain(0.002))
            client.drain(0.05)
            off_before, events_before = len(emu.outputs_off_at), len(events)
            t0 = now[0]()
            client.estop()
            _wait(lambda: len(emu.outputs_off_at) > off_before and len(events) > events_before, 2.0,
                  pump=lambda: client.drain(0.002))
            off = emu.outputs_off_at[-1]
            board.append((off if bench_board.lockstep else emu.wall_time(off)) - t0)
            host.append(events[-1] - t0)
        return {"trials": trials, "byte_to_outputs_off": percentiles(board),
                "byte_to_event_at_host": percentiles(host)}
    finally:
        port.close()


def judge(sent: Sequence[tuple[int, tuple[int, ...]]], executed: Sequence[tuple[int, tuple[int, ...]]]) -> dict:
    """Compare the board's log of completed waypoints, (id, values) in order,
    with what the host sent, (id, values) in order. Per id (an id may be sent
    more than once when ids wrap): lost = sent but not executed, duplicated =
    executed more often than sent (or never sent), wrong_value = executed with
    values the host never sent for that id."""
    want: dict[int, Counter] = defaultdict(Counter)
    got: dict[int, Counter] = defaultdict(Counter)
    for i, v in sent:
        want[i][tuple(v)] += 1
    for i, v in executed:
        got[i][tuple(v)] += 1
    lost = duplicated = wrong = 0
    for i in want.keys() | got.keys():
        n_want, n_got = sum(want[i].values()), sum(got[i].values())
        lost += max(0, n_want - n_got)
        duplicated += max(0, n_got - n_want)
        # Executions with values not sent for this id, beyond those already counted as duplicates.
        wrong += max(0, sum((got[i] - want[i]).values()) - max(0, n_got - n_want))
    return {"lost": lost, "duplicated": duplicated, "wrong_value": wrong,
            "in_order": [i for i, _ in executed] == [i for i, _ in sent]}


def soak(seconds: float, url_faults: str, reset_every_s: float, chunk: int = 100,
         board: BenchBoard = BOARDS["esp32"]) -> dict:
    """Plans of `chunk` waypoints back to back in one session until `seconds` have
    passed (wall time; sim time in lockstep); the board's log must hold every waypoint
    once, in order, with the values the host sent."""
    resets = ",".join(f"{t:g}" for t in np.arange(reset_every_s, seconds, reset_every_s))
    url = board.url + ("&" if "?" in board.url else "?") + url_faults + (f"&reset_at={resets}" if resets else "")
    port, client = _session(url, board.robot)
    now = _clock(board, client)
    emu = port.emulator
    q = wave(chunk, board.soak_step, board.period, board.robot).tolist()  # arm3r: 20 mrad in 20 ms = 1 rad/s
    plans = 0
    try:
        t0 = now()
        while now() - t0 < seconds:
            client.execute([20] * chunk, q, timeout=600)
            plans += 1
        elapsed = now() - t0
        # Ids run on across the plans of a session: 0, 1, 2, ... (mod 65536).
        sent = [(i % 65536, tuple(q[i % chunk])) for i in range(plans * chunk)]
        verdict = judge(sent, [(i, v) for _, i, v in emu.executed])
        st = client.stats
        return {"seconds": elapsed, "plans": plans, "waypoints": plans * chunk, "executed": len(emu.executed),
                **verdict, "resets": emu.counters["resets"], "resyncs": st.resyncs,
                "retransmitted": st.waypoints_retransmitted, "line_errors": st.line_errors,
                "faults_injected": emu.counters}
    finally:
        port.close()


def _wait(pred: Callable[[], bool], timeout: float, pump: Callable[[], None] | None = None) -> None:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise TimeoutError("benchmark condition not reached")
        if pump is not None:
            pump()
        else:
            time.sleep(0.001)


# ---------------------------------------------------------------- the whole bench

@dataclass
class LinkBenchSize:
    damaged_lines: int  # per protocol version
    waypoints: int
    throughput_runs: int
    pings: int
    estops: int
    soak_s: float
    reset_every_s: float


FULL = LinkBenchSize(damaged_lines=10_000_000, waypoints=3000, throughput_runs=3, pings=500, estops=30,
                     soak_s=600, reset_every_s=60)
QUICK = LinkBenchSize(damaged_lines=20_000, waypoints=300, throughput_runs=1, pings=50, estops=5, soak_s=15,
                      reset_every_s=7)
SOAK_FAULTS = "drop=0.01&corrupt=0.01&dup=0.01&seed=7"


MODBUS_URL = "modbus:emu:arduino_pump?addr=1&speed=0"


def run(size: LinkBenchSize, progress: Callable[[str], None] = print, workers: int = 2,
        board: str = "esp32", load: float | None = None) -> dict:
    """Every measurement of the bench on `board` (BOARDS), the pty ones first (so the
    damage model's worker processes do not share the cores with the paced emulator);
    the syringe-pump board adds the Modbus round trip and leaves out the damage model
    (the codec's, the same for every board). `load` (not None): throughput, round trip
    and e-stop only, with that many busy processes per core beside them (bench/load.py;
    0: the same at rest, for the figures beside them)."""
    from armbridge.bench.load import Busy

    b = BOARDS[board]
    clock = "emulator (sim time)" if b.lockstep else "wall"
    result: dict = {"board": board, "url": b.url, "clock": clock, "load_per_core": load}
    with Busy(load or 0.0) as busy:
        result["busy_processes"] = busy
        progress(f"{board}: throughput: {size.throughput_runs} x {size.waypoints} waypoints, {clock} clock"
                 + (f", {busy} busy processes beside" if busy else ""))
        result["throughput"] = throughput(size.waypoints, size.throughput_runs, b)
        progress(f"round trip: {size.pings} pings")
        result["round_trip"] = round_trip(size.pings, b)
        progress(f"e-stop: {size.estops} trials")
        result["estop"] = estop_latency(size.estops, b)
    if load is not None:
        result["size"] = size.__dict__
        return result
    progress(f"soak: {size.soak_s:g} s with {SOAK_FAULTS}, a reset every {size.reset_every_s:g} s")
    result["soak"] = soak(size.soak_s, SOAK_FAULTS, size.reset_every_s, board=b)
    if board == "arduino_pump":
        from armbridge.bench.modbus import modbus_round_trip

        progress(f"Modbus round trip: {size.pings} reads of one register, {size.pings} set-point writes")
        result["modbus"] = modbus_round_trip(MODBUS_URL, size.pings)
    else:
        result["undetected"] = {}
        for version in (1, 2):
            progress(f"undetected errors, protocol v{version}: {size.damaged_lines:,} damaged lines, "
                     f"{workers} workers")
            t0 = time.monotonic()
            r = undetected_errors(size.damaged_lines, version, workers=workers)
            r["seconds"] = time.monotonic() - t0
            result["undetected"][f"v{version}"] = r
    result["targets"] = targets(result)
    result["size"] = size.__dict__
    return result


def targets(r: dict) -> dict[str, bool]:
    if "soak" not in r:  # a run under load: its figures stand beside the idle ones, no targets
        return {}
    so = r["soak"]
    out = {"v2 undetected == 0": r["undetected"]["v2"]["undetected"] == 0} if "undetected" in r else {}
    out.update({
        f"waypoints/s >= {TARGET_WPS}": r["throughput"]["waypoints_per_s"] >= TARGET_WPS,
        f"e-stop byte -> outputs off < {TARGET_ESTOP_MS:g} ms": r["estop"]["byte_to_outputs_off"]["max_ms"]
        < TARGET_ESTOP_MS,
        "soak 0 lost / 0 duplicated / 0 wrong, in order": (so["lost"], so["duplicated"], so["wrong_value"],
                                                            so["in_order"]) == (0, 0, 0, True),
    })
    return out


def print_result(r: dict, console) -> None:
    """The table of `armbridge bench link` (rich console): bench/link_table.py."""
    from armbridge.bench.link_table import print_result as table

    table(r, console)


def link_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 20,000 damaged lines per version, "
                               "300 waypoints, 50 pings, 5 e-stops, 15 s soak."),
    soak_s: float = typer.Option(None, "--soak", min=1.0, help="Soak length in seconds (full run: 600)."),
    damaged: int = typer.Option(None, "--damaged", min=1, help="Damaged lines per protocol version (full run: 10^7)."),
    workers: int = typer.Option(2, "--workers", min=1, help="Processes for the damage model."),
    json_out: Path = typer.Option(None, "--json", help="Where to write the results ('-': stdout)."
                                  "[default: runs/bench-link.json, runs/bench-link-BOARD.json for another board]."),
    board: str = typer.Option("esp32", "--board", help="The emulated board: esp32 (the MicroPython firmware, paced "
                              "to the wall clock) or arduino_pump (the .elf in simavr in lockstep, on its clock; "
                              "adds the Modbus round trip, leaves out the damage model)."),
    load: Optional[float] = typer.Option(None, "--load", min=0.0, help="Busy-loop processes per core beside the "
                                         "run: then throughput, round trip and e-stop only, for the figures at load "
                                         "(0: the same at rest, to stand beside them)."),
) -> None:
    """The line protocol: undetected errors of v1 and v2 under the UART fault mix, and,
    over a pty paced at 115200 baud, throughput, round trip, e-stop latency and a soak
    under link faults and board resets."""
    from dataclasses import replace

    from rich.console import Console

    if board not in BOARDS:
        raise typer.BadParameter(f"{board!r}: use one of {', '.join(BOARDS)}", param_hint="--board")
    if json_out is None:
        tag = ("" if board == "esp32" else f"-{board}") + (f"-load{load:g}" if load is not None else "")
        json_out = Path(f"runs/bench-link{tag}.json")
    size = QUICK if quick else FULL
    if soak_s is not None:
        size = replace(size, soak_s=soak_s, reset_every_s=min(size.reset_every_s, soak_s / 2))
    if damaged is not None:
        size = replace(size, damaged_lines=damaged)
    console = Console()
    result = run(size, progress=lambda text: console.print(f"[dim]bench link: {text}[/]"), workers=workers,
                 board=board, load=load)
    write_json(result, json_out)
    print_result(result, console)
    console.print(f"wrote {json_out}")
