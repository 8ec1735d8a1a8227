"""`armbridge draw` as plotter users expect it (issue 25 part 4): vpype's 2-opt sorting, merging
and filtering; direct pen-up moves at their own speed inside the safe disc; pen settle waits;
pages, margins and rotation; transparent PNGs; the figure framed on the drawing; the drawn
strokes as SVG; option errors as one line."""
from __future__ import annotations

import re
import subprocess
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from typer.testing import CliRunner

from armbridge.cli import build_app
from armbridge.draw import export, layout, page, path, sources
from armbridge.draw.build import build
from armbridge.draw.figure import draw_png, frame
from armbridge.errors import ArmbridgeError
from armbridge.plans.drawing import pen_strips, point_polyline_distance
from armbridge.plans.format import load_plan
from armbridge.robots import get_robot

from cli_procs import ARMBRIDGE

ARM = get_robot("arm3r")
TEXTS = ("MANIT", "RESEARCH", "Hello world")


def _text(t: str, scale: float = 0.02):
    lc = sources.text_lines(t)
    lc.scale(scale)
    return lc


def _key(s: np.ndarray) -> tuple:
    s = s if tuple(s[0]) <= tuple(s[-1]) else s[::-1]
    return tuple(np.round(s, 9).ravel())


# ---------------------------------------------------------------- vpype: sorting, merging, filtering

@pytest.mark.parametrize("text", TEXTS)
def test_two_opt_cuts_pen_up_travel_below_greedy_and_repeats(text):
    lc = _text(text)
    greedy, g = layout.tidy(lc, sort="greedy")
    two, t = layout.tidy(lc, sort="2opt")
    assert t.travel_after < g.travel_after <= g.travel_before  # 2-opt beats greedy on these texts
    assert t.travel_greedy == pytest.approx(g.travel_after)
    # the same strokes, only reordered or reversed
    assert sorted(map(_key, sources.to_strokes(two))) == sorted(map(_key, sources.to_strokes(greedy)))
    again, t2 = layout.tidy(lc, sort="2opt")  # deterministic
    assert [s.tolist() for s in sources.to_strokes(again)] == [s.tolist() for s in sources.to_strokes(two)]
    _, n = layout.tidy(lc, sort="none")
    assert n.travel_after == n.travel_before


def test_merge_joins_ends_within_tolerance_only():
    a = np.array([[0.0, 0.0], [0.01, 0.0]])
    b = np.array([[0.01005, 0.0], [0.02, 0.0]])  # 0.05 mm after a's end
    c = np.array([[0.03, 0.0], [0.02 + 0.0005, 0.0]])  # reversed, its end 0.5 mm from b's
    lc = sources.from_strokes([a, b, c])
    assert len(layout.merge(lc, 1e-4)) == 2  # a+b joined; c too far
    assert len(layout.merge(lc, 1e-3)) == 1  # c joined, flipped
    out, rep = layout.tidy(lc, merge_tolerance=1e-3)
    assert (rep.strokes_in, rep.strokes_out) == (3, 1)


def test_filter_drops_short_strokes_and_says_when_nothing_is_left():
    lc = sources.from_strokes([np.array([[0.0, 0.0], [0.01, 0.0]]), np.array([[0.0, 0.01], [0.0001, 0.01]])])
    out, rep = layout.tidy(lc, min_length=0.0005)
    assert len(out) == 1 and rep.dropped == 1
    with pytest.raises(ArmbridgeError, match="shorter than the 20 mm --min-stroke"):
        layout.tidy(lc, min_length=0.02)


# ---------------------------------------------------------------- pen-up moves, settle

def test_pen_up_moves_are_single_waypoints_at_the_travel_speed():
    d = build(sources.text_lines("MANIT"), ARM, name="m", source="t", speed=0.02, travel_speed=0.1)
    plan, pen = d.plan, d.plan.pen
    up = np.flatnonzero(pen[1:] == 0) + 1  # pen-up moves (waypoint 0 is the approach)
    assert d.travel_cuts == 0
    assert len(up) == len(d.strokes) - 1  # one move between consecutive strokes
    for i in up:
        assert pen[i - 1] == 1 and (i + 1 == plan.k or pen[i + 1] == 1)
        swept = path.sweep(ARM, plan.q[i - 1], plan.q[i])
        length = float(np.sum(np.hypot(*np.diff(swept, axis=0).T)))
        joint = float(np.max(np.abs(plan.q[i] - plan.q[i - 1]) / (path.V_HEADROOM * ARM.v_max)))
        assert plan.durations[i] == pytest.approx(max(length / 0.1, joint, 1e-3))
        # the swept path stays inside the safe disc less the margin
        assert np.linalg.norm(swept - d.region.center, axis=1).max() <= d.region.radius - d.placement.margin + 1e-9
    down = np.flatnonzero(pen[1:] == 1) + 1
    seg = np.hypot(*np.diff(d.xy, axis=0).T)
    assert np.all(plan.durations[down] >= seg[down - 1] / 0.02 - 1e-12)


def test_a_pen_up_move_leaving_the_disc_is_cut_until_it_stays_inside():
    c = np.array([0.076, 0.19])  # the safe disc's centre
    p0, p1 = c + [0.0, -0.08], c + [0.0, 0.08]
    q = path.solve_path(ARM, np.c_[np.vstack([p0, p1]), [0.0, 0.0]], (ARM.q_min + ARM.q_max) / 2)
    swept = path.sweep(ARM, q[0], q[1])
    mid = (p0 + p1) / 2
    bow = swept[:, 0] - mid[0]
    side = np.sign(bow[np.argmax(np.abs(bow))])
    center = mid - [side * 1.0, 0.0]  # a disc through both ends with the bow on its outside
    radius = float(np.linalg.norm(p0 - center)) + 1e-9
    assert np.linalg.norm(swept - center, axis=1).max() > radius + 5e-3  # it leaves by millimetres
    q2, pen2, cuts = path.split_travel(ARM, q, np.array([0, 0]), center, radius)
    assert cuts == 1 and len(q2) > 2 and (pen2 == 0).all()
    np.testing.assert_allclose(q2[[0, -1]], q[[0, -1]])
    for a, b in zip(q2[:-1], q2[1:]):
        assert np.linalg.norm(path.sweep(ARM, a, b) - center, axis=1).max() <= radius + 1e-9
    q3, _, cuts3 = path.split_travel(ARM, q2, pen2, center, radius)  # cutting again changes nothing
    assert cuts3 == 0 and np.array_equal(q3, q2)


def test_pen_settle_adds_a_still_wait_after_every_pen_change():
    base = build(sources.text_lines("IO"), ARM, name="io", source="t", size=0.04)
    d = build(sources.text_lines("IO"), ARM, name="io", source="t", size=0.04, pen_settle=(0.25, 0.1))
    changes = int(np.sum(np.diff(base.plan.pen) != 0))
    assert d.plan.k == base.plan.k + changes
    still = np.flatnonzero(np.all(np.diff(d.plan.q, axis=0) == 0, axis=1)) + 1
    assert len(still) == changes
    for i in still:
        assert d.plan.pen[i] != d.plan.pen[i - 1]  # the wait is the first move of the new pen state
        assert d.plan.durations[i] == pytest.approx(0.25 if d.plan.pen[i] == 1 else 0.1)
    assert d.plan.total_duration == pytest.approx(base.plan.total_duration + 0.25 * 2 + 0.1 * 1)
    assert path.check_settle("300") == (0.3, 0.3) and path.check_settle("300,50") == (0.3, 0.05)


# ---------------------------------------------------------------- pages

def test_page_sizes_orientation_and_margins():
    a4 = page.parse_page("A4")
    assert (round(a4.width * 1000), round(a4.height * 1000)) == (210, 297)
    a4l = page.parse_page("a4", landscape=True, margin_mm=12)
    assert (round(a4l.width * 1000), round(a4l.height * 1000), a4l.margin) == (297, 210, 0.012)
    letter = page.parse_page("letter")
    assert letter.width == pytest.approx(0.2159) and letter.height == pytest.approx(0.2794)
    wxh = page.parse_page("150x100")
    assert (wxh.width, wxh.height) == pytest.approx((0.150, 0.100))  # as given: W along x
    assert page.parse_page("15x10cm").width == pytest.approx(0.150)
    assert page.parse_page("150x100", margin_mm=10).printable == pytest.approx((0.130, 0.080))
    xy = a4.to_page([[0.0, 0.0]], (0.105, 0.1485))  # the arm-frame origin is the page's bottom-left
    np.testing.assert_allclose(xy, [[0.0, 297.0]], atol=1e-9)


def test_a_drawing_on_a_page_lies_inside_its_printable_area_and_the_reach():
    sheet = page.parse_page("60x40", margin_mm=5)
    d = build(sources.text_lines("Plot"), ARM, name="p", source="t", page=sheet)
    pts = np.vstack(d.strokes)
    x0, y0 = np.asarray(d.placement.at) - np.asarray(sheet.printable) / 2
    x1, y1 = np.asarray(d.placement.at) + np.asarray(sheet.printable) / 2
    assert pts[:, 0].min() >= x0 - 1e-9 and pts[:, 0].max() <= x1 + 1e-9
    assert pts[:, 1].min() >= y0 - 1e-9 and pts[:, 1].max() <= y1 + 1e-9
    assert d.placement.limited_by == "page"
    assert np.isclose(np.ptp(pts[:, 0]), 0.050, atol=2e-4) or np.isclose(np.ptp(pts[:, 1]), 0.030, atol=2e-4)
    # an A4 page is larger than the arm's safe disc: the disc sets the size, and it still holds
    big = build(sources.text_lines("Plot"), ARM, name="p", source="t", page=page.parse_page("A4"))
    assert big.placement.limited_by == "reach"
    tips = big.plan.ee_path()
    assert np.linalg.norm(tips - big.region.center, axis=1).max() <= big.region.radius - big.placement.margin + 1e-7
    assert big.plan.provenance["drawing"]["page"]["width_mm"] == 210.0


def test_rotation_turns_the_drawing():
    flat = np.vstack(build(sources.text_lines("LONG"), ARM, name="r", source="t", size=0.08).strokes)
    turned = np.vstack(build(sources.text_lines("LONG"), ARM, name="r", source="t", size=0.08, rotate=90).strokes)
    assert np.ptp(flat[:, 0]) > 2 * np.ptp(flat[:, 1])
    assert np.ptp(turned[:, 1]) > 2 * np.ptp(turned[:, 0])
    assert np.ptp(turned[:, 1]) == pytest.approx(0.08, abs=1e-6)


def test_a_drawing_larger_than_the_page_is_refused():
    with pytest.raises(ArmbridgeError, match=r"does not fit the page's printable area \(40.0 mm x 20.0 mm\)"):
        build(sources.text_lines("Plot"), ARM, name="p", source="t", size=0.05,
              page=page.parse_page("50x30", margin_mm=5))


# ---------------------------------------------------------------- images, figure

def test_transparent_png_is_traced_by_its_alpha(tmp_path):
    from skimage import io as skio

    img = np.zeros((60, 60, 4), np.uint8)
    img[15:45, 15:45, 3] = 255  # a black square on a transparent ground
    skio.imsave(tmp_path / "black.png", img, check_contrast=False)
    img[..., :3] = 255  # a white square on a transparent ground: flat over white, traced by its alpha
    skio.imsave(tmp_path / "white.png", img, check_contrast=False)
    for name in ("black.png", "white.png"):
        (s,) = sources.to_strokes(sources.image_file(tmp_path / name))
        assert np.ptp(s[:, 0]) == pytest.approx(30, abs=1.5) and np.ptp(s[:, 1]) == pytest.approx(30, abs=1.5)
    with pytest.raises(ArmbridgeError, match="one flat colour"):
        sources.image_lines(np.zeros((20, 20, 4), np.uint8), "clear")


def test_the_figure_is_framed_on_the_drawing(tmp_path):
    d = build(sources.text_lines("Hi"), ARM, name="h", source="t", size=0.023)
    x0, x1, y0, y1 = frame(d)
    pts = d.xy[1:]
    assert x0 < pts[:, 0].min() and x1 > pts[:, 0].max() and y0 < pts[:, 1].min() and y1 > pts[:, 1].max()
    assert max(x1 - x0, y1 - y0) < 0.023 * 1.5  # not the arm's 0.76 m reach
    trace = [pts[:10] + 0.0005]
    out = draw_png(d, tmp_path / "h.png", title="t", trace=trace)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ---------------------------------------------------------------- SVG export, a run

def _svg_strokes(svg: str) -> tuple[list[np.ndarray], tuple[float, float]]:
    root = ET.fromstring(svg)
    vb = [float(x) for x in root.get("viewBox").split()]
    lines = []
    for el in root.iter():
        if el.tag.endswith("polyline") or el.tag.endswith("polygon"):  # vpype writes a closed stroke as a polygon
            pts = np.array([[float(v) for v in p.split(",")] for p in el.get("points").split()])
            lines.append(np.vstack([pts, pts[:1]]) if el.tag.endswith("polygon") else pts)
        elif el.tag.endswith("line") and el.get("x1") is not None:
            lines.append(np.array([[float(el.get("x1")), float(el.get("y1"))], [float(el.get("x2")), float(el.get("y2"))]]))
    mm = 25.4 / 96.0
    return [s * mm for s in lines], (vb[2] * mm, vb[3] * mm)


def test_planned_svg_is_at_the_page_scale():
    sheet = page.parse_page("A5", margin_mm=10)
    d = build(sources.text_lines("IO"), ARM, name="io", source="t", size=0.04, page=sheet)
    strokes, (w, h) = _svg_strokes(export.svg_text(export.planned_strokes(d.plan), sheet, d.placement.at))
    assert (w, h) == pytest.approx((148.0, 210.0), abs=0.01)
    back = [sheet.to_page(s, d.placement.at) for s in pen_strips(d.plan.ee_path(), d.plan.pen)]
    assert len(strokes) == len(back)
    for a, b in zip(strokes, back):
        np.testing.assert_allclose(a, b, atol=1e-3)  # mm


def test_svg_of_a_run_holds_the_drawn_strokes_close_to_the_plan(tmp_path):
    out, svg, png, js = tmp_path / "io.json", tmp_path / "io.svg", tmp_path / "io.png", tmp_path / "s.json"
    r = CliRunner().invoke(build_app(), ["draw", "IO", "--size", "0.03", "--speed", "0.03", "--page", "60x40",
                                         "--margin", "5", "--out", str(out), "--svg-out", str(svg), "--png", str(png),
                                         "--port", "emu:esp32?speed=0", "--rrd", str(tmp_path / "r.rrd"),
                                         "--json", str(js), "--no-progress"])
    assert r.exit_code == 0, r.output
    import json

    summary = json.loads(js.read_text())["drawing"]
    assert summary["safe_outside"] == 0  # the executed pen, rapids included, kept to the safe disc
    plan = load_plan(out)
    sheet, at = page.parse_page("60x40", margin_mm=5), plan.provenance["drawing"]["at"]
    strokes, (w, h) = _svg_strokes(svg.read_text())
    assert (w, h) == pytest.approx((60.0, 40.0), abs=0.01)
    assert 'inkscape:label="drawn"' in svg.read_text()
    target = [sheet.to_page(s, at) for s in pen_strips(plan.ee_path(), plan.pen)]
    assert len(strokes) >= len(target) == 2  # I and O (a dropout may split a stroke, never merge two)
    pts = np.vstack(strokes)
    assert 50 < len(pts) <= summary["trace_points"]  # the trace, less single-sample strips
    d = point_polyline_distance(pts, target)  # mm, on the page
    assert d.max() <= summary["trace_max_mm"] + 1e-3 and d.max() < 3.0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ---------------------------------------------------------------- option errors

@pytest.mark.parametrize("args,message", [
    (["--travel-speed", "2"], r"--travel-speed 2 m/s is outside \[0.001, 0.5\] m/s"),
    (["--speed", "0"], r"--speed 0 m/s is outside \[0.001, 0.5\] m/s"),
    (["--page", "B9"], r"--page 'B9': expected A4, A5, letter"),
    (["--page", "A5", "--margin", "80"], r"--margin 80 mm: expected 0 <= MM < 74"),
    (["--landscape"], r"--landscape and --margin need --page"),
    (["--margin", "5"], r"--landscape and --margin need --page"),
    (["--rotate", "720"], r"--rotate 720: expected degrees in \[-360, 360\]"),
    (["--sort", "fast"], r"--sort 'fast': expected one of 2opt, greedy, none"),
    (["--merge-tolerance", "9"], r"--merge-tolerance 9 mm is outside \[0, 5\] mm"),
    (["--min-stroke", "-1"], r"--min-stroke -1 mm is outside \[0, 50\] mm"),
    (["--pen-settle", "9000"], r"--pen-settle '9000': expected MS or DOWN,UP in ms, each in \[0, 5000\]"),
])
def test_bad_options_are_one_line_and_write_nothing(tmp_path, args, message):
    out = tmp_path / "p.json"
    r = CliRunner().invoke(build_app(), ["draw", "IO", "--out", str(out), *args])
    assert isinstance(r.exception, ArmbridgeError), r.output
    assert re.search(message, str(r.exception)) and "\n" not in str(r.exception)
    assert not out.exists()


def test_a_bad_option_exits_2_with_one_line_and_no_traceback(tmp_path):
    r = subprocess.run([ARMBRIDGE, "draw", "IO", "--out", str(tmp_path / "p.json"), "--travel-speed", "9"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "Traceback" not in r.stderr
    assert "--travel-speed 9 m/s is outside" in r.stderr


# ---------------------------------------------------------------- the keyboard side of pause / resume

def test_pause_keys_toggle_hold_on_a_terminal_and_do_nothing_elsewhere():
    import os
    import threading

    from armbridge.draw.keys import PauseKeys, is_toggle

    assert is_toggle(" ") and is_toggle("p") and is_toggle("P") and not is_toggle("x")
    calls: list[bool] = []
    got = threading.Event()

    def on_hold(held: bool) -> None:
        calls.append(held)
        if len(calls) == 2:
            got.set()

    r, w = os.pipe()  # not a terminal: inactive
    with os.fdopen(r) as pipe, PauseKeys(on_hold, pipe) as keys:
        assert not keys.active
    os.close(w)
    master, slave = os.openpty()
    with os.fdopen(slave) as term:
        with PauseKeys(on_hold, term) as keys:
            assert keys.active
            os.write(master, b"x p")  # x ignored; space holds, p resumes
            assert got.wait(10.0)
        assert not keys.active
    os.close(master)
    assert calls == [True, False]
