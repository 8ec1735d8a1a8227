"""`armbridge draw`: text, an SVG, a CSV of points, an image, a shape or a built-in sample
-> a joint-space plan for the drawing arm (and a PNG of it). See docs/drawing.md."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from armbridge.errors import ArmbridgeError
from armbridge.executor.command import (CARTESIAN_HELP, KEYS_HELP, PEN_DOWN_HELP, PEN_HELP, PEN_UP_HELP,
                                        PEN_WAIT_HELP)
from armbridge.executor.penpos import pen_pos_options

PEN_DRAW_NOTE = (" Kept in the plan (its drawing provenance) for `armbridge run`; with --port sent as one PENPOS "
                 "before the first waypoint.")

DEFAULT_SPEED = 0.02  # m/s: a steady pen on a hobby-servo arm
DEFAULT_TRAVEL_SPEED = 0.1  # m/s: pen-up moves (the fastest the 3 mm safety margin was measured at)
PAGE_MARGIN_MM = 10.0  # --margin's default
MERGE_MM = (0.0, 5.0)  # --merge-tolerance accepted, mm
MIN_STROKE_MM = (0.0, 50.0)  # --min-stroke accepted, mm


def _parse_at(at: str) -> tuple[float, float]:
    parts = at.split(",")
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise ArmbridgeError(f"--at {at!r}: expected X,Y in metres, e.g. --at 0.08,0.19") from None
    return x, y


def _check_mm(value: float, option: str, bounds: tuple[float, float]) -> float:
    """An option in mm checked against bounds -> m; one clear line naming the range."""
    lo, hi = bounds
    if not lo <= value <= hi:
        raise ArmbridgeError(f"{option} {value:g} mm is outside [{lo:g}, {hi:g}] mm")
    return value / 1000.0


def _list_samples() -> None:
    from armbridge.draw.samples import SAMPLES

    typer.echo("The paper's samples (Table 3):")
    for name, s in SAMPLES.items():
        typer.echo(f"  {s.number:2d}  {name:15s} {s.source:6s} {s.plot}")


def _sample_text(sample: str | None) -> str | None:
    """The text a text sample writes (its characters time the drawing), else None."""
    from armbridge.draw.samples import SAMPLES

    s = SAMPLES.get(sample.lower()) if sample is not None else None
    return s.plot if s is not None and s.source == "Text" else None


def _lines(text, svg, csv, image, shape, sample, font):
    """(lines, source description, default name) of the one source given."""
    from armbridge.draw import samples, sources

    given = [(k, v) for k, v in (("TEXT", text), ("--svg", svg), ("--csv", csv), ("--image", image),
                                 ("--shape", shape), ("--sample", sample)) if v is not None]
    if len(given) != 1:
        what = "none" if not given else ", ".join(k for k, _ in given)
        raise ArmbridgeError(f"give exactly one thing to draw: TEXT, --svg, --csv, --image, --shape or --sample "
                             f"(got {what})")
    kind, value = given[0]
    if kind == "TEXT":
        value = value.replace("\\n", "\n")  # a shell passes "\n" as two characters
        return sources.text_lines(value, font), f"text {value!r} ({font})", "text"
    if kind == "--svg":
        return sources.svg_file(value), f"svg {value}", Path(value).stem
    if kind == "--csv":
        return sources.csv_file(value), f"csv {value}", Path(value).stem
    if kind == "--image":
        return sources.image_file(value), f"image {value}", Path(value).stem
    if kind == "--shape":
        return sources.shape_lines(value), f"shape {value}", value.lower()
    return samples.sample_lines(value), f"sample {value}", value.lower()


def draw_cmd(
    text: Optional[str] = typer.Argument(None, help="Text to draw (single-stroke Hershey font; \\n for a new line)."),
    svg: Optional[Path] = typer.Option(None, "--svg", help="SVG file to draw (its paths and shapes)."),
    csv: Optional[Path] = typer.Option(None, "--csv", help="CSV file of points: x,y a line, blank line or pen column "
                                                           "between strokes (docs/drawing.md)."),
    image: Optional[Path] = typer.Option(None, "--image", help="Image file: the outlines of its dark shapes (a "
                                                               "transparent PNG: of its opaque ones)."),
    shape: Optional[str] = typer.Option(None, "--shape", help="circle, triangle, square, pentagon, hexagon or star."),
    sample: Optional[str] = typer.Option(None, "--sample", help="One of the paper's samples (see --list-samples)."),
    list_samples: bool = typer.Option(False, "--list-samples", help="List the built-in samples and exit."),
    out: Optional[Path] = typer.Option(None, "--out", help="Plan file to write (armbridge-plan JSON)."),
    png: Optional[Path] = typer.Option(None, "--png", help="Also write a figure of the drawing (framed on it; with "
                                                           "--port, with the executed trace)."),
    svg_out: Optional[Path] = typer.Option(None, "--svg-out", help="Also write the pen-down strokes as SVG at the "
                                                                   "page's scale (with --port: those drawn, from the "
                                                                   "measured angles)."),
    size: Optional[float] = typer.Option(None, "--size", help="The drawing's longer side in m [default: --fit]. It "
                                                                "must fit the safe region; what lies within the "
                                                                "safety margin of its edge is pressed inside by the "
                                                                "CBF filter."),
    fit: bool = typer.Option(False, "--fit", help="As large as fits the safe region less its safety margin (3 mm "
                                                  "up to 0.1 m/s, wider faster: docs/drawing.md) and the page "
                                                  "less its margin (the default)."),
    at: Optional[str] = typer.Option(None, "--at", metavar="X,Y",
                                     help="Where the drawing's (and the page's) centre goes, m [default: the safe "
                                          "region's centre]."),
    page: Optional[str] = typer.Option(None, "--page", metavar="A4|A5|letter|WxH",
                                       help="The sheet it is drawn on (WxH in mm unless a unit is given): the "
                                            "drawing fits it less --margin, and the SVG is in its frame."),
    margin: Optional[float] = typer.Option(None, "--margin", metavar="MM",
                                           help=f"With --page: the margin on every side, mm [default: {PAGE_MARGIN_MM:g}]."),
    landscape: bool = typer.Option(False, "--landscape", help="With --page: the page's longer side along x."),
    rotate: float = typer.Option(0.0, "--rotate", metavar="DEG", help="Turn the drawing counter-clockwise, degrees "
                                                                      "(-360..360)."),
    speed: float = typer.Option(DEFAULT_SPEED, "--speed", help="Pen-down speed in m/s."),
    travel_speed: float = typer.Option(DEFAULT_TRAVEL_SPEED, "--travel-speed",
                                       help="Pen-up speed in m/s: one direct move between strokes (joint speed "
                                            "limits and the safe region still hold)."),
    sort: str = typer.Option("2opt", "--sort", metavar="2opt|greedy|none",
                             help="Stroke order (vpype linesort: greedy, then 2-opt passes)."),
    merge_tolerance: float = typer.Option(0.1, "--merge-tolerance", metavar="MM",
                                          help="Join strokes whose ends are this close (vpype linemerge), mm."),
    min_stroke: float = typer.Option(0.0, "--min-stroke", metavar="MM",
                                     help="Drop strokes shorter than this (vpype filter), mm; 0 keeps all."),
    pen_settle: str = typer.Option("0", "--pen-settle", metavar="MS|DOWN,UP",
                                   help="Extra wait after the pen goes down (and up), ms, beyond the board's own "
                                        "settle (PEN_SETTLE_MS, 150 ms on the ESP32 arm)."),
    font: str = typer.Option("futural", "--font", help="Hershey font for TEXT (vpype's fonts)."),
    robot_name: str = typer.Option("arm3r", "--robot", help="The drawing arm (a planar 3R robot)."),
    ik: str = typer.Option("closed", "--ik", metavar="closed|paper",
                           help="How the joints are planned: closed (the closed-form IK) or paper (the 3R "
                                "paper's ANN + FABRIK with the pen angle held + CBF; arm3r only)."),
    port: Optional[str] = typer.Option(None, "--port", help="Also run the plan on this board (as `armbridge run`: "
                                                            "a serial device, pyserial URL or emu:DEVICE)."),
    rrd: Optional[Path] = typer.Option(None, "--rrd", help="With --port: the recording [default: runs/<time>-<plan>.rrd]."),
    rate: int = typer.Option(50, "--rate", help="With --port: telemetry rate in Hz."),
    json_out: Optional[str] = typer.Option(None, "--json", metavar="FILE",
                                           help="With --port: the run summary as JSON to FILE ('-': stdout)."),
    clear: bool = typer.Option(False, "--clear", help="With --port: clear a latched ESTOP/WDOG/FAULT first."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="With --port: show a progress bar."),
    cartesian: bool = typer.Option(False, "--cartesian", help="With --port: " + CARTESIAN_HELP),
    pen: str = typer.Option("auto", "--pen", metavar="auto|on|off", help="With --port: " + PEN_HELP),
    keys: bool = typer.Option(True, "--keys/--no-keys", help="With --port: " + KEYS_HELP),
    pen_up: Optional[int] = typer.Option(None, "--pen-up", metavar="US", help=PEN_UP_HELP + PEN_DRAW_NOTE),
    pen_down: Optional[int] = typer.Option(None, "--pen-down", metavar="US", help=PEN_DOWN_HELP),
    pen_wait: Optional[int] = typer.Option(None, "--pen-wait", metavar="MS", help=PEN_WAIT_HELP),
) -> None:
    """Turn text, an SVG, a CSV of points, an image or a shape into a plan for the drawing arm.

    The drawing is fitted into the arm's safe region less a safety margin
    (what the executed pen strays from the commanded one, measured: 3 mm up
    to 0.1 m/s) and into --page less its margin, its strokes merged, filtered
    and sorted (vpype, 2-opt by default) to cut pen-up travel, and planned in
    joint space; a discrete control-barrier-function filter then keeps every
    waypoint's pen inside the margin (a point placed beyond it is pressed onto
    it) before the plan is written and streamed. Pen-up moves are one direct
    move each at --travel-speed, cut only where the arm's swept path would
    leave the safe region. Each waypoint carries a pen flag (1 draws, 0 pen
    up). Nothing is written when an input is bad or the drawing does not fit.
    With --port the plan is then run on the board as `armbridge run` does
    (same exit codes: 0 completed, 1 failed, 2 bad input, 128+signal), and
    the summary adds the drawing error.
    """
    if list_samples:
        _list_samples()
        return
    if out is None:
        raise ArmbridgeError("--out PLAN.json is required (where to write the plan)")
    if port is None and (rrd is not None or json_out is not None or clear or cartesian or pen != "auto"):
        raise ArmbridgeError("--rrd, --json, --clear, --cartesian and --pen need --port (they are about running "
                             "the plan)")
    pen_pos = pen_pos_options(pen_up, pen_down, pen_wait)  # bad values: one line, before anything is built
    if fit and size is not None:
        raise ArmbridgeError("give --size or --fit, not both")
    if page is None and (landscape or margin is not None):
        raise ArmbridgeError("--landscape and --margin need --page (they are about the page)")
    from armbridge.draw import layout
    from armbridge.draw.build import build
    from armbridge.draw.page import check_rotate, parse_page
    from armbridge.draw.path import check_ik, check_settle, check_speed
    from armbridge.plans.format import save_plan

    ik = check_ik(ik)
    options = dict(speed=check_speed(speed), travel_speed=check_speed(travel_speed, "--travel-speed"),
                   sort=layout.check_sort(sort), rotate=check_rotate(rotate), pen_settle=check_settle(pen_settle),
                   merge_tolerance=_check_mm(merge_tolerance, "--merge-tolerance", MERGE_MM),
                   min_length=_check_mm(min_stroke, "--min-stroke", MIN_STROKE_MM),
                   page=None if page is None else parse_page(page, landscape=landscape,
                                                             margin_mm=PAGE_MARGIN_MM if margin is None else margin))
    from armbridge.robots import get_robot

    lines, source, name = _lines(text, svg, csv, image, shape, sample, font)
    d = build(lines, get_robot(robot_name), name=name, source=source, size=size,
              at=None if at is None else _parse_at(at), ik=ik, **options)  # type: ignore[arg-type]
    written = text.replace("\\n", "\n") if text is not None else _sample_text(sample)
    if written is not None:
        from armbridge.draw.sources import characters

        d.plan.provenance["drawing"]["characters"] = characters(written)
    if pen_pos:  # `armbridge run` of this plan sends them too (its command line wins)
        d.plan.provenance["drawing"]["pen_pos"] = pen_pos
    try:
        _outputs(d, png, svg_out, source, None)
        save_plan(d.plan, out)
    except OSError as exc:
        raise ArmbridgeError(f"{exc.filename}: cannot write ({exc.strerror})") from None
    _report(d, source, out, png, svg_out)
    if port is not None:  # as `armbridge run` (exit codes, signals, summary)
        from armbridge.executor.command import run_command
        from armbridge.telemetry.recording import default_rrd_path

        rrd = rrd if rrd is not None else default_rrd_path(d.plan.name)
        try:
            run_command(out, port, rrd, rate, json_out, clear, progress, cartesian=cartesian, pen=pen, keys=keys,
                        pen_pos=pen_pos)
        finally:  # completed or not: the figure and the SVG show what was drawn
            if (png is not None or svg_out is not None) and rrd.exists():
                _drawn_outputs(d, png, svg_out, source, rrd)


def _drawn_outputs(d, png: Path | None, svg_out: Path | None, source: str, rrd: Path) -> None:
    """The figure and the SVG again, from the run's recording; a problem is a warning (the run's
    own outcome and exit code stand)."""
    from armbridge.draw.export import drawn_strokes

    try:
        _outputs(d, png, svg_out, source, drawn_strokes(rrd))
    except (ArmbridgeError, OSError) as exc:
        typer.secho(f"warning: the figure or SVG of what was drawn was not written: {exc}", fg="yellow", err=True)


def _outputs(d, png: Path | None, svg_out: Path | None, source: str, trace) -> None:
    """The figure (with the executed trace when there is one) and the SVG (the trace, else the
    plan's pen-down strokes)."""
    if png is not None:
        from armbridge.draw.figure import draw_png

        draw_png(d, png, title=f"armbridge draw: {source}", trace=trace)
    if svg_out is not None:
        from armbridge.draw.export import planned_strokes, write_svg

        strokes = trace if trace is not None else planned_strokes(d.plan)
        write_svg(svg_out, strokes, d.page, d.placement.at, label="drawn" if trace is not None else "planned",
                  source=source)


def _report(d, source: str, out: Path, png: Path | None, svg_out: Path | None) -> None:
    """What was made, a few lines."""
    t = d.tidy
    p = d.placement
    on = f" on {d.page.name} ({d.page.width * 1000:.0f} x {d.page.height * 1000:.0f} mm)" if d.page else ""
    limit = {"reach": ", as large as the arm's safe region allows", "page": ", as large as the page allows"}
    typer.echo(f"{source}: {t.strokes_out} stroke{'s' * (t.strokes_out != 1)} ({t.strokes_in} before merging"
               + (f", {t.dropped} too short dropped" if t.dropped else "") + f"), {d.drawn_length * 1000:.0f} mm "
               f"drawn, size {p.size * 1000:.1f} mm at ({p.at[0]:.4f}, {p.at[1]:.4f}) m{on}"
               + limit.get(p.limited_by, ""))
    typer.echo(f"pen-up travel: {t.travel_before * 1000:.0f} mm before sorting, {t.travel_after * 1000:.0f} mm after"
               + (f" ({t.sort}; greedy alone {t.travel_greedy * 1000:.0f} mm)" if t.sort == "2opt" else f" ({t.sort})")
               + (f"; {d.travel_cuts} pen-up move{'s' * (d.travel_cuts != 1)} cut to stay in the safe region"
                  if d.travel_cuts else ""))
    if d.ik["method"] == "paper":
        k = d.ik
        typer.echo(f"joints: the paper's ANN + FABRIK + CBF ({k['model']}): {k['oriented']} of {k['waypoints']} "
                   f"waypoints at the pen angle, ANN {k['ann_tip_mean_mm']:.2f} mm mean -> {k['tip_max_mm']:.4f} mm "
                   f"max tip error, wrist angle within {k['theta_max_deg']:.2g} deg")
    else:
        typer.echo("joints: the closed-form IK")
    f = d.safety
    typer.echo(f"safety: every waypoint {p.margin * 1000:.1f} mm inside the safe region (radius "
               f"{d.region.radius * 1000:.1f} mm); the CBF filter moved {f.moved} waypoint{'s' * (f.moved != 1)}"
               + (f" (up to {f.max_shift * 1000:.2g} mm)" if f.moved else ""))
    info = d.plan.provenance["drawing"]
    extra = [str(x) for x in (png, svg_out) if x is not None]
    typer.echo(f"wrote {out}: {d.plan.k} waypoints, {d.plan.total_duration:.1f} s at {info['speed']:g} m/s "
               f"(pen up {info['travel_speed']:g} m/s)" + (f"; {', '.join(extra)}" if extra else ""))
