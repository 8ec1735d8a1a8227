"""scripts/smm7r_device.py end to end on the CPU with --tiny, as a lent GPU machine would run it: only
torch, numpy and scipy importable besides the standard library and the checkout (every other
third-party import, array_api_compat included, is blocked), results and the packed model under --out
within the device tool's limits (8 files, 16 MiB each), and the packed model loads back."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from require import missing

try:
    import torch
except ImportError:
    missing("torch is not installed (`make setup` installs the [train] extra)")

from armbridge.smm import packed
from armbridge.smm.networks import SmmClassifier, SmmRegressor

ROOT = Path(__file__).resolve().parents[1]
# Modules the lent machine has (docs/notes/toolchain.md: python 3.12, torch, numpy, scipy; onnx there too,
# but not needed), and torch's own dependencies.
ALLOWED = {"torch", "numpy", "scipy", "typing_extensions", "sympy", "mpmath", "networkx", "jinja2", "markupsafe",
           "filelock", "fsspec", "functorch", "torchgen"}
RUNNER = """
import runpy, sys
sys.path.insert(0, sys.argv[1])
sys.argv = ['smm7r_device.py'] + sys.argv[2:]
runpy.run_path(SCRIPT, run_name='__main__')
""".replace("SCRIPT", repr(str(ROOT / "scripts" / "smm7r_device.py")))


def device_site(tmp_path: Path) -> Path:
    """A site-packages of links to this environment's copies of the ALLOWED packages only (and their
    bundled libraries): what `python -I -S` with it on sys.path can import is what the lent machine has."""
    import site

    out = tmp_path / "site"
    out.mkdir()
    for sp in site.getsitepackages():
        for entry in Path(sp).iterdir():
            top = entry.name.split(".")[0].removesuffix("-stubs")
            if top in ALLOWED and not entry.name.endswith((".dist-info", ".pth")) and not (out / entry.name).exists():
                (out / entry.name).symlink_to(entry)
    return out


def test_device_script_runs_tiny_on_the_cpu_with_only_torch_numpy_scipy(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-I", "-S", "-c", RUNNER, str(device_site(tmp_path)), "--tiny", "--device",
                           "cpu", "--out", str(out), "--budget", "120"], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    res = json.loads((out / "results.json").read_text())
    assert res["errors"] == [] and res["array_api_compat"] == "scipy's vendored copy"
    assert set(res["phases"]) == {"tracer", "data", "train", "measure"}
    tr = res["tracer"]
    for check in ("check_fused_vs_compact", "check_device_vs_cpu"):
        assert tr[check]["same_counts"] and tr[check]["same_singular"] and tr[check]["max_point_diff_rad"] < 1e-8
    assert {r["engine"] for r in tr["rows"]} >= {"compact", "fused"} and all(r["s_per_location"] > 0 for r in tr["rows"])
    data = res["data"]
    m = data["margin"]  # margin-sampled points, traced until half the budget
    assert m["traced"] >= 1 and 0 <= m["labelled"] <= m["traced"] and sum(m["count_histogram"].values()) == m["traced"]
    assert data["refine"]["patches_traced"] >= 1
    assert data["locations_traced"] == 8 + data["refine"]["cells_traced"] + m["traced"]
    rnd = res["accuracy"]["random_locations"]
    assert rnd["locations"] == 6 and 0 <= rnd["branch_count_mismatch_pct"] <= 100
    files = sorted(p.name for p in out.iterdir())
    assert len(files) <= 8 and all((out / f).stat().st_size <= 16 * 2**20 for f in files)
    assert "model.json" in files and "model-0.npz" in files
    assert set(res["model"]["files"]) == set(files) - {"results.json"}
    clf, regs, card = packed.unpack(out)
    assert card["robot"] == "spatial7r" and len(card["cluster_branches"]) == clf.body[-1].out_features
    assert set(regs) == {int(c) for c in card["regressors"]}


def test_pack_keeps_the_networks_within_int8_rounding_and_splits_files(tmp_path):
    torch.manual_seed(0)
    lo, hi, periodic = np.zeros(4), np.ones(4), (False, False, False, True)  # the 7R's azimuth wraps
    clf = SmmClassifier(lo, hi, (8,), 3, periodic)
    regs = {c: SmmRegressor(lo, hi, (64, 64), np.full(200, float(c)), 0.5, periodic) for c in (0, 2)}
    files = packed.pack(clf, regs, {"robot": "spatial7r", "lo": lo.tolist()}, tmp_path, max_bytes=40_000)
    assert [f.name for f in files] == ["model.json", "model-0.npz", "model-1.npz"]  # a regressor a file
    c2, r2, _ = packed.unpack(tmp_path)
    assert c2.periodic == periodic and all(m.periodic == periodic for m in r2.values())
    x = torch.rand(50, 4)
    with torch.no_grad():
        assert torch.equal(c2(x), clf(x))  # the classifier is kept in float32
        for c, m in regs.items():
            ref, got = m(x), r2[c](x)
            assert float((ref - got).abs().max()) < 0.02 * float(ref.abs().max())
            assert not torch.equal(ref, got)  # int8 weights: close, not equal
    with pytest.raises(Exception, match="more than a file"):
        packed.pack(clf, regs, {"lo": lo.tolist()}, tmp_path / "small", max_bytes=1000)
    (tmp_path / "model.json").write_text("{}")
    with pytest.raises(Exception, match="format None"):
        packed.unpack(tmp_path)


def _script():
    import importlib.util

    spec = importlib.util.spec_from_file_location("smm7r_device", ROOT / "scripts" / "smm7r_device.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_data_tracer_is_the_fastest_that_agreed_and_the_model_is_narrowed_to_fit():
    from types import SimpleNamespace

    dev = _script()
    agreed = {"check_fused_vs_compact": {"same_counts": True, "same_singular": True}, "capture_error": None}
    assert dev._engine(agreed, cuda=True) == {"engine": "fused", "graphs": True}
    assert dev._engine({**agreed, "capture_error": "RuntimeError: no"}, cuda=True) == {"engine": "fused",
                                                                                      "graphs": False}
    assert dev._engine(agreed, cuda=False)["graphs"] is False
    differed = {"check_fused_vs_compact": {"same_counts": False, "same_singular": True}}
    assert dev._engine(differed, cuda=True)["engine"] == "compact" and dev._engine(None, True)["engine"] == "compact"
    s = {"reg_hidden": (150,) * 6}
    small = SimpleNamespace(cluster_branches=np.array([0, 2, 3]), K=24)
    assert dev._fit_size(s, small) == (150,) * 6
    big = SimpleNamespace(cluster_branches=np.array([6] * 600), K=40)  # 600 six-branch clusters at K = 40
    hidden = dev._fit_size(s, big)
    assert len(hidden) == 6 and hidden[0] < 150
    n_out = 6 * 7 * 40 * 2
    widths = (4,) + hidden
    params = 600 * (sum(a * b for a, b in zip(widths[:-1], widths[1:])) + hidden[-1] * n_out)
    assert params <= dev.MODEL_BYTES <= 64 * 2**20 - 2**20  # int8: a byte a weight; results.json beside it
