"""The board's Cartesian IK (firmware/esp32/ik3r.py + mlp.py, issue 10 section 3)
against its numpy reference (host/armbridge/ik/board_ik.py), under CPython and
under the real MicroPython WebAssembly interpreter (emulator/mpbridge/boardik.mjs).

Tolerance. The integer core of the net is exact on both sides; the floats are
not: the chip computes in float32 (unit roundoff 6e-8), the reference in
float64. Running the reference itself in float32 over 20,000 disc targets
(test_float32_fits_the_tolerance) moves the answers by at most 4e-6 rad: the net
alone moves by up to 1e-3 rad (a rounding that flips one activation's quantum),
and FABRIK, a contraction onto the same fixed point, removes that. TOL_Q = 5e-5
rad is ten times the measured float32 effect (19 um at the full reach of 0.38 m).
The answer/refusal decision must agree except where the tip error lies within
TOL_EDGE of IK_TOL_UM (the rounding can put it either side there).
"""
import json
import math
import shutil
import subprocess
import sys
from array import array
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from emu_host import Codec, is_reply
from require import require_micropython

from armbridge.bench.board_ik import under_micropython
from armbridge.emulator.board import EmulatedBoard
from armbridge.emulator.micropython import find_micropython
from armbridge.emulator.runner import load_firmware
from armbridge.errors import ArmbridgeError
from armbridge.ik.board_ik import BoardIKReference, board_forward, quant_levels, shipped_weights
from armbridge.ik.flat_int8 import flat_int8_forward, read_flat_int8
from armbridge.resources import firmware_dir

ROOT = Path(__file__).resolve().parents[1]
TOL_Q = 5e-5  # rad (module docstring)
TOL_EDGE = 1e-6  # m


@pytest.fixture(scope="module")
def fw():
    return load_firmware([firmware_dir() / "esp32", firmware_dir() / "common"], ("config", "ik3r"))


@pytest.fixture(scope="module")
def ref(fw):
    return BoardIKReference.from_config(fw["config"])


@pytest.fixture(scope="module")
def weights():
    return shipped_weights().read_bytes()


def targets(ref, n, seed, spread=0.25, outside=0.1):
    """n targets: most uniform in the safe disc, `outside` of them in a ring just outside
    it; theta uniform in IK_THETA +- spread."""
    rng = np.random.default_rng(seed)
    (cx, cy), r = ref.region.center, ref.region.radius
    rad = r * np.sqrt(rng.random(n))
    out = rng.random(n) < outside
    rad[out] = r * (1.0 + 1e-4 + 0.3 * rng.random(out.sum()))
    ang = rng.random(n) * 2 * np.pi
    return np.stack([cx + rad * np.cos(ang), cy + rad * np.sin(ang), spread * (2 * rng.random(n) - 1)], -1)


def compare(ref, poses, q_board):
    """Board answers (list of [q1, q2, q3] | None) against the reference, within TOL_Q."""
    sol = ref.solve(poses)
    got = np.array([q is not None for q in q_board])
    edge = np.abs(sol.error - ref.tol) <= TOL_EDGE
    assert not np.any(got[~sol.inside]), "an answer for a target outside the safe disc"
    bad = (got != sol.ok) & ~edge
    assert not bad.any(), f"{bad.sum()} answers/refusals differ from the reference, e.g. {poses[bad][:3]}"
    both = got & sol.ok
    qb = np.array([q for q in q_board if q is not None])
    dq = np.abs(qb - sol.q[got]).max(axis=-1)[both[got]]
    assert dq.max() <= TOL_Q, f"max |dq| {dq.max():.3g} rad > {TOL_Q}"
    return sol, got, dq


MP_POSES = 2000
MP_SEED = 6


@pytest.fixture(scope="module", autouse=True)
def micropython_reference_run(request, ref):
    """test_micropython_matches_reference's run of the firmware under MicroPython (~40 s of one
    core: the net is ~5 ms a point there), started in a thread before the module's first test,
    so that the other tests run beside it; that test, last in the module, takes its answers.
    None when it is not to run, or node or the package is missing (the test then skips or
    fails through run_micropython)."""
    wanted = any(item.name == "test_micropython_matches_reference" and item.module is request.module
                 for item in request.session.items)
    if not wanted or shutil.which("node") is None:
        yield None
        return
    try:
        find_micropython()
    except ArmbridgeError:
        yield None
        return
    poses = targets(ref, MP_POSES, seed=MP_SEED)
    with ThreadPoolExecutor(1) as pool:
        yield poses, pool.submit(under_micropython, poses, True)


def test_cpython_matches_reference(fw, ref, weights):
    ik = fw["ik3r"].BoardIK(fw["config"], weights)
    poses = targets(ref, 3000, seed=1)
    q_board = [ik.solve(*p) for p in poses.tolist()]
    sol, got, _ = compare(ref, poses, q_board)
    assert 0.8 < got.mean() < 0.95  # ~10 % outside, a few percent beyond the limits at theta +- 0.25
    lo, hi = ref.chain.q_min, ref.chain.q_max
    qb = np.array([q for q in q_board if q is not None])
    assert np.all((qb >= lo - 1e-12) & (qb <= hi + 1e-12))
    tip = ref.chain.ee_point(qb)
    assert np.linalg.norm(tip - poses[got, :2], axis=-1).max() <= ref.tol


def test_float32_fits_the_tolerance(ref):
    poses = targets(ref, 20000, seed=2)
    a, b = ref.solve(poses), ref.solve(poses, np.float32)
    edge = np.abs(a.error - ref.tol) <= TOL_EDGE
    assert np.all((a.ok == b.ok) | edge)
    both = a.ok & b.ok
    assert np.abs(a.q - b.q)[both].max() <= TOL_Q / 5


def test_every_disc_target_at_the_pen_angle_converges(fw, ref):
    """With IK_FABRIK_PASSES, every target of the safe disc at the pen angle IK_THETA_MRAD
    ends within IK_TOL_UM (measured: 100,000 of 100,000, max 40 um, at 128 passes)."""
    poses = targets(ref, 50000, seed=3, spread=0.0, outside=0.0)
    poses[:, 2] = fw["config"].IK_THETA_MRAD / 1000.0
    sol = ref.solve(poses)
    assert sol.inside.all() and sol.ok.all(), f"{(~sol.ok).sum()} of {len(poses)} did not converge"
    assert sol.error.max() <= ref.tol / 2


def test_outside_the_disc_is_refused(fw, ref, weights):
    ik = fw["ik3r"].BoardIK(fw["config"], weights)
    (cx, cy), r = ref.region.center, ref.region.radius
    for a in np.linspace(0, 2 * np.pi, 37):
        for k in (1.0005, 1.2, 3.0):
            assert ik.solve(cx + k * r * np.cos(a), cy + k * r * np.sin(a), 0.0) is None
    assert ik.solve(cx, cy, 0.0) is not None
    assert ik.solve(cx, cy, 20.0) is None  # a pen angle no configuration has


def test_net_is_the_flat_int8_net(fw, ref):
    """The integer-activation forward pass is the flat file's net up to the activation
    quantum (15 bits): close to ik.flat_int8's float forward."""
    layers = read_flat_int8(shipped_weights())
    f = np.random.default_rng(4).random((2000, 3))
    a, b = board_forward(layers, f), flat_int8_forward(layers, f)
    assert np.abs(a - b).max() < 2e-3 * np.abs(b).max()
    for cols in range(1, 700):
        q = quant_levels(cols)
        assert fw["mlp"].levels(cols) == q and 127 * q * cols < 2**30 and (q == 32767 or 127 * (q + 1) * cols >= 2**30)
    assert quant_levels(100) == 32767


def test_kernels_agree_and_the_viper_sign_fix(fw):
    mlp = fw["mlp"]
    rng = np.random.default_rng(5)
    w = rng.integers(-127, 128, (7, 100)).astype(np.int8)
    for zeros in (0.0, 0.5, 0.9):
        x = rng.integers(-32767, 32768, 100) * (rng.random(100) >= zeros)
        want = w.astype(np.int64) @ x
        wa, xa = array("b", w.tobytes()), array("i", x.astype(np.int32).tobytes())
        for kernel, wbuf in ((mlp._dot_plain, wa), (mlp._dot_viper, wa),
                             (mlp._dot_viper, bytes(wa))):  # bytes index unsigned, as viper's ptr8
            acc = array("i", bytes(4 * 7))
            kernel(wbuf, xa, acc, (7 << 16) | 100)
            assert list(acc) == want.tolist()
    assert mlp.NATIVE is False  # CPython: the viper decorator is a no-op


def test_bad_weight_files_raise_one_clear_error(fw, weights):
    ik3r, cfg = fw["ik3r"], fw["config"]
    cases = {
        "missing": (None, "missing"),
        "empty": (b"", "not a flat int8"),
        "magic": (b"XXXX" + weights[4:], "not a flat int8"),
        "version": (weights[:4] + b"\x02\x00" + weights[6:], "version 2"),
        "header": (weights[:16], "truncated"),
        "half": (weights[: len(weights) // 2], "truncated"),
        "short": (weights[:-4], "truncated"),
        "long": (weights + b"\x00" * 4, "has 12264 bytes"),
        "n_in": (weights[:8] + b"\x04\x00" + weights[10:], "its input has 4"),
    }
    for name, (data, words) in cases.items():
        with pytest.raises(ValueError) as exc:
            ik3r.BoardIK(cfg, data)
        assert words in str(exc.value), (name, str(exc.value))
    with pytest.raises(ArmbridgeError, match="not a flat int8"):
        BoardIKReference.from_config(cfg, _bad_file(b"XXXX" + weights[4:]))


def _bad_file(data):
    import tempfile

    f = tempfile.NamedTemporaryFile(suffix=".bin", delete=False)
    f.write(data)
    f.close()
    return Path(f.name)


def run_micropython(poses, timing=False):
    """The firmware's BoardIK on `poses` under the MicroPython WebAssembly interpreter
    (armbridge.bench.board_ik.under_micropython: emulator/mpbridge/boardik.mjs)."""
    require_micropython()
    return under_micropython(poses, timing=timing)


# ---------------------------------------------------------------- the board's files in the emulator

@pytest.mark.parametrize("interpreter", ["cpython", "micropython"])
def test_emulated_board_solves_xy_from_its_flashed_weights(interpreter, ref, weights):
    """The emulator flashes the shipped weights as cfg.IK_WEIGHTS (SimHal files; under
    MicroPython written into the interpreter's filesystem at boot): XY at a disc point
    runs to the reference's joint angles, a point outside is refused REACH, and a pen
    move comes back through the bridge onto the emulator's HAL."""
    if interpreter == "micropython":
        run_micropython([])  # node and the package, or skip / fail under ARMBRIDGE_REQUIRE_HIL
    emu = EmulatedBoard("esp32", speed=0, interpreter=interpreter)
    try:
        cfg = emu.cfg
        assert emu.hal.read_file(cfg.IK_WEIGHTS) == weights and emu.hal.read_file("nothing.bin") is None
        codec, lines = Codec(), []

        def request(verb, *args):
            emu.inject(codec.hello(*args) if verb == "HELLO" else codec.line(verb, *args))
            seq = codec.seq
            found = []

            def check():
                lines.extend(codec.feed(emu.read_output()))
                found[:] = [ln for ln in lines if is_reply(ln, seq)]
                return bool(found)

            assert emu.run_until(check, 3.0), lines[-5:]
            return found[0]

        assert request("HELLO", 3)[1] == "OK"
        (cx, cy), r = ref.region.center, ref.region.radius
        x, y = cx + 0.3 * r, cy - 0.2 * r
        ok = request("XY", 1, 300, round(x * 1e6), round(y * 1e6))
        assert ok[1] == "OK", ok
        far = request("XY", 2, 300, round(cx * 1e6), round((cy + 1.01 * r) * 1e6))
        assert far[1] == "ER" and far[2][1] == "13", far
        emu.run_for(0.6)
        assert [wid for _, wid, _ in emu.executed] == [1]
        pen_before = len(emu.hal.pen_log)
        assert request("PEN", 1)[1] == "OK"  # at rest: the pen moves now
        want = ref.solve(np.array([[round(x * 1e6) / 1e6, round(y * 1e6) / 1e6, cfg.IK_THETA_MRAD / 1000.0]]))
        assert want.ok[0]
        assert np.abs(np.array(emu.executed[0][2]) - want.q[0] * 1000).max() <= 0.5 + TOL_Q * 1000
        assert [down for _, down in emu.hal.pen_log[pen_before:]] == [True]
    finally:
        emu.stop()


def test_bench_board_ik_cli_writes_its_numbers(tmp_path):
    run_micropython([])  # node and the package, or skip / fail under ARMBRIDGE_REQUIRE_HIL
    out = tmp_path / "b.json"
    proc = subprocess.run([str(Path(sys.executable).with_name("armbridge")), "bench", "board-ik", "--points", "30",
                           "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    r = json.loads(out.read_text())
    assert r["net"]["file_bytes"] == len(shipped_weights().read_bytes()) and r["net"]["macs_per_point"] == 10600
    for name in ("pen_angle", "pen_angle_spread"):
        for who in ("micropython", "cpython"):
            c = r[name][who]
            assert c["targets"] == 30 and c["agree_with_reference"] == 30
            assert c["vs_int8_reference_rad"]["max"] <= TOL_Q and c["tip_error_um"]["max"] <= r["tol_um"]
    assert r["pen_angle"]["micropython"]["answered"] == 30 and r["pen_angle"]["converged_by_passes"]["128"] == 1.0
    assert "multiply-adds" in proc.stdout


def test_the_boards_disc_is_the_hosts_safe_region():
    """config.IK_REGION_UM is ik.region.safe_region(arm3r) in um, its radius rounded up and 1 um
    more, so that every target the host places in the region (then rounds to um for an X line)
    is one the board accepts, and the board's disc is no more than 2 um larger."""
    from armbridge.ik.region import safe_region
    from armbridge.robots import get_robot

    from armbridge.emulator.runner import load_firmware
    from armbridge.resources import firmware_dir

    cfg = load_firmware([firmware_dir() / "esp32"], ("config",))["config"]
    reg = safe_region(get_robot("arm3r"))
    cx, cy, r = cfg.IK_REGION_UM
    off = math.hypot(cx - reg.center[0] * 1e6, cy - reg.center[1] * 1e6)
    assert off < 0.5
    assert r - off - math.sqrt(0.5) >= reg.radius * 1e6   # host disc + X's rounding inside
    assert r - reg.radius * 1e6 < 2.0


# ---------------------------------------------------------------- last: it waits for its run

def test_micropython_matches_reference(ref, micropython_reference_run):
    """2,000 targets under MicroPython (micropython_reference_run: started with the module)."""
    if micropython_reference_run is None:
        poses = targets(ref, MP_POSES, seed=MP_SEED)
        out = run_micropython(poses, timing=True)
    else:
        poses, future = micropython_reference_run
        out = future.result(timeout=600)
    assert out["native"] is False  # the port strips the viper decorator: the plain kernel ran
    assert out["macs"] == 3 * 100 + 100 * 100 + 100 * 3
    _, got, _ = compare(ref, poses, out["q"])
    assert 0.8 < got.mean() < 0.95
    assert np.abs(np.array(out["guess"]) - ref.net(poses)).max() <= TOL_Q  # the net alone, too
    assert out["ram_bytes"] == 12260 - 12 - 3 * 8 + 8 * 100 and out["heap_bytes"] > out["ram_bytes"]
