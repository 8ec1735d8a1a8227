"""`armbridge bench arm3r-servo`: the drawing arm on boards of hidden truth, uncalibrated beside calibrated (issue 23 §2).

For each rig (effort: continuous servos, pots, the board's PIDs; pca9685: the
paper's positional servos) and each of `plants` boards drawn from the
documented spreads (`emu:esp32?servos=RIG&plant=random&seed=K`,
emulator/truth.py), a drawing (the text `TEXT` through the draw pipeline:
Hershey text fitted to the safe region, closed-form joint plan at the pen
speed, as `armbridge draw` builds it) runs with `run_plan` twice:

* uncalibrated: the firmware's defaults;
* calibrated: first `armbridge calibrate`'s procedure (calibrate/arm3r.py:
  relay gains on the effort rig, the jig step with the emulated user,
  calibrate/jig.py EmuJig), its settings sent and saved (CALID) in the board's
  filesystem (the emulator's `fs=` folder), then the same drawing on a fresh
  boot of that board (it loads cal.txt).

Judged by the truth the host cannot see: every 10 ms of board time the
plant's true joint angles are taken (a tap on the emulator's tick), with the
board's set point then. Stroke error: the true pen's trace while the pen
servo really touched the paper against the drawing's strokes, and back
(plans/drawing.py's drawing_error; the run summary's own figure uses the
pots, which a pot offset fools). Joint tracking error: the true joint angle
against the set point the board was following (the plan's angle), while the
arm moved.

Options: `--rigs`, `--text`, `--rule` (the gains step's tuning rule, or
"shipped": no gains step), and for the pca9685 rig `--servo-hz` and
`--servo-lead-ms` (its boards then run a copy of the firmware whose config
sets SERVO_FREQ_HZ / SERVO_LEAD_MS: firmware_at).
"""
from __future__ import annotations

import contextlib
import platform
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import typer

from armbridge.bench.command import write_json

RIGS = ("effort", "pca9685")
TEXT = "ARM"
SPEED = 0.03        # m/s, the pen speed (as bench arm3r's ROBOTICS)
TARGET_MM = 1.5     # issue 23: stroke error with the pen down, after calibration


def drawing_plan(text: str = TEXT, speed: float = SPEED):
    from armbridge.draw.build import build
    from armbridge.draw.sources import text_lines
    from armbridge.robots import get_robot

    return build(text_lines(text), get_robot("arm3r"), name=f"text-{text}", source=f"text {text}", speed=speed).plan


@contextlib.contextmanager
def traced_emulators(every_s: float = 0.01, firmware_root: Path | None = None) -> Iterator[list[dict[str, Any]]]:
    """Every emu: port opened inside gets a tap: its `trace` (t, true q, set point rad) every
    `every_s` of board time; yields the list of {"emu", "trace"} (one per board opened).
    `firmware_root`: the boards run the firmware from there (lockstep ports only)."""
    import armbridge.emulator.url as url_mod

    seen: list[dict[str, Any]] = []
    orig = url_mod.open_emu_port

    def open_at(url: str, baud: int = 115200, timeout: float | None = 0.1):
        from armbridge.emulator.board import EmulatedBoard
        from armbridge.emulator.lockstep import lockstep_port

        device, kw = url_mod.parse_emu_url(url)
        return lockstep_port(EmulatedBoard(device, firmware_root=firmware_root, **kw), url, timeout, baud)

    def opener(url: str, *a: Any, **kw: Any):
        port = (open_at if firmware_root is not None else orig)(url, *a, **kw)
        emu = port.emulator
        rec: dict[str, Any] = {"emu": emu, "trace": []}
        seen.append(rec)
        tick = emu._tick
        nxt = [0.0]

        def tapped(dus: int) -> None:
            tick(dus)
            t = emu.clock.t
            if t >= nxt[0] and emu.board is not None:
                nxt[0] = t + every_s
                sp = np.asarray(emu.board.traj.sp, float) / 1000.0
                rec["trace"].append((t, np.asarray(emu.plant.q, float).copy(), sp))
        emu._tick = tapped
        return port

    url_mod.open_emu_port = opener
    try:
        yield seen
    finally:
        url_mod.open_emu_port = orig


def judge(plan: Any, rec: dict[str, Any]) -> dict[str, float]:
    """Stroke error (mm) of the true pen while down, and joint tracking error (mrad), from a traced run."""
    from armbridge.plans.drawing import drawing_error, pen_strips, trace_strips

    emu, tr = rec["emu"], rec["trace"]
    t = np.array([x[0] for x in tr])
    q = np.array([x[1] for x in tr])
    sp = np.array([x[2] for x in tr])
    down = np.array([emu.hal.pen_down_at(x) for x in t], bool)
    tips = np.asarray(plan.robot.ee_point(q))[:, :2]
    target = pen_strips(np.asarray(plan.ee_path())[:, :2], plan.pen)
    d = drawing_error(target, trace_strips(tips, down)).to_dict()
    moving = np.r_[False, np.any(np.abs(np.diff(sp, axis=0)) > 1e-6, axis=1)]
    err = np.abs(q - sp)[moving] * 1000.0
    return {"stroke_mean_mm": d["trace_mean_mm"], "stroke_max_mm": d["trace_max_mm"],
            "coverage_max_mm": d["target_max_mm"],
            "track_mean_mrad": float(err.mean()) if err.size else float("nan"),
            "track_max_mrad": float(err.max()) if err.size else float("nan")}


def firmware_at(overrides: dict[str, int], folder: Path) -> Path:
    """A copy of the firmware whose esp32 config sets each NAME = value of `overrides`
    (SERVO_FREQ_HZ, SERVO_LEAD_MS: lines the config has)."""
    import shutil

    from armbridge.resources import firmware_dir

    root = folder / ("firmware-" + "-".join(f"{k}{v}" for k, v in sorted(overrides.items())))
    if not root.exists():
        shutil.copytree(firmware_dir(), root)
        cfg = root / "esp32" / "config.py"
        lines = cfg.read_text().splitlines()
        for name, value in overrides.items():
            at = [i for i, ln in enumerate(lines) if ln.startswith(f"{name} = ")]
            if len(at) != 1:
                raise RuntimeError(f"the esp32 config has no single {name} line")
            lines[at[0]] = f"{name} = {int(value)}"
        cfg.write_text("\n".join(lines) + "\n")
    return root


def calibrate_board(url: str, cal_dir: Path, rule: str | None = None, root: Path | None = None) -> dict[str, Any]:
    """`armbridge calibrate esp32 --jig emu` on the board at `url` (calibrate/base.py's flow:
    the procedure with the emulated jig, the settings, CALID in the board's filesystem, the
    host file in `cal_dir`) -> what it found. `rule`: the gains step's (None: its default;
    "shipped": no gains step). `root`: the firmware tree the board runs (its config)."""
    from armbridge.calibrate.base import calibrate_board as flow

    only = ("jig",) if rule == "shipped" else None
    options = {"rule": rule} if rule and rule != "shipped" else None
    return flow(url, "esp32", only=only, cal_dir=cal_dir, jig="emu", options=options, firmware=root).found.values


def run_one(rig: str, seed: int, plan: Any, folder: Path, rule: str | None = None,
            config: dict[str, int] | None = None) -> dict[str, Any]:
    from armbridge.executor.run import RunFailed, run_plan

    base = f"emu:esp32?speed=0&servos={rig}&plant=random&seed={seed}"
    out: dict[str, Any] = {"rig": rig, "seed": seed}
    fs = folder / f"fs-{rig}-{seed}"
    fs.mkdir(parents=True, exist_ok=True)
    root = firmware_at(config, folder) if config else None
    for label in ("uncalibrated", "calibrated"):
        try:
            if label == "calibrated":
                with traced_emulators(firmware_root=root):
                    out["found"] = calibrate_board(f"{base}&fs={fs}", folder / "host-calibration", rule, root)
            with traced_emulators(firmware_root=root) as seen:
                s = run_plan(plan, f"{base}&fs={fs}", folder / f"{rig}-{seed}-{label}.rrd", progress=False)
            out[label] = {"completed": bool(s.completed), **judge(plan, seen[-1])}
        except (RunFailed, RuntimeError) as exc:
            out[label] = {"completed": False, "error": str(exc)}
    return out


def summarize(runs: list[dict[str, Any]], label: str) -> dict[str, Any]:
    ok = [r[label] for r in runs if r.get(label, {}).get("completed")]
    if not ok:
        return {"runs": len(runs), "completed": 0}

    def col(k: str) -> np.ndarray:
        return np.asarray([r[k] for r in ok], float)
    return {"runs": len(runs), "completed": len(ok),
            "stroke_mean_mm": float(col("stroke_mean_mm").mean()), "stroke_max_mm": float(col("stroke_max_mm").max()),
            "stroke_max_mm_median": float(np.median(col("stroke_max_mm"))),
            "track_mean_mrad": float(col("track_mean_mrad").mean()),
            "track_max_mrad": float(col("track_max_mrad").max()),
            "meet_target": float(np.mean(col("stroke_mean_mm") <= TARGET_MM)),
            "meet_target_max": float(np.mean(col("stroke_max_mm") <= TARGET_MM))}


def run(plants: int, rigs=RIGS, text: str = TEXT, rule: str | None = None, config: dict[str, int] | None = None,
        progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """`config`: esp32 config values the pca9685 rig's boards run with (firmware_at)."""
    t0 = time.perf_counter()
    plan = drawing_plan(text)
    result: dict[str, Any] = {
        "benchmark": "arm3r-servo (issue 23 section 2: calibration of the drawing arm on boards of hidden truth)",
        "drawing": {"text": text, "speed_m_s": SPEED, "waypoints": plan.k, "planned_s": plan.total_duration},
        "target_stroke_mm": TARGET_MM, "rule": rule or "default", "pca9685_config": config or "as shipped",
        "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()}}
    with tempfile.TemporaryDirectory(prefix="armbridge-arm3r-servo-") as tmp:
        for rig in rigs:
            runs = []
            for k in range(plants):
                runs.append(run_one(rig, k, plan, Path(tmp), rule, config if rig == "pca9685" else None))
                progress(_line(runs[-1]))
            result[rig] = {"runs": runs, "uncalibrated": summarize(runs, "uncalibrated"),
                           "calibrated": summarize(runs, "calibrated")}
    result["wall_s"] = time.perf_counter() - t0
    return result


def _line(r: dict[str, Any]) -> str:
    parts = [f"{r['rig']} plant {r['seed']}:"]
    for label in ("uncalibrated", "calibrated"):
        x = r.get(label, {})
        if not x.get("completed"):
            parts.append(f"{label} failed ({x.get('error', '?')})")
        else:
            parts.append(f"{label} stroke {x['stroke_mean_mm']:.2f} / {x['stroke_max_mm']:.2f} mm, "
                         f"track {x['track_mean_mrad']:.1f} / {x['track_max_mrad']:.1f} mrad")
    return " ".join(parts)


def arm3r_servo_cmd(
    plants: int = typer.Option(20, "--plants", min=1, help="Random boards per rig (plant=random&seed=0..N-1)."),
    json_out: Path = typer.Option(Path("runs/bench-arm3r-servo.json"), "--json", help="Where to write the results ('-': stdout)."),
    text: str = typer.Option(TEXT, "--text", help="The text drawn (Hershey, through the draw pipeline)."),
    servo_hz: int = typer.Option(None, "--servo-hz", min=24, max=1526,
                                 help="The pca9685 rig's PWM frequency (default: the config's SERVO_FREQ_HZ)."),
    servo_lead_ms: int = typer.Option(None, "--servo-lead-ms", min=0, max=200,
                                      help="The pca9685 rig's SERVO_LEAD_MS (default: the config's)."),
    rigs: str = typer.Option(",".join(RIGS), "--rigs", help="Comma-separated rigs to run."),
    rule: str = typer.Option(None, "--rule", help="The tuning rule of the gains step (calibrate/tuning.py RULES; "
                                                       "'shipped': no gains step, the config's gains)."),
) -> None:
    """The drawing arm on N boards of hidden truth per rig, uncalibrated beside calibrated (`armbridge calibrate`'s
    procedure with the emulated jig): the true pen's stroke error with the pen down (the share of boards whose
    mean, and whose largest error, is within issue 23's 1.5 mm) and the joints' tracking error."""
    from rich.console import Console
    from rich.table import Table

    console = Console()
    chosen = tuple(r.strip() for r in rigs.split(",") if r.strip())
    bad = [r for r in chosen if r not in RIGS]
    if bad or not chosen:
        raise typer.BadParameter(f"rigs: {', '.join(RIGS)}", param_hint="--rigs")
    config = {k: v for k, v in (("SERVO_FREQ_HZ", servo_hz), ("SERVO_LEAD_MS", servo_lead_ms)) if v is not None}
    result = run(plants, rigs=chosen, text=text, rule=rule, config=config,
                 progress=lambda s: console.print(f"[dim]bench arm3r-servo: {s}[/]"))
    write_json(result, json_out)
    t = Table(title=f"'{text}' on {plants} drawn boards per rig (true figures)")
    for c in ("rig", "", "runs", "stroke mean (mm)", "stroke max, median / worst (mm)", "tracking mean / max (mrad)",
              f"stroke mean <= {TARGET_MM:g} mm", f"stroke max <= {TARGET_MM:g} mm"):
        t.add_column(c, justify="left" if c in ("rig", "") else "right")
    for rig in chosen:
        for label in ("uncalibrated", "calibrated"):
            s = result[rig][label]
            if not s.get("completed"):
                t.add_row(rig, label, f"0/{s['runs']}", *["-"] * 5)
                continue
            t.add_row(rig, label, f"{s['completed']}/{s['runs']}", f"{s['stroke_mean_mm']:.2f}",
                      f"{s['stroke_max_mm_median']:.2f} / {s['stroke_max_mm']:.2f}",
                      f"{s['track_mean_mrad']:.1f} / {s['track_max_mrad']:.1f}", f"{s['meet_target']:.0%}",
                      f"{s['meet_target_max']:.0%}")
    console.print(t)
    console.print(f"wrote {json_out}")
