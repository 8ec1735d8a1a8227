"""The shape-static tracer (smm/fused.py) against the compacting one (smm/stepping.py) on the CPU:
the same branch counts, singular flags and points, on the arms the data sets use.

The CUDA-graph capture runs only where a CUDA device is visible (the GPU test at the end; the
device script scripts/smm7r_device.py measures it on a lent GPU).
"""
import numpy as np
import pytest

from require import missing

try:
    import torch
except ImportError:
    missing("torch is not installed (`make setup` installs the [train] extra)")

from armbridge.errors import ArmbridgeError
from armbridge.smm import fused, nullspace
from armbridge.smm.arms import get_smm_arm
from armbridge.smm.grid import random_locations, region_grid, region_locations

torch.set_num_threads(1)


def _same(a, b) -> None:
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_array_equal(a.singular, b.singular)
    assert a.points.shape == b.points.shape
    np.testing.assert_allclose(a.points, b.points, rtol=0, atol=1e-8, equal_nan=True)


@pytest.mark.parametrize("name,count,opts", [
    ("planar3r", 24, dict(seeds=16)),
    # more traces than fused.MIN_BATCH: the batch shrinks to a smaller power of two as traces end
    ("spatial4r", 40, dict(seeds=16)),
    ("spatial7r", 6, dict(seeds=16, sing_tol=0.005, step=0.04)),
])
def test_fused_tracer_gives_the_compacting_tracers_smms(name, count, opts) -> None:
    arm = get_smm_arm(name)
    if arm.tool_roll:
        x = np.asarray(arm.uncanonical(region_locations(region_grid(arm), count, seed=3)))
    else:
        x = random_locations(arm, count, seed=3)
    x = np.concatenate([x, x[:1] * 10])  # and one out of reach (no converged seed: no trace)
    ref = nullspace.compute(arm, x, device="cpu", **opts)
    got = nullspace.compute(arm, x, device="cpu", engine="fused", **opts)
    _same(ref, got)
    assert ref.count[-1] == 0 and ref.count[:-1].min() >= 1
    if name == "spatial7r":
        assert ref.count.max() >= 2  # several branches: later traces stop on earlier seeds' loops


def test_fused_batches_shrink_and_chunks_agree() -> None:
    """Chunks of 5 locations (batches of a few traces) and one chunk (batches that shrink): the same SMMs,
    which is also the compacting tracer's."""
    arm = get_smm_arm("spatial4r")
    x = random_locations(arm, 30, seed=5)
    tracer = fused.Tracer()
    ctx_opts = dict(device="cpu", seeds=32)
    whole = nullspace.compute(arm, x, engine=tracer, **ctx_opts)
    parts = nullspace.compute(arm, x, engine="fused", chunk=5, **ctx_opts)
    _same(whole, parts)
    _same(whole, nullspace.compute(arm, x, **ctx_opts))
    # the first wave, 4 traces a location, starts at the power of two that holds them and shrinks as its
    # traces end; every batch is a power of two
    assert tracer.sizes[0] == 128 and tracer.sizes[1] < 128 and tracer.blocks > 0
    assert all(b & (b - 1) == 0 for b in tracer.sizes)
    assert tracer.captured == 0  # nothing is captured on the CPU


def test_max_steps_ends_open_traces_as_singular_in_both() -> None:
    arm = get_smm_arm("planar3r")
    x = random_locations(arm, 4, seed=1)
    ref = nullspace.compute(arm, x, device="cpu", seeds=8, max_steps=40)
    got = nullspace.compute(arm, x, device="cpu", seeds=8, max_steps=40, engine="fused")
    _same(ref, got)
    assert ref.singular.all()  # no loop closes in 40 steps of 0.02 rad


def test_unknown_engine_is_a_clear_error() -> None:
    with pytest.raises(ArmbridgeError, match="engine must be one of compact, fused"):
        nullspace.compute(get_smm_arm("planar3r"), np.zeros((1, 2)), engine="graph")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_graphs_give_the_cpu_smms() -> None:
    arm = get_smm_arm("spatial7r")
    x = np.asarray(arm.uncanonical(region_locations(region_grid(arm), 64, seed=3)))
    ref = nullspace.compute(arm, x, device="cpu", sing_tol=0.005)
    got = nullspace.compute(arm, x, device="cuda", sing_tol=0.005, engine="fused", graphs=True)
    np.testing.assert_array_equal(ref.count, got.count)
    np.testing.assert_array_equal(ref.singular, got.singular)
    np.testing.assert_allclose(ref.points, got.points, rtol=0, atol=1e-6, equal_nan=True)
