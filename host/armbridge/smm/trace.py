"""Ground-truth SMMs of many locations, traced in shards.

`trace_smms` runs the nullspace tracer (smm/nullspace.py) over task locations,
`batch` locations a shard (armbridge.shards: here one after the other, or on
Ray workers, resumable from checkpoints); `compute_smms` does so at canonical
locations (no shift). Every shard traces with the same IK seed, as the serial
path always has, so the result does not depend on where or in which order the
shards ran.

Apart from the data set (smm/dataset.py) because this is how SMMs are
computed at scale, which the benches (bench smm, bench shards) and the
refinement use on their own.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from armbridge.smm.arms import SmmArm
from armbridge.smm.manifold import SmmSet, concat

if TYPE_CHECKING:
    from armbridge.shards import Runner, Shard

Progress = Callable[[int, int], None]


def compute_smms(
    arm: SmmArm,
    canon: np.ndarray,
    n_points: int = 128,
    batch: int = 2048,  # locations per nullspace call: larger batches amortise the per-step overhead
    progress: Progress | None = None,
    runner: Runner | None = None,
    job: str = "smm",
    **nullspace_options: Any,
) -> SmmSet:
    """Nullspace SMMs at canonical locations (no shift): trace_smms at arm.uncanonical(canon)."""
    x = np.asarray(arm.uncanonical(np.asarray(canon, dtype=np.float64)))
    return trace_smms(arm, x, n_points, batch, progress, runner, job, **nullspace_options)


def trace_smms(
    arm: SmmArm,
    x: np.ndarray,
    n_points: int = 128,
    batch: int = 2048,
    progress: Progress | None = None,
    runner: Runner | None = None,
    job: str = "smm",
    seconds: list[float] | None = None,
    **nullspace_options: Any,
) -> SmmSet:
    """Nullspace SMMs at task locations x, `batch` locations per call, one shard each.

    The shards (armbridge.shards) run where `runner` says (None: here, one
    after the other); each traces its locations with the same IK seed
    `seed` (a nullspace option), as the serial path always has, so the
    result does not depend on where or in which order the shards ran.
    progress(done, total) follows the shards in order; `seconds` gets each
    shard's nullspace time (a measurement, not part of the result).
    """
    from armbridge.shards import Job, Runner, Shard

    x = np.asarray(x, dtype=np.float64)
    options = dict(nullspace_options)
    seed = options.pop("seed", 0)
    if "device" in options and options["device"] is not None:
        options["device"] = str(options["device"])
    work = Job(job, smm_shard, {"arm": arm.to_dict(), "n_points": int(n_points), "options": options},
               gpu=options.get("device") is None)
    shards = [Shard(i, seed, {"start": s}, {"x": x[s : s + batch]}) for i, s in enumerate(range(0, len(x), batch))]
    done = 0

    def advance(shard: Shard, arrays: dict[str, np.ndarray]) -> None:
        nonlocal done
        done += len(arrays["count"])
        if seconds is not None:
            seconds.append(float(arrays["seconds"]))
        if progress is not None:
            progress(done, len(x))

    parts = (runner or Runner()).map(work, shards, on_result=advance, label=f"SMM {job}")
    return concat([SmmSet(p["points"], p["count"], p["singular"]) for p in parts], n_points, arm.n)


def smm_shard(params: Mapping[str, Any], shard: Shard) -> dict[str, np.ndarray]:
    """One shard of trace_smms: nullspace.compute on its locations, on one torch thread (the
    tracer's ops are small: a second thread only adds hand-offs, nullspace's docstring)."""
    import torch

    from armbridge.robots.dh import DHChain
    from armbridge.smm import nullspace

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    arm = DHChain.from_dict(params["arm"])
    try:
        t0 = time.perf_counter()
        s = nullspace.compute(arm, shard.inputs["x"], n_points=params["n_points"], seed=shard.seed, **params["options"])
        took = time.perf_counter() - t0
    finally:
        torch.set_num_threads(threads)
    return {"points": s.points, "count": s.count, "singular": s.singular, "seconds": np.asarray(took)}
