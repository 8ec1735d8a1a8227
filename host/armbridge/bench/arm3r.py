"""`armbridge bench arm3r`: Tables 5-8 of the 3R drawing-arm paper (Murai, Vairagi, Semwal).

Targets: the pen waypoints of the paper's twelve samples (Table 3, `draw.samples`),
each placed in the safe region (`ik.region`) at 90 % of the largest size that fits
(so the tips start strictly inside the CBF's safe set), at the pen angle phi. The
reference joint angles of a target are the closed-form IK at (x, y, phi) (arm3r's
limits leave one elbow branch, so the reference is unique).

Rows, all on the same targets in one run:

* ANN: the shipped float net (Table 2) alone;
* ANN + FABRIK: `ik.arm3r_pipeline.solve` (tol 1 um, up to 200 passes), FABRIK with
  the pen angle held (the wrist joint on the target less l3 along phi, links 1-2
  solved there, the wrist making up phi: `ik.fabrik.fabrik_oriented`);
* ANN + FABRIK, position only: the same with FABRIK on position alone (the paper's
  Algorithm as printed, 50 passes), which spends the orientation: the wrist angle
  it leaves is why the held form is the pipeline's;
* ANN + FABRIK + CBF: each target's ANN + FABRIK answer is the CBF-QP's reference
  (`ik.cbf.track`, held, `cbf_steps` steps at gain 20/s, dt 10 ms) from the previous
  target's answer, so every step of the drawing passes the safety filter;
* closed form: `ik.analytic3r.ik` with the orientation (the free parameter of a
  position-only task) set to the pen angle: exact, the floor and the speed baseline;
* RTB LM: roboticstoolbox's `ik_LM` on arm3r as a DHRobot of three revolute links
  (mask x, y, yaw; from the middle of the limits; one point a call), on the first
  `rtb_points` targets of each sample, when roboticstoolbox imports (the masr extra).

Errors per row: MSE, RMSE, MAE of x and y (mm, FK of the answer against the target),
q1-q3 (deg, against the reference) and theta = q1 + q2 + q3 (deg, against phi), per
sample (Tables 6-7) and pooled (Tables 5 and 8), beside the paper's values (`PAPER`:
Tables 5-8; the paper gives theta per model and overall, not per sample, so each
sample's theta is held to the overall 1.25 deg of Table 8). Also: time per point single (one
target a call, median) and batched (a whole sample a call, best of 3); safe-region
and joint-limit violations of the CBF over `random_targets` random targets in a
square twice the disk's diameter around it (four in five outside); the CBF's Lyapunov
function along the samples drawn in turn, checked to decrease and plotted as Fig. 13
(`bench.arm3r_lyapunov`, key "lyapunov"); and the int8 nets (the board's flat file and
the int8 ONNX) against the float net; and "ROBOTICS" drawn on the emulated arm on
both rigs and with the board's own IK (`bench.arm3r_drawing`, key "drawing").
"""
from __future__ import annotations

import platform
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import typer

from armbridge.bench.command import write_json
from armbridge.ik import arm3r_pipeline as pipe
from armbridge.ik.analytic3r import ik as closed_form
from armbridge.ik.arm3r_ann import Arm3rANN, flat_int8_predictor, poses_of, shipped_card
from armbridge.ik.cbf import barrier_values, track
from armbridge.ik.region import pen_angle, safe_region
from armbridge.robots import get_robot
from armbridge.robots.planar import PlanarChain

CBF = pipe.PATH_CBF  # gamma 10/s, K 20/s, dt 10 ms: K dt = 0.2, 100 steps leave 2e-10 of a move
PLACE_FRACTION = 0.9


def _t(*v: float) -> dict[str, float]:
    return dict(zip(("mse", "rmse", "mae"), v))


# The paper's Tables 5-8 (units not stated; read here as mm and degrees). Per sample (Tables 6, 7):
# name in draw.samples -> x and y errors of ANN + FABRIK (+ CBF), MSE / RMSE / MAE.
PAPER_PER_SAMPLE: dict[str, dict[str, dict[str, float]]] = {
    "csv-circle": {"x": _t(0.10, 0.32, 0.24), "y": _t(0.48, 0.69, 0.51)},
    "csv-manit": {"x": _t(0.18, 0.43, 0.31), "y": _t(0.22, 0.47, 0.37)},
    "image-circle": {"x": _t(0.10, 0.31, 0.28), "y": _t(1.06, 1.03, 0.67)},
    "image-triangle": {"x": _t(0.12, 0.34, 0.23), "y": _t(0.50, 0.70, 0.43)},
    "image-square": {"x": _t(0.21, 0.46, 0.32), "y": _t(0.84, 0.92, 0.62)},
    "image-pentagon": {"x": _t(0.11, 0.34, 0.30), "y": _t(0.59, 0.77, 0.45)},
    "image-hexagon": {"x": _t(0.10, 0.31, 0.27), "y": _t(0.89, 0.94, 0.60)},
    "text-manit": {"x": _t(0.04, 0.20, 0.17), "y": _t(0.02, 0.15, 0.13)},
    "text-robotics": {"x": _t(0.06, 0.25, 0.20), "y": _t(0.18, 0.42, 0.28)},
    "text-3-link": {"x": _t(0.03, 0.19, 0.16), "y": _t(0.02, 0.15, 0.14)},
    "text-bhopal": {"x": _t(0.03, 0.18, 0.15), "y": _t(0.05, 0.23, 0.18)},
    "text-research": {"x": _t(2.71, 1.64, 1.40), "y": _t(0.26, 0.51, 0.32)},
}
PAPER_THETA = _t(1.66, 1.25, 0.96)  # Table 8, "Error in Theta": the wrist angle's target
PAPER: dict[str, Any] = {
    "overall_theta": PAPER_THETA,
    "table8_overall": {"q1": _t(2.52, 1.57, 1.33), "q2": _t(0.00, 0.01, 0.00), "q3": _t(2.52, 1.57, 1.34),
                       "theta": _t(1.66, 1.25, 0.96), "x": _t(0.18, 0.30, 0.24), "y": _t(0.43, 0.58, 0.39)},
    "table5": {"ann_fabrik": {"x": _t(0.23, 0.48, 0.319), "y": _t(0.15, 0.39, 0.29), "q1": _t(2.58, 1.6, 1.36),
                              "q2": _t(1.04, 0.0, 0.0), "q3": _t(2.58, 1.6, 1.36), "theta": _t(5.64, 2.37, 1.76)},
               "ann": {"x": _t(0.32, 0.57, 0.421), "y": _t(0.05, 0.24, 0.15), "q1": _t(2.44, 1.56, 1.31),
                       "q2": _t(4.5, 0.0, 0.0), "q3": _t(2.44, 1.56, 1.31), "theta": _t(0.72, 0.85, 0.68)}},
    "tables6_7_per_sample": PAPER_PER_SAMPLE,
    "time": "ANN under 1 ms, FABRIK 2-3 ms more per prediction (section 5.3)",
}


@dataclass(frozen=True)
class Arm3rBenchSize:
    samples: tuple[str, ...]  # names in draw.samples.SAMPLES; () = all twelve
    random_targets: int
    random_steps: int  # CBF steps per random target
    cbf_steps: int  # CBF steps per drawing target
    single_points: int  # targets per sample timed one a call
    rtb_points: int  # targets per sample for RTB LM
    drawing_speed: float  # m/s of the ROBOTICS drawing on the emulated rigs (bench/arm3r_drawing.py)


FULL = Arm3rBenchSize((), 100_000, 150, 100, 100, 100, 0.03)
QUICK = Arm3rBenchSize(("csv-circle", "image-square", "text-robotics"), 2_000, 100, 100, 10, 10, 0.1)
ROWS = ("ann", "ann_fabrik", "ann_fabrik_cbf", "ann_fabrik_position_only", "closed_form", "rtb_lm")
COLS = ("x", "y", "q1", "q2", "q3", "theta")


def errors(chain: PlanarChain, q: np.ndarray, poses: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """Per target (N, 6): x, y error (mm), q1-q3 error (deg), theta error (deg)."""
    got = poses_of(chain, q)
    return np.concatenate([(got[:, :2] - poses[:, :2]) * 1e3, np.rad2deg(q - q_ref),
                           np.rad2deg(got[:, 2:] - poses[:, 2:])], axis=1)


def stats(e: np.ndarray) -> dict[str, dict[str, float]]:
    """MSE, RMSE, MAE per column of errors (N, 6), and the mean tip distance (mm)."""
    out: dict[str, Any] = {}
    for i, c in enumerate(COLS):
        mse = float(np.mean(e[:, i] ** 2))
        out[c] = {"mse": mse, "rmse": float(np.sqrt(mse)), "mae": float(np.mean(np.abs(e[:, i])))}
    tip = np.hypot(e[:, 0], e[:, 1])
    out["tip_mm"] = {"mean": float(tip.mean()), "max": float(tip.max())}
    return out


def _best_ms(fn: Callable[[], Any], n: int, repeats: int = 3) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e3


def _single_ms(fn: Callable[[np.ndarray], Any], poses: np.ndarray) -> float:
    ts = []
    for p in poses:
        t0 = time.perf_counter()
        fn(p[None])
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts) * 1e3)


def _rtb(chain: PlanarChain) -> Callable[[np.ndarray], np.ndarray] | str:
    """poses (B, 3) -> q by roboticstoolbox's LM, one call a point; or why it is missing."""
    try:
        import roboticstoolbox as rtb  # type: ignore[import-untyped]
        from spatialmath import SE3  # type: ignore[import-untyped]
    except ImportError as exc:
        return f"roboticstoolbox is not installed ({exc.name}; the masr extra installs it)"
    robot = rtb.DHRobot([rtb.RevoluteDH(a=float(a), qlim=[float(lo), float(hi)])
                         for a, lo, hi in zip(chain.link_lengths, chain.q_min, chain.q_max)], name=chain.name)
    q0 = (chain.q_min + chain.q_max) / 2

    def solve(poses: np.ndarray) -> np.ndarray:
        out = np.empty((len(poses), chain.n))
        for k, (x, y, phi) in enumerate(poses):
            sol = robot.ik_LM(SE3(x, y, 0.0) * SE3.Rz(phi), q0=q0, mask=np.array([1, 1, 0, 0, 0, 1]), tol=1e-14,
                              ilimit=100, slimit=20, joint_limits=True)
            out[k] = sol[0]
        return out

    return solve


def _cbf_path(chain: PlanarChain, region: Any, q_ref: np.ndarray, q_first: np.ndarray, steps: int) -> Any:
    """Each target i's reference held for `steps` filter steps from target i-1's reference
    (the first from q_first), batched over the targets (`armbridge draw --ik paper` runs the same)."""
    return pipe.cbf_path(chain, region, q_ref, q_first, steps, CBF)


def _sample(chain, name, ann, rtb, size, region, phi) -> dict[str, Any]:
    from armbridge.draw.build import build
    from armbridge.draw.samples import SAMPLES, sample_lines

    s = SAMPLES[name]
    fit = build(sample_lines(name), chain, name=name, source=s.source)
    d = build(sample_lines(name), chain, name=name, source=s.source, size=PLACE_FRACTION * fit.placement.size)
    poses = np.c_[d.xy, np.full(len(d.xy), phi)]
    q_ref, ok = closed_form(chain, poses)
    assert ok.all(), f"{name}: a target outside the safe region's IK"  # placement keeps them inside
    res = pipe.solve(chain, ann.predict, poses[:, :2], phi)
    free = pipe.solve(chain, ann.predict, poses[:, :2], phi, orient=False)
    q_ann = ann.predict(poses)
    cbf = _cbf_path(chain, region, res.q, q_ref[0], size.cbf_steps)
    answers: dict[str, Any] = {"ann": q_ann, "ann_fabrik": res.q, "ann_fabrik_cbf": cbf.q,
                               "ann_fabrik_position_only": free.q, "closed_form": q_ref}
    k = min(size.rtb_points, len(poses))
    if callable(rtb):
        answers["rtb_lm"] = rtb(poses[:k])
    rows: dict[str, Any] = {r: stats(errors(chain, q, poses[: len(q)], q_ref[: len(q)])) for r, q in answers.items()}
    rows["rtb_lm"] = rows.get("rtb_lm", {"missing": rtb if isinstance(rtb, str) else ""})
    single = poses[: size.single_points]
    n = len(poses)
    timing = {
        "ann": {"single_ms": _single_ms(ann.predict, single), "batched_ms": _best_ms(lambda: ann.predict(poses), n)},
        "ann_fabrik": {"single_ms": _single_ms(lambda p: pipe.solve(chain, ann.predict, p[:, :2], phi), single),
                       "batched_ms": _best_ms(lambda: pipe.solve(chain, ann.predict, poses[:, :2], phi), n)},
        "cbf_filter": {"batched_ms_per_point_step": _best_ms(
            lambda: _cbf_path(chain, region, res.q, q_ref[0], 10), n * 10, 1)},
        "closed_form": {"single_ms": _single_ms(lambda p: closed_form(chain, p), single),
                        "batched_ms": _best_ms(lambda: closed_form(chain, poses), n)},
    }
    if callable(rtb):
        timing["rtb_lm"] = {"single_ms": _single_ms(rtb, poses[: min(k, size.single_points)])}
    return {"name": name, "number": s.number, "source": s.source, "plot": s.plot, "points": n,
            "rtb_points": k if callable(rtb) else 0, "size_m": d.placement.size,
            "fabrik_converged_pct": float(res.ok.mean() * 100),
            "fabrik_oriented_pct": float(res.oriented.mean() * 100) if res.oriented is not None else 0.0,
            "paper": PAPER_PER_SAMPLE.get(name, {}),
            "cbf": {"h_min": float(cbf.h_min.min()), "limit_margin_min_rad": float(cbf.limit_margin_min.min())},
            "rows": rows, "timing": timing, "_errors": {r: errors(chain, q, poses[: len(q)], q_ref[: len(q)])
                                                       for r, q in answers.items()},
            "_poses": poses, "_lyapunov": (q_ref[0], res.q)}


def _random_cbf(chain, ann, region, phi, count: int, steps: int, seed: int) -> dict[str, Any]:
    """ANN + FABRIK + CBF on random targets around the disk: every step in the safe set?"""
    rng = np.random.default_rng(seed)
    xy = np.asarray(region.center) + rng.uniform(-2 * region.radius, 2 * region.radius, (count, 2))
    t0 = time.perf_counter()
    res = pipe.solve(chain, ann.predict, xy, phi)
    t1 = time.perf_counter()
    q_start, _ = closed_form(chain, np.array([[*region.center, phi]]))
    out = track(chain, region, np.tile(q_start, (count, 1)), res.q, steps, CBF)
    t2 = time.perf_counter()
    final = barrier_values(chain, region, out.q)
    return {"targets": count, "outside_region": int((~region.contains(xy)).sum()), "steps": steps,
            "region_violations": int((out.h_min < 0).sum()), "limit_violations": int((out.limit_margin_min < 0).sum()),
            "final_unsafe": int((final < 0).any(axis=1).sum()),
            "lyapunov_rises": int((np.diff(out.V, axis=0) > 1e-12 * out.V[:-1] + 1e-15).sum()),
            "ann_fabrik_batched_ms_per_point": (t1 - t0) / count * 1e3,
            "cbf_ms_per_point_step": (t2 - t1) / (count * steps) * 1e3, "solver_rows": out.stats}


def _int8(chain, ann, poses: np.ndarray, phi: float) -> dict[str, Any]:
    """The int8 nets against the float net on the same targets, alone and after FABRIK."""
    card = shipped_card()
    qf = ann.predict(poses)
    nets = {"flat_int8 (board)": flat_int8_predictor(chain, card.parent / ann.card["files"]["int8_flat"]["path"]),
            "onnx_int8": Arm3rANN.load(card, int8=True).predict}
    out = {}
    for name, predict in nets.items():
        q8 = predict(poses)
        res = pipe.solve(chain, predict, poses[:, :2], phi)
        tip = np.linalg.norm(chain.ee_point(q8) - chain.ee_point(qf), axis=1) * 1e3
        out[name] = {"vs_float_q_max_abs_deg": float(np.rad2deg(np.abs(q8 - qf).max())),
                     "vs_float_q_mae_deg": float(np.rad2deg(np.abs(q8 - qf).mean())),
                     "vs_float_tip_mean_mm": float(tip.mean()), "vs_float_tip_max_mm": float(tip.max()),
                     "with_fabrik_tip_mean_mm": float(res.error.mean() * 1e3)}
    return out


def run(size: Arm3rBenchSize, progress: Callable[[str], None] = lambda s: None, seed: int = 10,
        lyapunov_png: Path | None = None) -> dict[str, Any]:
    from armbridge.bench.arm3r_drawing import drawing_runs
    from armbridge.bench.arm3r_lyapunov import section as lyapunov_section
    from armbridge.draw.samples import SAMPLES

    chain = get_robot("arm3r")
    region, phi = safe_region(chain), pen_angle(chain)
    ann = Arm3rANN.load()
    rtb = _rtb(chain)
    per = []
    for name in size.samples or tuple(SAMPLES):
        per.append(_sample(chain, name, ann, rtb, size, region, phi))
        progress(f"{name}: {per[-1]['points']} points")
    overall = {}
    for r in ROWS:
        e = [s["_errors"][r] for s in per if r in s["_errors"]]
        overall[r] = stats(np.concatenate(e)) if e else {"missing": rtb if isinstance(rtb, str) else ""}
    poses = np.concatenate([s.pop("_poses") for s in per])
    lyap = [s.pop("_lyapunov") for s in per]
    progress("Lyapunov function along the samples (Fig. 13)")
    lyapunov = lyapunov_section(chain, region, CBF, [s["name"] for s in per], [a for a, _ in lyap],
                                [b for _, b in lyap], lyapunov_png)
    for s in per:
        s.pop("_errors")
    progress(f"CBF on {size.random_targets:,} random targets")
    random = _random_cbf(chain, ann, region, phi, size.random_targets, size.random_steps, seed)
    violations = random["region_violations"] + random["limit_violations"] + sum(
        s["cbf"]["h_min"] < 0 or s["cbf"]["limit_margin_min_rad"] < 0 for s in per)
    drawing = drawing_runs(size.drawing_speed, progress=progress)
    timing = {r: {k: float(np.mean([s["timing"][r][k] for s in per if r in s["timing"]]))
                  for k in per[0]["timing"].get(r, {})} for r in per[0]["timing"]}
    return {
        "bench": "arm3r", "size": asdict(size), "robot": chain.name,
        "safe_region": {"center": list(region.center), "radius_m": region.radius, "pen_angle_rad": phi},
        "units": {"x, y": "mm", "q1-q3, theta": "deg", "time": "ms per point"},
        "cbf": asdict(CBF), "place_fraction": PLACE_FRACTION,
        "samples": per, "overall": overall, "timing_mean_over_samples": timing,
        "random_cbf": random, "lyapunov": lyapunov, "int8": _int8(chain, ann, poses, phi),
        "drawing": drawing, "paper": PAPER,
        "targets": {"ann_fabrik_mean_under_0.1mm_every_sample":
                    all(s["rows"]["ann_fabrik"]["tip_mm"]["mean"] < 0.1 for s in per),
                    "theta_rmse_at_most_paper_1.25deg_every_sample": all(
                        s["rows"][r]["theta"]["rmse"] <= PAPER_THETA["rmse"]
                        for s in per for r in ("ann_fabrik", "ann_fabrik_cbf")),
                    "xy_rmse_at_most_papers_every_sample": all(
                        s["rows"][r][c]["rmse"] <= s["paper"][c]["rmse"]
                        for s in per for r in ("ann_fabrik", "ann_fabrik_cbf") for c in ("x", "y")),
                    "zero_cbf_violations": violations == 0,
                    "ann_fabrik_under_0.1ms_batched": timing["ann_fabrik"]["batched_ms"] < 0.1,
                    "lyapunov_decreasing": lyapunov["decreasing"],
                    "robotics_drawn_on_every_rig": all(r.get("completed") for r in drawing["runs"].values())},
        "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
    }


def sample_table(result: dict[str, Any]) -> Any:
    """Per sample (Tables 6, 7 and Table 8's theta): RMSE of the full pipeline (ANN + FABRIK + CBF)
    beside the paper's, and the wrist angle FABRIK on position alone leaves."""
    from rich.table import Table

    t8 = result["paper"]["table8_overall"]
    table = Table(title="per sample, RMSE: ANN + FABRIK + CBF (ours) / the paper's ANN + FABRIK "
                        "(x, y: Tables 6, 7, mm; theta: Table 8 overall, deg)")
    for col in ("no.", "source", "plot", "points", "x", "y", "mean tip (mm)", "theta",
                "theta, FABRIK position only"):
        table.add_column(col, justify="left" if col in ("source", "plot") else "right")

    def cell(ours: float, paper: float | None) -> str:
        return f"{ours:.3g} / {paper:.2f}" if paper is not None else f"{ours:.3g}"

    for s in result["samples"]:
        row, paper = s["rows"]["ann_fabrik_cbf"], s.get("paper", {})
        table.add_row(str(s["number"]), s["source"], s["plot"], str(s["points"]),
                      *[cell(row[c]["rmse"], paper.get(c, {}).get("rmse")) for c in ("x", "y")],
                      f"{row['tip_mm']['mean']:.2g}", cell(row["theta"]["rmse"], t8["theta"]["rmse"]),
                      f"{s['rows']['ann_fabrik_position_only']['theta']['rmse']:.3g}")
    o = result["overall"]["ann_fabrik_cbf"]
    table.add_row("all", "", "", str(sum(s["points"] for s in result["samples"])),
                  *[cell(o[c]["rmse"], t8[c]["rmse"]) for c in ("x", "y")], f"{o['tip_mm']['mean']:.2g}",
                  cell(o["theta"]["rmse"], t8["theta"]["rmse"]),
                  f"{result['overall']['ann_fabrik_position_only']['theta']['rmse']:.3g}")
    return table


def arm3r_cmd(
    quick: bool = typer.Option(False, "--quick", help="Reduced size (CI): 3 of the 12 samples, 2,000 random CBF "
                               "targets, 10 points timed singly and solved by RTB LM."),
    seed: int = typer.Option(10, "--seed", help="Seed of the random CBF targets."),
    json_out: Path = typer.Option(Path("runs/bench-arm3r.json"), "--json", help="Where to write the results ('-': stdout)."),
    lyapunov_png: Path = typer.Option(None, "--lyapunov-png", help="Also plot Fig. 13 (the CBF's Lyapunov "
                                      "function along each sample) to this PNG."),
) -> None:
    """Tables 5-8 of the 3R drawing-arm paper on its twelve samples: MSE, RMSE, MAE in
    x, y, q1-q3, theta for ANN, ANN + FABRIK (pen angle held), ANN + FABRIK + CBF, ANN +
    FABRIK on position alone, the closed form and RTB LM, per sample beside the paper's; time per point; CBF violations over random targets; the Lyapunov function
    checked to decrease (Fig. 13); int8 against float."""
    from rich.console import Console
    from rich.table import Table

    console = Console()
    console = Console(width=max(console.width, 160))  # the tables' columns unclipped in a log or a pipe too
    result = run(QUICK if quick else FULL, seed=seed, lyapunov_png=lyapunov_png,
                 progress=lambda text: console.print(f"[dim]bench arm3r: {text}[/]"))
    write_json(result, json_out)
    table = Table(title="armbridge bench arm3r: overall (Tables 5, 8); x, y mm, angles deg: MSE / RMSE / MAE")
    for col in ("row", *COLS, "mean tip (mm)"):
        table.add_column(col, justify="left" if col == "row" else "right")
    for row, s in result["overall"].items():
        if "missing" in s:
            table.add_row(row, s["missing"], *[""] * 6)
            continue
        table.add_row(row, *[f"{s[c]['mse']:.3g} / {s[c]['rmse']:.3g} / {s[c]['mae']:.3g}" for c in COLS],
                      f"{s['tip_mm']['mean']:.2g}")
    console.print(table)
    console.print(sample_table(result))
    rc = result["random_cbf"]
    console.print(f"CBF on {rc['targets']:,} random targets ({rc['outside_region']:,} outside the region): "
                  f"{rc['region_violations']} region and {rc['limit_violations']} joint-limit violations")
    ly = result["lyapunov"]
    console.print(f"Lyapunov V on {ly['rows']} samples, {ly['checked']:,} filter steps: {ly['violations']} rises "
                  f"(max change {ly['max_increase']:.3g} rad^2), {ly['constrained_steps']} steps constrained"
                  + (f"; wrote {ly['png']}" if "png" in ly else ""))
    dr = result["drawing"]
    for name, drawn in dr["runs"].items():
        console.print(f"ROBOTICS at {dr['speed_m_s']:g} m/s on {name}: " + (
            f"trace from strokes {drawn['trace_mean_mm']:.2f} / {drawn['trace_max_mm']:.2f} mm, strokes from trace "
            f"{drawn['target_mean_mm']:.2f} / {drawn['target_max_mm']:.2f} mm (mean / max), "
            f"{drawn['s_per_character']:.2f} s per character" if drawn.get("completed") else f"FAILED: {drawn.get('error')}"))
    console.print("targets: " + ", ".join(f"{k} {'met' if v else 'MISSED'}" for k, v in result["targets"].items()))
    console.print(f"wrote {json_out}")
