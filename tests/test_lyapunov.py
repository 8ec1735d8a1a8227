"""The CBF's Lyapunov function checked to decrease (ik/lyapunov.py) and plotted as the
paper's Fig. 13 (bench/arm3r_lyapunov.py, `armbridge bench arm3r --lyapunov-png`)."""
from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from require import missing

try:
    import onnxruntime  # noqa: F401
    import qpsolvers  # noqa: F401
except ImportError as exc:
    missing(f"{exc.name} is not installed (`make setup` installs it)")

from armbridge.bench.arm3r_lyapunov import HOLD, fig13_png, section  # noqa: E402
from armbridge.errors import ArmbridgeError  # noqa: E402
from armbridge.ik.analytic3r import ik as closed_form  # noqa: E402
from armbridge.ik.cbf import CbfConfig, barrier_values, lyapunov  # noqa: E402
from armbridge.ik.lyapunov import check, held_path, simulate, trace_of  # noqa: E402
from armbridge.ik.region import pen_angle, safe_region  # noqa: E402
from armbridge.robots import get_robot  # noqa: E402

ARM = get_robot("arm3r")
REGION = safe_region(ARM)
PHI = pen_angle(ARM)
CFG = CbfConfig(gamma=10.0, gain=20.0, dt=0.01)  # the bench's
C = np.asarray(REGION.center)


def at(xy) -> np.ndarray:
    """q with the tip on xy (B, 2) at the pen angle (the closed form): a safe state inside the disc."""
    xy = np.atleast_2d(xy)
    q, ok = closed_form(ARM, np.c_[xy, np.full(len(xy), PHI)])
    assert ok.all()
    return q


def is_png(path) -> tuple[int, int]:
    """(width, height) of a real PNG file (signature, IHDR chunk), else an AssertionError."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR", data[:16]
    assert data[-8:-4] == b"IEND"
    return struct.unpack(">II", data[16:24])


def test_free_tracking_decreases_at_the_rate_of_the_gain():
    """References near the start, well inside the disc and the limits: no constraint binds, each
    step multiplies V by exactly (1 - K dt)^2, so V goes to 0 geometrically."""
    q0 = at(C + [[0.01, 0.0], [0.0, -0.02], [-0.015, 0.01]])
    q1 = at(C + [[0.005, 0.005], [0.0, -0.01], [-0.01, 0.005]])   # joint steps under v_max / K
    tr = simulate(ARM, REGION, q0, np.repeat(q1[None], 40, axis=0), CFG)
    r = check(tr)
    assert r["violations"] == r["dvdt_violations"] == r["constrained_steps"] == 0
    assert r["rows"] == 3 and r["steps"] == 40 and r["checked"] == 120 and r["updates"] == 3
    np.testing.assert_allclose(tr.after / tr.before, (1 - CFG.gain * CFG.dt) ** 2, rtol=1e-9)
    assert r["max_ratio"] == pytest.approx(0.64, rel=1e-9) and r["max_increase"] < 0
    np.testing.assert_allclose(tr.after[-1], 0.64**40 * tr.before[0], rtol=1e-7)   # -> 0 geometrically
    np.testing.assert_allclose(tr.before[0], lyapunov(q0, q1, CFG.weights))  # the V of ik.cbf, not a copy


def test_the_known_active_cases_are_reported_not_counted():
    """Row 0: a reference whose tip is outside the disc (the circle binds: V falls, then stalls
    above 0 at the boundary); row 1: a reference past the wrist's upper limit (the joint box
    binds; V stalls at the distance past it); row 2: a long jump (the speed limit binds at
    first, then tracking is free and V goes to 0). No row is a violation."""
    q0 = at(C + [[0.0, 0.0], [0.0, 0.0], [-0.08, 0.0]])
    ref_out = at(C + [[REGION.radius + 0.03, 0.0]])[0]           # reachable, tip 3 cm outside the disc
    ref_lim = q0[1].copy()
    ref_lim[2] = ARM.q_max[2] + 0.2
    ref_far = at(C + [[0.08, 0.0]])[0]
    refs = np.repeat(np.stack([ref_out, ref_lim, ref_far])[None], 400, axis=0)
    tr = simulate(ARM, REGION, q0, refs, CFG)
    r = check(tr)
    assert r["violations"] == 0 and r["dvdt_violations"] == 0
    per = r["constrained_per_row"]
    assert per[0] > 0 and per[1] > 0 and 0 < per[2] < 100
    assert r["constrained_at_end"] == 2                            # rows 0 and 1 are held off their reference
    assert tr.constrained[-1].tolist() == [True, True, False]
    h = barrier_values(ARM, REGION, tr.q[-1])
    assert abs(h[0, 0]) < 1e-4 and h[0].min() >= 0                # row 0 rests on the disc's edge
    assert tr.after[-1, 1] == pytest.approx(0.5 * 0.2**2, rel=1e-6)  # row 1 at the limit: 1/2 (0.2 rad)^2
    assert tr.after[-1, 0] > 1e-4 and tr.after[-1, 2] < 1e-20       # stalled above 0 / converged
    assert r["final_V_max_unconstrained"] == pytest.approx(tr.after[-1, 2])
    assert np.all((barrier_values(ARM, REGION, tr.q.reshape(-1, 3)) >= 0))  # safe at every step


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), spread=st.floats(0.05, 4.0), targets=st.integers(1, 6),
       hold=st.integers(1, 15), gain=st.floats(1.0, 150.0))
def test_random_targets_never_raise_v(seed, spread, targets, hold, gain):
    """Safe starts anywhere in the disc, a path of references anywhere around them (outside the
    disc and the limits too), each held `hold` steps: no step raises V, dV/dt <= 0, and every
    update is where the check says it is."""
    rng = np.random.default_rng(seed)
    n = 16
    r = REGION.radius * np.sqrt(rng.random(n))
    a = rng.random(n) * 2 * np.pi
    q0 = at(C + np.c_[r * np.cos(a), r * np.sin(a)])
    path = [q + rng.uniform(-spread, spread, (targets, 3)) for q in q0]
    cfg = CbfConfig(gamma=10.0, gain=gain, dt=min(0.01, 1.9 / gain))
    tr = simulate(ARM, REGION, q0, held_path(path, hold), cfg)
    res = check(tr)
    assert res["violations"] == 0 and res["dvdt_violations"] == 0, res
    assert res["steps"] == targets * hold and res["updates"] == n * targets
    assert np.all(barrier_values(ARM, REGION, tr.q.reshape(-1, 3)) >= 0)


def test_the_check_catches_a_rise():
    """A made-up run that steps away from its reference: each such step is a violation (the
    check can fail), and a rise at a target update is not one."""
    ref = np.zeros((3, 1, 3))
    q = np.array([[[0.1, 0, 0]], [[0.05, 0, 0]], [[0.08, 0, 0]], [[0.04, 0, 0]]])
    r = check(trace_of(q, ref, CFG))
    assert r["violations"] == 1 and r["violations_per_row"] == [1] and r["dvdt_violations"] == 1
    assert r["max_increase"] == pytest.approx(0.5 * (0.08**2 - 0.05**2))
    ref2 = np.array([[[0, 0, 0]], [[0.3, 0, 0]], [[0.3, 0, 0]]])   # a new reference at step 1
    q2 = np.array([[[0.1, 0, 0]], [[0.08, 0, 0]], [[0.124, 0, 0]], [[0.1592, 0, 0]]])
    r2 = check(trace_of(q2, ref2, CFG))
    assert r2["violations"] == 0 and r2["updates"] == 2 and r2["update_rises"] == 1
    assert r2["update_max_jump"] == pytest.approx(0.5 * (0.22**2 - 0.08**2))
    assert r2["constrained_steps"] == 0                              # each step was the nominal one


def test_bad_input_is_one_clear_error():
    with pytest.raises(ArmbridgeError, match="hold >= 1"):
        held_path([np.zeros((2, 3))], 0)
    with pytest.raises(ArmbridgeError, match="at least one target per row"):
        held_path([np.zeros((2, 3)), np.zeros((0, 3))], 3)
    with pytest.raises(ArmbridgeError, match="outside the safe set"):
        simulate(ARM, REGION, [[np.pi / 2, 0.0, 0.0]], np.zeros((2, 1, 3)), CFG)
    with pytest.raises(ArmbridgeError, match=r"refs \(steps, B, 3\)"):
        simulate(ARM, REGION, at(C), np.zeros((2, 3)), CFG)
    with pytest.raises(ArmbridgeError, match="q must be"):
        trace_of(np.zeros((3, 1, 3)), np.zeros((3, 1, 3)), CFG)


def test_held_path_pads_short_rows():
    refs = held_path([np.array([[1.0, 0, 0], [2.0, 0, 0]]), np.array([[5.0, 0, 0]])], 3)
    assert refs.shape == (6, 2, 3)
    assert refs[:, 0, 0].tolist() == [1, 1, 1, 2, 2, 2] and refs[:, 1, 0].tolist() == [5] * 6


def test_section_on_two_samples_and_the_png(tmp_path):
    """The bench's section on paths along two short strokes: decreasing, counted, and Fig. 13 a real PNG."""
    t = np.linspace(0, 1, 25)[:, None]
    a = at(C + np.c_[0.05 * np.cos(6 * t), 0.05 * np.sin(6 * t)])
    b = at(C + np.c_[-0.06 + 0.1 * t, 0.03 * np.ones_like(t)])[:17]
    png = tmp_path / "fig" / "f13.png"
    out = section(ARM, REGION, CFG, ["arc", "line"], [a[0], b[0]], [a, b], png)
    assert out["decreasing"] and out["violations"] == 0 and out["rows"] == 2
    assert out["steps"] == 25 * HOLD and out["updates"] == 25 + 17 and out["png"] == str(png)
    w, h = is_png(png)
    assert w > 600 and h > 200
    import matplotlib.image

    img = matplotlib.image.imread(png)
    assert img.shape[:2] == (h, w) and img.std() > 0.05             # decodes, and is not blank
    with pytest.raises(ArmbridgeError, match="hold >= 1"):
        section(ARM, REGION, CFG, ["x"], [a[0]], [a[:0]])
    p2 = fig13_png(simulate(ARM, REGION, a[:1], held_path([a], HOLD), CFG), ["arc"], [len(a)], tmp_path / "one.png")
    assert is_png(p2)[0] > 200


def test_bench_arm3r_writes_the_lyapunov_key_and_fig13(bench_arm3r_quick):
    """`armbridge bench arm3r --quick --lyapunov-png`: the report's lyapunov key and the figure
    (the run is shared with test_bench_arm3r: tests/bench_runs.py)."""
    from armbridge.bench import arm3r

    r, out, png = bench_arm3r_quick
    assert r.exit_code == 0, r.output
    ly = json.loads(out.read_text())["lyapunov"]
    assert ly["samples"] == list(arm3r.QUICK.samples) and ly["rows"] == 3
    assert ly["violations"] == 0 and ly["dvdt_violations"] == 0 and ly["decreasing"]
    assert ly["updates"] == sum(s["points"] for s in json.loads(out.read_text())["samples"])
    assert ly["checked"] == 3 * ly["steps"] and ly["max_increase"] <= 0
    assert ly["png"] == str(png) and is_png(png)[0] > 600
    assert "Lyapunov V on 3 samples" in r.output
    assert json.loads(out.read_text())["targets"]["lyapunov_decreasing"]
