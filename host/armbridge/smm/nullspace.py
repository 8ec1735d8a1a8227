"""Ground-truth SMMs by the nullspace projection method (section III-B).

For an arm with one degree of redundancy (n = m + 1) every branch of the SMM
of a location is a closed loop in joint space. compute() finds them all:

1. IK seeds: `seeds` random configurations per location driven onto the
   target by damped least squares (Levenberg-Marquardt damping per seed).
   A location where no seed converges is out of reach (count 0).
2. Tracing, eq. (1): dq = gamma * n/|n| + J^+ dx_e, n the null vector of
   eq. (6), always along +n. Traces of all locations run in lock-step as one
   torch batch; finished ones leave it. gamma is small and constant
   (section IV-C).
3. Seeds on a traced branch are not traced again. Tracing runs in waves: the
   first starts a trace from each of the lowest 4 converged seeds of every
   location. A trace stops as soon as it passes (within gamma) a seed of its
   wave with a lower index, or a seed that started a branch in an earlier
   wave: the rest of its loop is traced from there. So one trace per branch
   runs on, the one from the branch's lowest seed, until it is back within
   gamma of its start (wrapped angles) after having left it by 3 gamma. Every
   seed some trace passed lies on a traced branch; the next wave starts from
   4x as many of the seeds still unpassed (branches not found yet), until
   every converged seed is passed.
4. Each loop is resampled to n_points uniformly in arc length (traces are
   unwrapped by construction: angles are wrapped only at the end), corrected
   by a few J^+ steps (eq. 18) and wrapped to [-pi, pi) (geometry.wrap_angle). It starts at its
   seed and runs along +n, the orientation the Fourier phase rule expects.

Engines: "compact" (smm/stepping.py, the default, what CI tests) drops
finished traces from the batch as they pile up; "fused" (smm/fused.py)
keeps fixed-size batches where finished traces are masked, synchronises
with the host once per block of steps and, on CUDA, replays a block as a
CUDA graph. Both give the same branch counts and flags (tests).

Speed: the step solves one n x n system [W J; u^T] y = [W dx_e, e_n] per
configuration, u the previous unit tangent. Its second column is
n / (u . n) (cofactor expansion along the last row), i.e. eq. (6)'s null
vector with its sign as long as the tangent turns by less than 90 degrees
per step; the first column, minus its component along n, is J^+ dx_e
exactly. One LU instead of the n determinants of eq. (6) (used for the first
step). Seed and closure tests use chord distances |e^{iq} - e^{is}|, a
batched matrix product. On the CPU run it with torch.set_num_threads(1):
the ops are small, and with 2 threads on a busy 2-core machine thread
hand-offs made it 5-10x slower.

singular[l] is set when a branch of l comes near a singular configuration:
the smallest singular value of W J (position rows divided by the reach L as
in eq. 19, so W J is dimensionless and O(1)), checked every 4 steps, falls
below `sing_tol`; or when a branch fails to close: not within max_steps, or
stuck within 3 gamma of its start for 50 steps (at a singular configuration
the null space is 2-D and the tangent dithers). Near a
fold the smallest singular value along the SMM grows like sqrt(distance):
for planar3r it is about 0.5 sqrt(|r - 1| / 3) near the singular radius 1,
so sing_tol = 0.02 flags |r - 1| < ~0.005 (0.16 % of L). On a workspace grid
of spacing h, sing_tol ~ 0.5 sqrt(h / (2 L)) flags a band about one cell
wide. Near singular configurations branches come close and a trace may jump
between them, so the branches of a singular location are not trusted.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from armbridge.errors import ArmbridgeError
from armbridge.geometry import wrap_angle
from armbridge.robots.dh import DHChain
from armbridge.smm.correction import correct
from armbridge.smm.manifold import SmmSet, concat
from armbridge.smm import fused
from armbridge.smm.stepping import Ctx, Traces, ik_seeds, null_vector, resample, trace

__all__ = ["ENGINES", "compute", "ik_seeds", "null_vector", "resample", "trace"]

ENGINES = ("compact", "fused")
TraceFn = Callable[[Ctx, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, float, float, int], Traces]


def compute(
    arm: DHChain,
    x: np.ndarray | torch.Tensor,
    *,
    n_points: int = 128,
    seeds: int = 64,
    step: float = 0.02,
    sing_tol: float = 0.02,
    max_steps: int | None = None,
    correct_iters: int = 3,
    chunk: int = 1024,
    device: str | torch.device | None = None,
    seed: int = 0,
    engine: str | fused.Tracer = "compact",
    graphs: bool = True,
) -> SmmSet:
    """SMMs of the L locations x (L, m) of arm, each branch sampled at n_points.

    seeds: IK seeds per location; step: gamma of eq. (1) in rad (norm of the
    null-space step); sing_tol: see the module doc; max_steps: longest
    trace, beyond which a branch counts as not closing (default
    12 pi n / step, six full turns of every joint; the longest branches met
    in our runs took under half of that); correct_iters: eq. (18) steps on
    the resampled points; chunk: locations per torch batch (larger batches
    amortise the per-step overhead); device: None picks CUDA when available;
    seed: of the random IK starts; engine: "compact" (stepping.trace, the
    default) or "fused" (fused.trace: fixed-size batches, no per-step host
    synchronisation, the same branches) or a fused.Tracer (whose counters the
    caller reads); graphs: with engine "fused" on a CUDA device, replay each
    block of steps as a CUDA graph.
    """
    if not isinstance(engine, fused.Tracer) and engine not in ENGINES:
        raise ArmbridgeError(f"engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    if arm.n != arm.m + 1:
        raise ArmbridgeError(f"robot {arm.name!r}: SMMs need exactly one redundant joint, got n={arm.n}, m={arm.m}")
    try:
        xt = torch.as_tensor(np.asarray(x, dtype=float) if not isinstance(x, torch.Tensor) else x,
                             dtype=torch.float64).cpu()
    except (TypeError, ValueError):
        raise ArmbridgeError(f"robot {arm.name!r}: locations must be numbers, got {x!r}") from None
    if xt.ndim != 2 or xt.shape[1] != arm.m:
        raise ArmbridgeError(f"robot {arm.name!r}: locations must have shape (L, {arm.m}), got {tuple(xt.shape)}")
    if not bool(torch.isfinite(xt).all()):
        raise ArmbridgeError(f"robot {arm.name!r}: locations must be finite numbers")
    for name, value, low in (("n_points", n_points, 4), ("seeds", seeds, 1), ("chunk", chunk, 1)):
        if int(value) < low:
            raise ArmbridgeError(f"{name} must be >= {low}, got {value}")
    if not 0 < step < 0.5:
        raise ArmbridgeError(f"step must be in (0, 0.5) rad, got {step}")
    if not 0 <= sing_tol < 1:
        raise ArmbridgeError(f"sing_tol must be in [0, 1), got {sing_tol}")
    dev = torch.device(device) if device is not None else torch.device("cuda" if torch.cuda.is_available() else "cpu")
    tracer: TraceFn = trace
    if isinstance(engine, fused.Tracer):  # the caller's, to read its counters (benches)
        tracer = engine
    elif engine == "fused":
        tracer = fused.Tracer(graphs=graphs and dev.type == "cuda")
    rows = [1 / arm.reach] * 3 + [1.0] * 3 if arm.space == "pose" else [1 / arm.reach] * arm.m
    ctx = Ctx(arm, torch.tensor(rows, dtype=torch.float64, device=dev))
    max_steps = int(max_steps) if max_steps is not None else math.ceil(12 * math.pi * arm.n / step)
    gen = torch.Generator().manual_seed(seed)
    parts = []
    for start in range(0, xt.shape[0], chunk):
        xc = xt[start : start + chunk]
        q0 = (torch.rand(xc.shape[0], seeds, arm.n, generator=gen, dtype=torch.float64) * 2 - 1) * math.pi
        q, conv = ik_seeds(ctx, xc.to(dev), q0.to(dev))
        parts.append(_branches(ctx, xc.to(dev), q, conv, n_points, step, sing_tol, max_steps, correct_iters, tracer))
    return concat(parts, n_points, arm.n)


def _branches(ctx: Ctx, x: torch.Tensor, seeds: torch.Tensor, conv: torch.Tensor, n_points: int, step: float,
              sing_tol: float, max_steps: int, correct_iters: int, tracer: TraceFn = trace,
              first_wave: int = 4) -> SmmSet:
    """The SmmSet of locations x (L, m) from IK seeds (L, S, n) with converged mask.

    Waves: the first traces the lowest `first_wave` seeds of every location;
    each later wave four times as many of the seeds no trace has passed yet
    (on branches still missing). Usually one or two waves.
    """
    n_loc, _, n = seeds.shape
    dev = x.device
    covered = ~conv
    origin = torch.zeros_like(conv)
    waves: list[Traces] = []
    k = first_wave
    while not bool(covered.all()):
        pick = ~covered & (torch.cumsum((~covered).to(torch.long), 1) <= k)
        tr = tracer(ctx, x, seeds, pick, origin, step, sing_tol, max_steps)
        covered |= tr.passed | pick
        origin[tr.loc, tr.seed] = True
        waves.append(tr)
        k *= 4
    loc = torch.cat([w.loc for w in waves]) if waves else torch.zeros(0, dtype=torch.long, device=dev)
    count = torch.bincount(loc, minlength=n_loc)
    singular = torch.zeros(n_loc, dtype=torch.bool, device=dev)
    out = torch.full((n_loc, max(1, int(count.max()) if n_loc else 1), n_points, n), torch.nan,
                     dtype=x.dtype, device=dev)
    slot = torch.zeros(n_loc, dtype=torch.long, device=dev)
    for w in waves:
        branch = resample(w.points, w.length, w.closed, n_points)
        target = x[w.loc][:, None, :].expand(-1, n_points, -1).reshape(-1, x.shape[-1])
        branch = wrap_angle(correct(ctx.arm, branch.reshape(-1, n), target, correct_iters).reshape(branch.shape))
        singular[w.loc[w.singular]] = True
        # Slot within the location: traces of one wave are in seed order per location.
        order = torch.argsort(w.loc, stable=True)
        per = torch.bincount(w.loc, minlength=n_loc)
        rank = torch.empty_like(w.loc)
        rank[order] = torch.arange(w.loc.numel(), device=dev) - (torch.cumsum(per, 0) - per)[w.loc[order]]
        out[w.loc, slot[w.loc] + rank] = branch
        slot += per
    return SmmSet(points=out.cpu().numpy(), count=count.cpu().numpy(), singular=singular.cpu().numpy())
