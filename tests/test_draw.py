"""armbridge draw: sources to strokes, the safe region, placement, vpype tidying, the plan, the CLI."""
from __future__ import annotations

import json
import re
import subprocess

import numpy as np
import pytest
import vpype as vp
from typer.testing import CliRunner

from armbridge.cli import build_app
from armbridge.draw import layout, path, sources
from armbridge.draw.build import build
from armbridge.draw.samples import SAMPLES, sample_lines
from armbridge.errors import ArmbridgeError
from armbridge.ik import region
from armbridge.ik.analytic3r import ik
from armbridge.plans.format import load_plan, loads_plan, make_plan, plan_to_dict, save_plan
from armbridge.robots import get_robot

from cli_procs import ARMBRIDGE

ARM = get_robot("arm3r")


def _pts(lc: vp.LineCollection) -> np.ndarray:
    return np.concatenate(sources.to_strokes(lc))


# ---------------------------------------------------------------------------
# sources


def test_text_strokes_are_the_fonts_glyphs():
    lc = sources.text_lines("LI")
    # futural's L is two strokes and its I one; vpype's glyph data, flipped to y up
    assert len(lc) == 3
    vertical = [s for s in sources.to_strokes(lc) if np.ptp(s[:, 0]) < 1e-9]
    assert len(vertical) == 2  # the L's stem and the I
    assert all(np.ptp(s[:, 1]) > 0.5 for s in vertical)  # cap height in font heights
    glyph_i = vp.text_line("I", "futural", size=1.0)
    assert np.isclose(np.ptp(_pts(glyph_i)[:, 1]), np.ptp(vertical[1][:, 1]))
    two = sources.text_lines("L\nL")
    assert len(two) == 4 and np.isclose(np.ptp(_pts(two)[:, 1]) - np.ptp(_pts(sources.text_lines("L"))[:, 1]),
                                        sources.LINE_SPACING)


@pytest.mark.parametrize("text, msg", [("", "the text to draw is empty"), ("  \n ", "the text to draw is empty"),
                                       ("Caf\u00e9", "font futural has no glyph for '\u00e9' (U+00E9)")])
def test_text_bad(text, msg):
    with pytest.raises(ArmbridgeError, match=re.escape(msg)):
        sources.text_lines(text)


def test_svg_strokes(tmp_path):
    f = tmp_path / "d.svg"
    f.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="100" height="100">'
                 '<path d="M 10 10 L 90 10 L 90 50"/><rect x="20" y="60" width="30" height="20"/></svg>')
    strokes = sources.to_strokes(sources.svg_file(f))
    assert len(strokes) == 2
    path_ = next(s for s in strokes if len(s) == 3)
    np.testing.assert_allclose(path_, [[10, -10], [90, -10], [90, -50]])  # y flipped up
    rect = next(s for s in strokes if s is not path_)
    np.testing.assert_allclose(np.ptp(rect, axis=0), [30, 20])
    np.testing.assert_allclose(rect[0], rect[-1])  # closed


@pytest.mark.parametrize("content, msg", [("this is not xml", "cannot read the SVG"),
                                          ('<svg xmlns="http://www.w3.org/2000/svg"></svg>', "no paths or shapes")])
def test_svg_bad(tmp_path, content, msg):
    f = tmp_path / "bad.svg"
    f.write_text(content)
    with pytest.raises(ArmbridgeError, match=f"^{f}: .*{msg}"):
        sources.svg_file(f)
    with pytest.raises(ArmbridgeError, match="nope.svg: cannot read the SVG file"):
        sources.svg_file(tmp_path / "nope.svg")


def test_image_contours_trace_a_square(tmp_path):
    from skimage import io as skio

    img = np.full((60, 80), 255, dtype=np.uint8)
    img[10:40, 20:60] = 0  # a dark 40 x 30 px rectangle
    f = tmp_path / "sq.png"
    skio.imsave(f, img)
    strokes = sources.to_strokes(sources.image_file(f))
    assert len(strokes) == 1
    s = strokes[0]
    np.testing.assert_allclose(s[0], s[-1])
    # the outline is on the ink's edge (pixel centres 20..59, rows 10..39) within a pixel, y up
    np.testing.assert_allclose(s.min(axis=0), [19.5, -39.5], atol=1.0)
    np.testing.assert_allclose(s.max(axis=0), [59.5, -9.5], atol=1.0)
    assert len(s) < 30  # simplified: a rectangle, not a pixel staircase


def test_image_bad(tmp_path):
    f = tmp_path / "bad.png"
    f.write_bytes(b"not a png at all")
    with pytest.raises(ArmbridgeError, match=f"^{f}: cannot read the image"):
        sources.image_file(f)
    with pytest.raises(ArmbridgeError, match="one flat colour"):
        sources.image_lines(np.ones((10, 10)), "blank")


def test_csv_blank_lines_and_pen_column():
    lc = sources.csv_lines("x,y\n0,0\n1,0\n\n2,0\n2,1 # comment\n")
    assert [len(s) for s in sources.to_strokes(lc)] == [2, 2]
    lc = sources.csv_lines("x,y,pen\n0,0,0\n1,0,1\n1,1,1\n5,5,0\n6,5,1\n")
    strokes = sources.to_strokes(lc)
    assert [len(s) for s in strokes] == [3, 2]
    np.testing.assert_allclose(strokes[1], [[5, 5], [6, 5]])
    assert len(sources.csv_lines("0,0\n3,4\n")) == 1  # no header: x,y


@pytest.mark.parametrize("text, msg", [
    ("x,y\n0,0\n1,abc\n", "f.csv: line 3, column 2 (y): 'abc' is not a finite number"),
    ("x,y,pen\n0,0,0\n1,1,2\n", "f.csv: line 3, column 3 (pen): '2' is not 0 (up) or 1 (down)"),
    ("0,0\n1,2,3\n", "f.csv: line 2: 3 values, expected 2 (x, y)"),
    ("x,y\n0,0\n", "f.csv: no stroke of two or more points to draw"),
    ("0,0\nnan,1\n", "f.csv: line 2, column 1 (x): 'nan' is not a finite number"),
])
def test_csv_bad(text, msg):
    with pytest.raises(ArmbridgeError) as e:
        sources.csv_lines(text, "f.csv")
    assert str(e.value) == msg


@pytest.mark.parametrize("name", sources.SHAPES)
def test_shapes(name):
    s = sources.to_strokes(sources.shape_lines(name))
    assert len(s) == 1
    np.testing.assert_allclose(s[0][0], s[0][-1])
    np.testing.assert_allclose(np.hypot(*s[0].T).max(), 1.0)
    corners = {"triangle": 3, "square": 4, "pentagon": 5, "hexagon": 6, "star": 10}
    if name in corners:
        assert len(s[0]) == corners[name] + 1
    with pytest.raises(ArmbridgeError, match='unknown shape "blob"'):
        sources.shape_lines("blob")


# ---------------------------------------------------------------------------
# the safe region


def test_safe_region_is_reachable_with_margin():
    reg = region.safe_region(ARM)
    center, radius = np.asarray(reg.center), reg.radius
    phi = region.pen_angle(ARM)
    assert 0.08 < radius < ARM.reach / 2
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 2 * np.pi, 5000)
    r = radius * np.sqrt(rng.uniform(0, 1, 5000))
    pts = center + np.c_[r * np.cos(a), r * np.sin(a)]
    edge = center + radius * np.c_[np.cos(a), np.sin(a)]
    for p in (pts, edge):
        q, ok = ik(ARM, np.c_[p, np.full(len(p), phi)])
        assert ok.all()
        assert np.all(q >= ARM.q_min + region.JOINT_MARGIN - 1e-12)
        assert np.all(q <= ARM.q_max - region.JOINT_MARGIN + 1e-12)
    # and it is not much smaller than it could be: 2 grid steps out, some point fails
    h = 2 * ARM.reach / region.GRID_STEPS
    out = center + (radius + 3 * h) * np.c_[np.cos(a), np.sin(a)]
    assert not region.reachable(ARM, out, phi).all()


def test_safe_region_refuses_other_robots():
    with pytest.raises(ArmbridgeError, match="planar 3-joint arm"):
        region.safe_region(get_robot("masr5"))


# ---------------------------------------------------------------------------
# placement


def test_place_fits_and_sizes():
    center, radius = np.array([0.1, 0.2]), 0.1
    lc = sources.shape_lines("square")
    placed, where = layout.place(lc, center, radius)
    pts = _pts(placed)
    assert np.isclose(np.linalg.norm(pts - center, axis=1).max(), radius)  # fills the disk
    assert np.isclose(where.size, np.sqrt(2) * radius) and np.isclose(where.largest, where.size)
    placed, where = layout.place(lc, center, radius, size=0.05, at=(0.12, 0.2))
    pts = _pts(placed)
    np.testing.assert_allclose((pts.min(axis=0) + pts.max(axis=0)) / 2, [0.12, 0.2])
    np.testing.assert_allclose(np.ptp(pts, axis=0), [0.05, 0.05])
    # off centre the largest fit shrinks: the far corner touches the disk
    _, where = layout.place(lc, center, radius, at=(0.15, 0.2))
    assert where.size < np.sqrt(2) * radius
    assert np.isclose(np.hypot(0.05 + where.size / 2, where.size / 2), radius)


def test_place_refuses_with_the_overflow():
    lc = sources.shape_lines("square")  # 1.414 wide: 1 unit of circumradius
    with pytest.raises(ArmbridgeError) as e:
        layout.place(lc, (0.0, 0.0), 0.1, size=0.2)
    # half-diagonal 0.1414 m against a 0.1 m disk: 41.4 mm over; 0.1414 m fits
    assert "overflows the safe region (centre (0.0000, 0.0000) m, radius 0.1000 m) by 41.4 mm" in str(e.value)
    assert "the largest size that fits at (0.0000, 0.0000) m is 0.1414 m" in str(e.value)
    with pytest.raises(ArmbridgeError, match=r"--at \(0.2000, 0.0000\) m is outside the safe region .* 100.0 mm"):
        layout.place(lc, (0.0, 0.0), 0.1, at=(0.2, 0.0))


# ---------------------------------------------------------------------------
# vpype tidying


def _random_segments(seed: int, n: int = 40) -> vp.LineCollection:
    rng = np.random.default_rng(seed)
    return sources.from_strokes([rng.uniform(0, 1, (rng.integers(2, 5), 2)) for _ in range(n)])


@pytest.mark.parametrize("seed", range(5))
def test_sort_never_loses_a_stroke_nor_adds_travel(seed):
    lc = _random_segments(seed)
    out = layout.sort_lines(lc)
    assert len(out) == len(lc)
    key = lambda s: tuple(np.round(s if tuple(s[0]) <= tuple(s[-1]) else s[::-1], 12).ravel())  # noqa: E731
    assert sorted(map(key, sources.to_strokes(out))) == sorted(map(key, sources.to_strokes(lc)))
    assert layout.pen_up_travel(out) <= layout.pen_up_travel(lc)
    assert layout.pen_up_travel(out) < 0.7 * layout.pen_up_travel(lc)  # random order: sorting helps a lot


def test_tidy_merges_touching_strokes_and_reports_travel():
    lc = sources.from_strokes([np.array([[0, 0], [1, 0]]), np.array([[5, 0], [6, 0]]),
                               np.array([[1, 0], [1, 1]]), np.array([[6, 0], [6, 1]])])
    out, rep = layout.tidy(lc)
    assert (rep.strokes_in, rep.strokes_out) == (4, 2)
    assert rep.travel_after <= rep.travel_before
    assert np.isclose(out.length(), 4.0)  # nothing drawn is lost


# ---------------------------------------------------------------------------
# the plan


def test_pen_path_flags_and_density():
    strokes = [np.array([[0.0, 0.0], [0.01, 0.0]]), np.array([[0.02, 0.0], [0.02, 0.01]])]
    xy, pen = path.pen_path(strokes, step=0.002, direct=False)
    assert pen[0] == 0 and len(xy) == len(pen)
    assert np.hypot(*np.diff(xy, axis=0).T).max() <= 0.002 + 1e-12
    # pen down along both strokes, up between: 5 + 5 down, 5 up moves (plus the approach)
    assert (pen == 1).sum() == 10 and (pen == 0).sum() == 6
    down = xy[1:][pen[1:] == 1]
    assert np.all((np.isclose(down[:, 1], 0) & (down[:, 0] <= 0.01 + 1e-12)) | np.isclose(down[:, 0], 0.02))
    # the default: one pen-up move between the strokes, straight to the next start
    xy, pen = path.pen_path(strokes, step=0.002)
    assert (pen == 1).sum() == 10 and (pen == 0).sum() == 2
    up = np.flatnonzero(pen[1:] == 0) + 1
    np.testing.assert_allclose(xy[up], [[0.02, 0.0]])


@pytest.mark.parametrize("name", list(SAMPLES))
def test_every_sample_builds_a_valid_plan(name):
    d = build(sample_lines(name), ARM, name=name, source=f"sample {name}", speed=0.05)
    plan = d.plan
    assert plan.pen is not None and plan.pen.shape == (plan.k,)
    # the plan's tip follows the pen path (the IK's own accuracy), inside the safe region
    tip = plan.ee_path()
    np.testing.assert_allclose(tip, d.xy, atol=1e-7)
    assert np.linalg.norm(tip - d.region.center, axis=1).max() <= d.region.radius + 1e-9
    # each drawing move takes its length at the pen speed unless a joint limits it
    seg = np.hypot(*np.diff(d.xy, axis=0).T)
    assert np.all(plan.durations[1:] >= seg / 0.05 - 1e-12)
    info = plan.provenance["drawing"]
    assert info["pen_up_travel_after_sort"] <= info["pen_up_travel_before_sort"]
    if SAMPLES[name].source == "Text":
        assert info["strokes"] > 1


def test_joint_space_moves_keep_the_pen_on_the_stroke():
    """Between waypoints the arm moves linearly in joint space: at STEP the tip stays within 20 um
    (pen down; a pen-up move is one direct move and bows, tests/test_draw_plotter.py)."""
    d = build(sample_lines("text-robotics"), ARM, name="r", source="s")
    q, t = d.plan.q, np.linspace(0, 1, 21)[:, None, None]
    tip = ARM.ee_point(q[:-1][None] * (1 - t) + q[1:][None] * t)
    a, ab = d.xy[:-1], np.diff(d.xy, axis=0)
    s = np.clip(np.sum((tip - a) * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), 1e-18), 0, 1)
    dev = np.linalg.norm(tip - (a + s[..., None] * ab), axis=-1)
    assert dev[:, d.pen[1:] == 1].max() < 2e-5


def test_plan_pen_flags_round_trip_and_old_plans_load(tmp_path):
    q = np.zeros((3, 3)) + [1.0, -1.0, 0.0]
    plan = make_plan(ARM, q, 0.5, {"name": "p"}, pen=[0, 1, 1])
    f = save_plan(plan, tmp_path / "p.json")
    back = load_plan(f)
    assert back.pen.tolist() == [0, 1, 1]
    doc = plan_to_dict(back)
    assert [w["pen"] for w in doc["waypoints"]] == [0, 1, 1]
    for w in doc["waypoints"]:
        del w["pen"]
    assert loads_plan(json.dumps(doc)).pen is None  # a plan without pen flags loads as before
    doc["waypoints"][1]["pen"] = 1
    with pytest.raises(ArmbridgeError, match="waypoint 1: pen is given on some waypoints only"):
        loads_plan(json.dumps(doc))
    doc["waypoints"][0]["pen"] = "down"
    with pytest.raises(ArmbridgeError, match='waypoint 0, pen must be 0 \\(up\\) or 1 \\(down\\), got the string "down"'):
        loads_plan(json.dumps(doc))


# ---------------------------------------------------------------------------
# the command


def test_cli_end_to_end_writes_plan_and_png(tmp_path):
    out, png = tmp_path / "robotics.json", tmp_path / "robotics.png"
    r = subprocess.run([ARMBRIDGE, "draw", "ROBOTICS", "--out", str(out), "--png", str(png), "--size", "0.15",
                        "--speed", "0.05"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    plan = load_plan(out)
    assert plan.robot.name == "arm3r" and set(plan.pen.tolist()) == {0, 1}
    assert np.isclose(plan.provenance["drawing"]["size"], 0.15)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert "pen-up travel:" in r.stdout and "before sorting" in r.stdout
    assert f"wrote {out}: {plan.k} waypoints" in r.stdout
    r = CliRunner().invoke(build_app(), ["draw", "A\\nB", "--out", str(tmp_path / "ab.json")])
    assert r.exit_code == 0, r.output
    ab = load_plan(tmp_path / "ab.json").ee_path()
    assert np.ptp(ab[:, 1]) > 1.5 * np.ptp(ab[:, 0])  # two lines: B under A, taller than wide


def test_cli_list_samples():
    r = CliRunner().invoke(build_app(), ["draw", "--list-samples"])
    assert r.exit_code == 0
    assert all(name in r.output for name in SAMPLES) and "3 LINK" in r.output


def _bad_inputs(tmp_path):
    csv = tmp_path / "bad.csv"
    csv.write_text("x,y\n0,0\n0.1,zero\n")
    img = tmp_path / "bad.png"
    img.write_bytes(b"\x89PNG garbage")
    svg = tmp_path / "bad.svg"
    svg.write_text("<svg")
    return [
        ([""], "the text to draw is empty"),
        (["na\u00efve"], "font futural has no glyph for '\u00ef'"),
        (["--image", str(img)], f"{img}: cannot read the image"),
        (["--svg", str(svg)], f"{svg}: cannot read the SVG"),
        (["--csv", str(csv)], f"{csv}: line 3, column 2 (y): 'zero' is not a finite number"),
        (["--shape", "square", "--size", "0.5"], "overflows the safe region"),
        (["--shape", "square", "--at", "0.3,0"], "is outside the safe region"),
        (["--shape", "square", "--speed", "5"], "--speed 5 m/s is outside"),
        (["--shape", "square", "--at", "x"], "--at 'x': expected X,Y in metres"),
        (["--sample", "nope"], 'unknown sample "nope"'),
        (["ABC", "--shape", "star"], "give exactly one thing to draw"),
    ]


def test_cli_bad_inputs_write_nothing(tmp_path):
    for args, msg in _bad_inputs(tmp_path):
        out, png = tmp_path / "out.json", tmp_path / "out.png"
        r = CliRunner().invoke(build_app(), ["draw", *args, "--out", str(out), "--png", str(png)])
        assert isinstance(r.exception, ArmbridgeError), (args, r.output, r.exception)
        assert msg in str(r.exception), (args, str(r.exception))
        assert "\n" not in str(r.exception)
        assert not out.exists() and not png.exists()


def test_cli_bad_input_is_one_line_exit_2(tmp_path):
    csv = tmp_path / "bad.csv"
    csv.write_text("x,y\n0,0\n0.1,zero\n")
    r = subprocess.run([ARMBRIDGE, "draw", "--csv", str(csv), "--out", str(tmp_path / "o.json")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr == f"error: {csv}: line 3, column 2 (y): 'zero' is not a finite number\n"
    assert not (tmp_path / "o.json").exists()
