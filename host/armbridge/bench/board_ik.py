"""`armbridge bench board-ik`: the ESP32's Cartesian IK (issue 10 section 3) measured.

The firmware's BoardIK (firmware/esp32/ik3r.py + mlp.py) runs on random targets
of the safe disc, under the real MicroPython interpreter (WebAssembly, by Node:
emulator/mpbridge/boardik.mjs) and under CPython (the same files imported), and
is compared with the host's float64 reference of the same algorithm
(`ik.board_ik`) and with the float net (`Arm3rANN`, float.onnx) followed by the
same FABRIK passes. Reported: the net's size (file, parsed buffers, heap taken
under MicroPython), multiply-adds per point, time per point (net alone, FABRIK
alone, the whole solve) in both interpreters, the board's answers against both
references, the tip error distribution, the fraction that converge within
IK_TOL_UM against the pass count, and the float32 effect (the reference run in
float32, the chip's float width).

Times are wall-clock on the machine that runs the bench (under MicroPython:
performance.now()); no chip was measured.
"""
from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import typer

from armbridge.bench.command import write_json
from armbridge.errors import ArmbridgeError
from armbridge.ik.board_ik import BoardIKReference, firmware_config, shipped_weights

POINTS = 2000
SEED = 0
SPREAD = 0.25  # rad: theta = IK_THETA +- SPREAD for the second target set
SWEEP = (16, 32, 64, 96, 128, 160)
WASM_TIMEOUT_S = 900.0


def disc_targets(ref: BoardIKReference, n: int, seed: int, theta: float, spread: float = 0.0) -> np.ndarray:
    """n targets (x, y, theta) uniform in the safe disc, theta uniform in theta +- spread."""
    rng = np.random.default_rng(seed)
    (cx, cy), r = ref.region.center, ref.region.radius
    rad, ang = r * np.sqrt(rng.random(n)), 2 * np.pi * rng.random(n)
    th = theta + spread * (2 * rng.random(n) - 1)
    return np.stack([cx + rad * np.cos(ang), cy + rad * np.sin(ang), th], axis=-1)


def under_micropython(poses: Any, timing: bool = False, config: dict | None = None,
                      timeout: float = WASM_TIMEOUT_S) -> dict[str, Any]:
    """The firmware's BoardIK on poses (B, 3) under the MicroPython WebAssembly interpreter."""
    from armbridge.emulator.micropython import find_micropython, find_node
    from armbridge.resources import firmware_dir

    script = _script()
    argv = [find_node(), str(script), str(find_micropython()), str(firmware_dir() / "esp32"), str(shipped_weights())]
    inp = json.dumps({"targets": np.asarray(poses, dtype=float).tolist(), "time": timing, "config": config or {}})
    try:
        proc = subprocess.run(argv, input=inp, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise ArmbridgeError(f"the board IK under MicroPython took over {timeout:g} s") from None
    if proc.returncode != 0:
        raise ArmbridgeError(f"the board IK under MicroPython failed (status {proc.returncode}): "
                             f"{proc.stderr.strip()[-1500:]}")
    out: dict[str, Any] = json.loads(proc.stdout)
    return out


def _script() -> Any:
    from importlib import resources

    return resources.files("armbridge.emulator.mpbridge") / "boardik.mjs"


def under_cpython(ik: Any, poses: np.ndarray) -> dict[str, Any]:
    """The firmware's BoardIK on poses under CPython: answers and times (s per point)."""
    pts = poses.tolist()
    t0 = time.perf_counter()
    q = [ik.solve(*p) for p in pts]
    t1 = time.perf_counter()
    guess = [ik.guess(*p) for p in pts]
    t2 = time.perf_counter()
    for p, g in zip(pts, guess):
        ik.refine(p[0], p[1], p[2], g, ik.passes)
    t3 = time.perf_counter()
    n = len(pts)
    return {"q": q, "guess": guess, "us_solve": 1e6 * (t1 - t0) / n, "us_net": 1e6 * (t2 - t1) / n,
            "us_refine": 1e6 * (t3 - t2) / n}


def dist(a: np.ndarray, scale: float = 1.0) -> dict[str, float]:
    """mean, median, p99 and max of a, times scale."""
    a = np.asarray(a, dtype=float) * scale
    return {"mean": float(a.mean()), "median": float(np.median(a)), "p99": float(np.quantile(a, 0.99)),
            "max": float(a.max())}


def _tip(ref: BoardIKReference, q: np.ndarray, poses: np.ndarray) -> np.ndarray:
    return np.linalg.norm(ref.chain.ee_point(q) - poses[:, :2], axis=-1)


def _as_q(answers: list) -> tuple[np.ndarray, np.ndarray]:
    got = np.array([q is not None for q in answers])
    q = np.array([q if q is not None else [np.nan] * 3 for q in answers], dtype=float)
    return got, q


def compare(ref: BoardIKReference, poses: np.ndarray, answers: list, q_float: np.ndarray) -> dict[str, Any]:
    """The board's answers against the int8 reference and the float net + the same FABRIK."""
    sol = ref.solve(poses)
    got, q = _as_q(answers)
    both = got & sol.ok
    tip = _tip(ref, q[got], poses[got])
    return {
        "targets": int(len(poses)), "answered": int(got.sum()),
        "agree_with_reference": int((got == sol.ok).sum()),
        "vs_int8_reference_rad": dist(np.abs(q[both] - sol.q[both]).max(axis=-1)),
        "vs_float_net_fabrik_rad": dist(np.abs(q[got] - q_float[got]).max(axis=-1)),
        "tip_error_um": dist(tip, 1e6),
    }


def board_ik_report(points: int = POINTS, seed: int = SEED, progress=lambda text: None) -> dict[str, Any]:
    """Every number of the module docstring on `points` targets (seeded)."""
    from armbridge.emulator.runner import load_firmware
    from armbridge.ik.arm3r_ann import Arm3rANN
    from armbridge.resources import firmware_dir

    if points < 10:
        raise ArmbridgeError(f"the board IK bench needs at least 10 points, got {points}")
    fw = load_firmware([firmware_dir() / "esp32", firmware_dir() / "common"], ("config", "ik3r"))
    cfg = firmware_config()
    ref = BoardIKReference.from_config(cfg)
    theta = cfg.IK_THETA_MRAD / 1000.0
    weights = shipped_weights().read_bytes()
    ik = fw["ik3r"].BoardIK(fw["config"], weights)
    ann = Arm3rANN.load()
    sets = {"pen_angle": disc_targets(ref, points, seed, theta),
            "pen_angle_spread": disc_targets(ref, points, seed + 1, theta, SPREAD)}
    result: dict[str, Any] = {
        "points": points, "seed": seed, "passes": ref.passes, "tol_um": ref.tol * 1e6,
        "region": {"center_m": list(ref.region.center), "radius_m": ref.region.radius},
        "net": {"file_bytes": len(weights), "ram_bytes": ik.net.ram_bytes(), "macs_per_point": ik.net.macs(),
                "parameters": int(sum(lay["rows"] * (lay["cols"] + 1) for lay in ref.layers)),
                "layers": [[lay["cols"], lay["rows"]] for lay in ref.layers]},
    }
    for name, poses in sets.items():
        progress(f"{name}: MicroPython (WebAssembly), {points} targets")
        mp = under_micropython(poses, timing=True)
        progress(f"{name}: CPython and the references")
        cp = under_cpython(ik, poses)
        q_float = ref.refine(poses, ann.predict(poses))
        n_int8, n_float = ref.net(poses), ann.predict(poses)
        f32 = ref.solve(poses, np.float32)
        sol = ref.solve(poses)
        both = f32.ok & sol.ok
        result[name] = {
            "theta_rad": [float(poses[:, 2].min()), float(poses[:, 2].max())],
            "micropython": compare(ref, poses, mp["q"], q_float),
            "cpython": compare(ref, poses, cp["q"], q_float),
            "net_tip_error_mm": {"int8_board": dist(_tip(ref, n_int8, poses), 1e3),
                                 "float": dist(_tip(ref, n_float, poses), 1e3)},
            "net_int8_vs_float_rad": dist(np.abs(n_int8 - n_float).max(axis=-1)),
            "float32_vs_float64_rad": dist(np.abs(f32.q[both] - sol.q[both]).max(axis=-1)),
            "converged_by_passes": {str(p): float(np.mean(_tip(ref, ref.refine(poses, n_int8, p), poses) <= ref.tol))
                                    for p in SWEEP},
            "us_per_point": {
                "micropython": {"net": mp["us_net"] / points, "fabrik": mp["us_refine"] / points,
                                "solve": mp["us_solve"] / points},
                "cpython": {"net": cp["us_net"], "fabrik": cp["us_refine"], "solve": cp["us_solve"]}},
        }
        result["net"]["micropython_heap_bytes"] = mp["heap_bytes"]
        result["net"]["native"] = mp["native"]
    return result


def print_report(r: dict[str, Any], console: Any) -> None:
    net = r["net"]
    console.print(f"board IK: net {' -> '.join(str(c) for c, _ in net['layers'])} -> {net['layers'][-1][1]}, "
                  f"{net['parameters']:,} parameters, file {net['file_bytes']:,} B, buffers {net['ram_bytes']:,} B, "
                  f"MicroPython heap {net['micropython_heap_bytes']:,} B, {net['macs_per_point']:,} multiply-adds "
                  f"per point; {r['passes']} FABRIK passes, tol {r['tol_um']:g} um")
    for name in ("pen_angle", "pen_angle_spread"):
        s = r[name]
        mp, t = s["micropython"], s["us_per_point"]
        console.print(
            f"{name} (theta {s['theta_rad'][0]:.2f}..{s['theta_rad'][1]:.2f} rad): answered {mp['answered']}"
            f"/{mp['targets']}, agree with the reference {mp['agree_with_reference']}/{mp['targets']}, "
            f"max |dq| vs int8 reference {mp['vs_int8_reference_rad']['max']:.2g} rad, vs float net + FABRIK "
            f"{mp['vs_float_net_fabrik_rad']['max']:.2g} rad; tip error mean {mp['tip_error_um']['mean']:.2f} "
            f"max {mp['tip_error_um']['max']:.1f} um")
        console.print(
            f"  us per point: MicroPython net {t['micropython']['net']:.0f} fabrik {t['micropython']['fabrik']:.0f} "
            f"solve {t['micropython']['solve']:.0f}; CPython net {t['cpython']['net']:.0f} "
            f"fabrik {t['cpython']['fabrik']:.0f} solve {t['cpython']['solve']:.0f}")


def board_ik_cmd(
    points: int = typer.Option(2000, "--points", min=10, help="Random targets per set (two sets: at the pen "
                               "angle, and +- 0.25 rad around it)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the random targets."),
    json_out: Path = typer.Option(Path("runs/bench-board-ik.json"), "--out", "--json",
                                  help="Where to write the results ('-': stdout)."),
) -> None:
    """The ESP32's Cartesian IK (int8 net + FABRIK, firmware/esp32/ik3r.py) under the
    real MicroPython interpreter and CPython: net size, multiply-adds and time per
    point, answers against the host's int8 reference and the float net, tip errors."""
    from rich.console import Console

    console = Console()
    result = board_ik_report(points, seed,
                             progress=lambda text: console.print(f"[dim]bench board-ik: {text}[/]"))
    write_json(result, json_out)
    print_report(result, console)
    console.print(f"wrote {json_out}")
