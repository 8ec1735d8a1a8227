"""The planning figures (planning.figure, bench.plots): what a reader of the PNG must be able to see.

Real matplotlib (Agg) and shapely, real E1-E3 environments; the figures are
checked through their artists (label positions, legend texts, z-order,
colours) and the written PNGs read back with matplotlib.image.imread.
"""
from __future__ import annotations

import colorsys

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.colors import to_rgb  # noqa: E402
from shapely.geometry import Point, Polygon  # noqa: E402

from armbridge.bench import masr_plan  # noqa: E402
from armbridge.bench.plots import family, fig5_figure, fig7_figure  # noqa: E402
from armbridge.errors import ArmbridgeError  # noqa: E402
from armbridge.planning import figure  # noqa: E402

from armbridge.planning.masr.environment import fixed_environment  # noqa: E402


def _png(path):
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 300 and img.shape[1] > 300 and img.shape[2] in (3, 4)
    return img


def _path(env):
    """start -> goal_q: one action of the motion convention (drawing needs no collision-free path)."""
    return np.stack([env.start, env.goal_q])


def test_label_point_lies_inside_every_obstacle_where_the_vertex_mean_may_not():
    pocket = fixed_environment("E3").obstacles[0]  # the U-shaped pocket around E3's goal
    assert not Polygon(pocket).contains(Point(np.mean(pocket, axis=0)))  # the old label spot: free space
    for name in ("E1", "E2", "E3"):
        for p in fixed_environment(name).obstacles:
            poly = Polygon(p)
            q = figure.label_point(p)
            assert poly.contains(Point(q)), (name, q)
            # the pole of inaccessibility: at least as far from the edges as the centroid when that is inside
            c = poly.centroid
            if poly.contains(c):
                assert poly.exterior.distance(Point(q)) >= poly.exterior.distance(c) - 1e-6


@pytest.mark.parametrize("name", ["E1", "E2", "E3"])
def test_masr_figure_labels_legend_and_goal_on_top(tmp_path, name):
    env = fixed_environment(name)
    pf = figure.masr_figure(env, _path(env))
    texts = [t for t in pf.ax.texts]
    assert [t.get_text() for t in texts] == [str(i) for i in range(len(env.obstacles))]
    for t, p in zip(texts, env.obstacles):
        assert Polygon(p).contains(Point(t.get_position())), (name, t.get_text())
        assert to_rgb(t.get_color()) == (0.0, 0.0, 0.0) and t.get_path_effects()  # dark text, light halo
    out = figure.finish(pf, tmp_path / f"{name}.png")
    _png(out)
    legend = [t.get_text() for t in pf.key.get_legend().get_texts()]
    for want in ("start configuration", "arm after each step", "final configuration", "goal (e_p = 8 mm",
                 "reach (0.80 m)", "MA path", "MA at waypoints", "obstacle", "obstacle margin (15 mm)"):
        assert any(s.startswith(want) for s in legend), (want, legend)
    # the legend is in its own panel, not on the data
    assert pf.ax.get_legend() is None and not pf.key.axison
    # the goal outline is drawn above the MA markers, and the markers are hollow
    goal = [p for p in pf.ax.patches if str(p.get_label()).startswith("goal")][0]
    ma = [ln for ln in pf.ax.lines if ln.get_label() == "MA at waypoints"][0]
    assert goal.get_zorder() > ma.get_zorder()
    assert to_rgb(ma.get_markerfacecolor()) == (1.0, 1.0, 1.0)
    # the detail panel frames the goal
    gx, gy = env.goal_pose[:2]
    x0, x1 = pf.detail.get_xlim()
    y0, y1 = pf.detail.get_ylim()
    assert x0 < gx - env.e_p and gx + env.e_p < x1 and y0 < gy - env.e_p and gy + env.e_p < y1
    assert x1 - x0 < 0.2


def test_ma_trace_is_the_ma_driving_along_the_links():
    env = fixed_environment("E2")
    arm = env.arm
    mid = 0.5 * (env.start + env.goal_q)
    mid[-1] = 0.9 * arm.total_length
    path = np.stack([env.start, mid, env.goal_q])
    tr = figure.ma_trace(arm, path, step=0.002)
    assert np.allclose(tr[0], arm.ma_point(path[0])) and np.allclose(tr[-1], arm.ma_point(path[-1]))
    # every waypoint is on the trace, and the trace never jumps (the old dashed waypoint line did)
    for q in path:
        assert np.min(np.linalg.norm(tr - arm.ma_point(q), axis=1)) < 1e-9
    seg = np.linalg.norm(np.diff(tr, axis=0), axis=1)
    assert seg.max() <= 0.002 + 1e-9
    # its length is the distance the MA drives (D_a of every action), up to the chords across joints
    travel = float(np.sum(arm.ma_travel(path[:-1], path[1:])))
    assert seg.sum() == pytest.approx(travel, rel=1e-3)
    # and every point lies on the arm as it stands at that moment: on one of the step shapes' links
    shapes = np.concatenate([arm.joint_points(path[:1]), figure.step_shapes(arm, path),
                             arm.joint_points(path[-1:])])

    def dist_to_chain(p, pts):
        a, b = pts[:-1], pts[1:]
        t = np.clip(np.sum((p - a) * (b - a), 1) / np.sum((b - a) ** 2, 1), 0, 1)
        return np.min(np.linalg.norm(a + t[:, None] * (b - a) - p, axis=1))

    assert max(min(dist_to_chain(p, s) for s in shapes) for p in tr[::5]) < 1e-9


def test_step_shapes_are_the_rotations_only():
    env = fixed_environment("E1")
    arm = env.arm
    path = _path(env)
    shapes = figure.step_shapes(arm, path)
    rotations = sum(1 for s in arm.action_sequence(path[0], path[1]) if s[0] == "rotate")
    assert shapes.shape == (rotations - 1, arm.n + 1, 2)  # the last rotation gives the final shape
    chain = np.concatenate([arm.joint_points(path[:1]), shapes, arm.joint_points(path[-1:])])
    assert all(not np.allclose(a, b) for a, b in zip(chain[:-1], chain[1:]))


def test_draw_without_path_and_cli_callers(tmp_path):
    env = fixed_environment("E3")
    out = figure.draw(env, None, tmp_path / "sub" / "e3.png")
    _png(out)
    assert figure.draw(env, _path(env), tmp_path / "p.png", title="E3 test").exists()
    (tmp_path / "file").write_text("x")
    with pytest.raises(ArmbridgeError, match="cannot write the figure"):
        figure.draw(env, None, tmp_path / "file" / "x.png")


def test_pieces_draw_another_planar_chain(tmp_path):
    """A 3-link chain that is not a MASR, drawn only with the generic pieces."""
    pf = figure.plan_axes()
    chains = np.array([[[0, 0], [0.1, 0], [0.2, 0], [0.3, 0]],
                       [[0, 0], [0.1, 0.02], [0.19, 0.06], [0.27, 0.12]],
                       [[0, 0], [0.09, 0.05], [0.16, 0.12], [0.2, 0.21]]], float)
    obstacles = [np.array([[0.2, -0.1], [0.3, -0.1], [0.3, -0.05], [0.2, -0.05]])]
    for ax in (pf.ax, pf.detail):
        figure.draw_reach(ax, 0.3)
        pts = figure.draw_obstacles(ax, obstacles, margin=0.01, labels=["A"])
        figure.draw_chain(ax, chains[0], role="start")
        figure.draw_shapes(ax, chains[1:-1])
        figure.draw_chain(ax, chains[-1], role="final")
        figure.draw_tip_path(ax, chains[:, -1], label="planned tip path")
        figure.draw_tip_path(ax, chains[:, -1] + 0.003, label="executed tip path", ls="--")
        figure.draw_goal(ax, chains[-1, -1], 0.01)
    assert Polygon(obstacles[0]).contains(Point(pts[0]))
    figure.style_workspace(pf.ax, 0.3)
    figure.zoom(pf, chains[-1, -1], 0.05)
    _png(figure.finish(pf, tmp_path / "chain.png"))
    legend = [t.get_text() for t in pf.key.get_legend().get_texts()]
    assert {"start configuration", "final configuration", "planned tip path", "executed tip path"} <= set(legend)
    assert sum(s.startswith("arm after each step") for s in legend) == 1  # one entry for all shapes
    with pytest.raises(ArmbridgeError, match=r"shape \(n\+1, 2\)"):
        figure.draw_chain(pf.ax, np.zeros((3, 3)))
    with pytest.raises(ArmbridgeError, match="1 labels for 2 obstacles"):
        figure.draw_obstacles(pf.ax, obstacles * 2, labels=["A"])


# ----------------------------------------------------------------------------- Fig. 5 / Fig. 7
def _curve(its, rise, top):
    x = np.arange(1, its + 1)
    return np.minimum(top, np.floor(top * 5 * np.clip(np.log10(x) / np.log10(rise), 0, 1)) / 5).tolist()


def _result(its=1200):
    """A result dict shaped as masr_plan.run returns (same keys), with hand-made curves."""
    labels = [masr_plan.label(p) for p in masr_plan.P_CS]
    cps = masr_plan.checkpoints(its)
    f5 = {"environments": 5, "iterations": its, "rows": [], "curves": {}}
    for k in cps:
        row = {"iterations": k, "common_solved": 4}
        for i, pl in enumerate(labels):
            row[pl] = {"success_rate": 1.0, "mean_cost_common_s": 20 - i - np.log10(k),
                       "mean_cost_own_s": 20 - i - np.log10(k)}
        f5["rows"].append(row)
    for i, pl in enumerate(labels):
        f5["curves"][pl] = {"success_rate": _curve(its, 30 if i else 150, 1.0)}
    two = (masr_plan.label(0.0), masr_plan.label(0.6))
    f7 = {"trials": 4, "iterations": its, "environments": {}}
    for name in masr_plan.FIXED:
        curves = {pl: {f"below_p{int(lv * 100)}": _curve(its, 400, 0.0 if pl == two[0] else 0.6)
                       for lv in masr_plan.LEVELS} for pl in two}  # 15th = 25th: coincident curves
        f7["environments"][name] = {"cost_range_s": [10.0, 30.0], "rows": [], "time_per_1000_s_mean": {},
                                    "curves": curves}
    return {"fig5": f5, "fig7": f7}


def _hue(c):
    return colorsys.rgb_to_hsv(*to_rgb(c))[0] * 360


def test_fig5_log_axes_plain_ticks_distinct_styles():
    res = _result()
    fig = fig5_figure(res["fig5"])
    try:
        a, b = fig.axes[:2]
        assert a.get_xscale() == b.get_xscale() == "log"
        fig.canvas.draw()
        for ax in (a, b):
            labels = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
            assert labels and all(s.isdigit() for s in labels), labels  # 1, 2, 5, 10 ... not 10^k
            assert all(str(int(s))[0] in "125" for s in labels)
            styles = {(ln.get_marker(), str(ln.get_linestyle()), ln.get_color()) for ln in ax.lines}
            assert len(styles) == len(ax.lines) == 4
        assert a.get_legend() is None and b.get_legend() is None and len(fig.legends) == 1
    finally:
        plt.close(fig)


def test_fig7_colour_family_per_planner_and_markers():
    res = _result()
    fig = fig7_figure(res["fig7"])
    try:
        assert [ax.get_title() for ax in fig.axes] == list(masr_plan.FIXED)  # one panel per environment
        for ax in fig.axes:
            assert ax.get_xscale() == "log"
            by = {}
            for ln in ax.lines:
                planner, level = ln.get_gid().split("|")
                by.setdefault(family(planner), []).append(ln)
            assert set(by) == {"masr", "rrt"} and all(len(v) == 2 for v in by.values())
            hues = {f: [_hue(ln.get_color()) for ln in v] for f, v in by.items()}
            for f, hs in hues.items():
                assert max(hs) - min(hs) < 20, (f, hs)  # one colour family per planner
                assert 180 < np.mean(hs) < 230 if f == "masr" else np.mean(hs) < 50  # blues / oranges
            for v in by.values():  # the two levels: different shade and line style, markers to see both
                assert v[0].get_color() != v[1].get_color()
                assert str(v[0].get_linestyle()) != str(v[1].get_linestyle())
            assert len({ln.get_marker() for ln in ax.lines}) == 4
            assert all(ln.get_markevery() for ln in ax.lines)
        assert len(fig.legends) == 1 and all(ax.get_legend() is None for ax in fig.axes)
    finally:
        plt.close(fig)


def test_bench_plots_write_readable_pngs(tmp_path):
    written = masr_plan.plots(_result(its=300), tmp_path / "png")
    assert [p.name for p in written] == ["masr-fig5.png", "masr-fig7.png"]
    for p in written:
        _png(p)


def test_walls_draw_as_lines_with_their_margin_and_long_ones_numbered():
    """2-vertex obstacles (walls, as in OMPL's horn) are lines; their number sits at the middle, and short
    walls, where numbers would pile up, carry none."""
    fig, ax = plt.subplots()
    walls = [np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([[0.0, 0.5], [0.01, 0.5]])]
    box = np.array([[0.2, 0.2], [0.4, 0.2], [0.4, 0.4], [0.2, 0.4]])
    pts = figure.draw_obstacles(ax, [*walls, box], margin=0.02)
    assert np.allclose(pts[0], [0.5, 0.0]) and Polygon(box).contains(Point(pts[2]))
    texts = sorted(t.get_text() for t in ax.texts)
    assert texts == ["0", "2"]
    labels = [h.get_label() for h in ax.get_legend_handles_labels()[0]]
    assert "wall" in labels and "obstacle" in labels
    plt.close(fig)
