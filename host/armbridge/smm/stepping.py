"""The nullspace tracer's pieces (eq. 1, 6, 18): the arm context, the null vector, IK seeds, the
compacting lock-step tracer and the arc-length resampling.

Apart from smm/nullspace.py (which puts them together into compute()) so
that the shape-static tracer (smm/fused.py) shares exactly these pieces with
the default path: both call Ctx.eval, null_vector and embed, so they step
the same arithmetic and differ only in how they batch it.

The compacting tracer (`trace`, the default and what CI tests): finished
traces keep stepping (masked) until enough of them piled up, then the batch
is compacted to the live ones: fewer ops per step on the CPU, but each
compaction is a host synchronisation and a new shape.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from armbridge.errors import ArmbridgeError
from armbridge.geometry import wrap_angle
from armbridge.robots.dh import DHChain
from armbridge.robots.rotations import rot_from_vec

SING_EVERY = 4
STUCK = 50

def null_vector(jac: torch.Tensor) -> torch.Tensor:
    """Eq. (6): n_i = (-1)^i det(J without column i), i = 1..n; J is (..., n-1, n).

    Polynomial in J, so it varies smoothly along a branch and never flips
    sign away from singular configurations (where it vanishes).
    """
    m, n = jac.shape[-2], jac.shape[-1]
    if n != m + 1:
        raise ArmbridgeError(f"null_vector needs a (n-1) x n Jacobian, got {m} x {n}")
    idx = torch.tensor([[j for j in range(n) if j != i] for i in range(n)], device=jac.device)
    minors = jac[..., :, idx].movedim(-2, -3)  # (..., n, m, m): minor i drops column i
    sign = torch.tensor([(-1.0) ** (i + 1) for i in range(n)], dtype=jac.dtype, device=jac.device)
    return sign * torch.linalg.det(minors)

@dataclass(frozen=True)
class Ctx:
    """The arm with the row weights and targets one computation uses."""

    arm: DHChain
    w: torch.Tensor  # (m,) row weights: 1/L for position rows, 1 for rotation rows

    def eval(self, q: torch.Tensor, x: torch.Tensor, rt: torch.Tensor | None = None
             ) -> tuple[torch.Tensor, torch.Tensor]:
        """Weighted Jacobian W J (..., m, n) and weighted error W dx_e (..., m).

        With rt (target rotations, 'pose' only) the orientation error is
        sin(angle) * axis of R_t R^T: cheaper than the log map and equal to it
        up to angle^3, for the tiny errors met while tracing.
        """
        rot, tip, jac = self.arm.kinematics(q)
        jac = jac * self.w[:, None]
        if rt is None:
            err = self.arm.tip_error(rot, tip, x)
        else:
            re = rt @ rot.transpose(-1, -2)
            vee = torch.stack([re[..., 2, 1] - re[..., 1, 2], re[..., 0, 2] - re[..., 2, 0],
                               re[..., 1, 0] - re[..., 0, 1]], -1) / 2
            err = torch.cat([x[..., :3] - tip, vee], -1)
        return jac, err * self.w

    def target_rotations(self, x: torch.Tensor) -> torch.Tensor | None:
        return rot_from_vec(x[..., 3:]) if self.arm.space == "pose" else None

def ik_seeds(ctx: Ctx, x: torch.Tensor, q: torch.Tensor, iters: int = 150, tol: float = 1e-10
             ) -> tuple[torch.Tensor, torch.Tensor]:
    """Drive configurations q (L, S, n) onto targets x (L, m) by Levenberg-Marquardt.

    Returns (q, converged (L, S)): converged where the weighted error is below
    tol. Seeds leave the batch once converged or stalled (damping at its cap).
    """
    shape = q.shape[:-1]
    q = q.reshape(-1, q.shape[-1]).clone()
    xs = x[:, None, :].expand(*shape, x.shape[-1]).reshape(-1, x.shape[-1])
    conv = torch.zeros(q.shape[0], dtype=torch.bool, device=q.device)
    act = torch.arange(q.shape[0], device=q.device)
    qa, xa = q, xs
    lam = torch.full((q.shape[0],), 1e-2, dtype=q.dtype, device=q.device)
    jac, err = ctx.eval(qa, xa)
    cost = (err * err).sum(-1)
    eye = torch.eye(jac.shape[-2], dtype=q.dtype, device=q.device)
    for _ in range(iters):
        jjt = jac @ jac.transpose(-1, -2) + lam[:, None, None] * eye
        dq = (jac.transpose(-1, -2) @ torch.linalg.solve(jjt, err[..., None]))[..., 0]
        dq = dq * (0.5 / torch.linalg.vector_norm(dq, dim=-1, keepdim=True).clamp_min(0.5))  # at most 0.5 rad
        jac_new, err_new = ctx.eval(qa + dq, xa)
        cost_new = (err_new * err_new).sum(-1)
        better = cost_new < cost
        qa = torch.where(better[:, None], qa + dq, qa)
        jac = torch.where(better[:, None, None], jac_new, jac)
        err = torch.where(better[:, None], err_new, err)
        cost = torch.where(better, cost_new, cost)
        lam = torch.where(better, lam * 0.3, lam * 4).clamp(1e-12, 1e6)
        ok = cost < tol * tol
        out = ok | (lam >= 1e6)
        if bool(out.any()):
            q[act[out]] = qa[out]
            conv[act[out]] = ok[out]
            keep = ~out
            act, qa, xa, jac, err, cost, lam = (v[keep] for v in (act, qa, xa, jac, err, cost, lam))
            if act.numel() == 0:
                break
    q[act] = qa
    return q.reshape(*shape, -1), conv.reshape(shape)

def embed(q: torch.Tensor) -> torch.Tensor:
    """Joints on the circle group, eq. (7), as real pairs: chord distances by dot products."""
    return torch.cat([torch.cos(q), torch.sin(q)], -1)


def start_state(q: torch.Tensor, x: torch.Tensor, seeds: torch.Tensor, pick: torch.Tensor, origin: torch.Tensor,
                loc: torch.Tensor, idx: torch.Tensor, rt_all: torch.Tensor | None, max_steps: int
                ) -> dict[str, torch.Tensor]:
    """The per-trace state both tracers start a wave from (this module's `trace`, fused.py's): where each
    trace began, its target, the seeds it may stop at (picked ones of lower index and earlier origins),
    and its flags, all rows live."""
    a_count, n_seed, dev = q.shape[0], seeds.shape[1], q.device
    st = {
        "start": embed(q),
        "x": x[loc],
        "es": embed(seeds)[loc],  # (A, S, 2n)
        "stopper": (pick[loc] & (torch.arange(n_seed, device=dev)[None, :] < idx[:, None])) | origin[loc],
        "left": torch.zeros(a_count, dtype=torch.bool, device=dev),
        "live": torch.ones(a_count, dtype=torch.bool, device=dev),
        "fin": torch.full((a_count,), max_steps + 1, dtype=torch.long, device=dev),
        "closed": torch.zeros(a_count, dtype=torch.bool, device=dev),
        "stopped": torch.zeros(a_count, dtype=torch.bool, device=dev),
        "singular": torch.zeros(a_count, dtype=torch.bool, device=dev),
        "passed": torch.zeros(a_count, n_seed, dtype=torch.bool, device=dev),
    }
    if rt_all is not None:
        st["rt"] = rt_all[loc]
    return st


@dataclass
class Traces:
    """The loops that one tracing wave kept, one per branch."""

    loc: torch.Tensor  # (T,) location index
    seed: torch.Tensor  # (T,) index of the seed each started from
    points: torch.Tensor  # (T, K, n) unwrapped; rows past `length` are NaN
    length: torch.Tensor  # (T,) valid points
    closed: torch.Tensor  # (T,) bool
    singular: torch.Tensor  # (T,) bool
    passed: torch.Tensor  # (L, S) bool: seeds some trace of the wave passed


def trace(ctx: Ctx, x: torch.Tensor, seeds: torch.Tensor, pick: torch.Tensor, origin: torch.Tensor, step: float,
          sing_tol: float, max_steps: int) -> Traces:
    """Trace the picked seeds (L, S, n) on their targets x (L, m) by eq. (1).

    A trace stops when it passes a picked seed of its location with a lower
    index, or an origin (a seed that started a branch in an earlier wave):
    the rest of its loop is traced from there. The others, one per branch,
    run until they close.

    Finished traces keep stepping (their results ignored) until enough of
    them have piled up to be worth dropping from the batch: fewer indexing
    ops per step.
    """
    n_loc, n_seed, n = seeds.shape
    dev, dt = seeds.device, seeds.dtype
    loc, idx = torch.nonzero(pick, as_tuple=True)
    rt_all = ctx.target_rotations(x)
    a_count = loc.numel()
    # Per trace, written back when the batch is compacted.
    length = torch.full((a_count,), max_steps + 1, dtype=torch.long, device=dev)
    closed = torch.zeros(a_count, dtype=torch.bool, device=dev)
    stopped = torch.zeros_like(closed)
    singular = torch.zeros_like(closed)
    passed = torch.zeros(a_count, n_seed, dtype=torch.bool, device=dev)
    # The active batch.
    rows = torch.arange(a_count, device=dev)
    q = seeds[loc, idx]
    st = start_state(q, x, seeds, pick, origin, loc, idx, rt_all, max_steps)
    hist: list[tuple[torch.Tensor, torch.Tensor]] = [(rows, q)]
    rhs = torch.zeros(a_count, n, 2, dtype=dt, device=dev)
    rhs[:, n - 1, 1] = 1
    jac, _ = ctx.eval(q, st["x"], st.get("rt"))
    u = null_vector(jac)  # eq. (6) fixes the direction; later steps keep its sign
    u = u / torch.linalg.vector_norm(u, dim=-1, keepdim=True).clamp_min(1e-300)
    # Chord^2 = 2n - 2 e.s, about the wrapped distance^2: near means e.s > n - step^2 / 2.
    near, far = n - step * step / 2, n - 9 * step * step / 2
    pending = 0

    def write_back() -> None:
        length[rows] = torch.minimum(st["fin"] + 1, length[rows])
        for name, out in (("closed", closed), ("stopped", stopped), ("singular", singular), ("passed", passed)):
            out[rows] |= st[name]

    for t in range(max_steps + 1):
        e = embed(q)
        # Only a live trace passes seeds: a finished one still stepping until the next compaction
        # must not, or what a wave covers would depend on when the batch was compacted.
        hit = ((st["es"] @ e[:, :, None])[..., 0] > near) & st["live"][:, None]
        st["passed"] |= hit
        stop = (hit & st["stopper"]).any(-1)
        dot = (st["start"] * e).sum(-1)
        st["left"] |= dot < far
        done = st["left"] & (dot > near) & ~stop
        # Not away from the start after STUCK steps: caught at a singular configuration (where
        # the null space is 2-D and the tangent dithers) or on a loop a few steps around. Ends
        # open, so the location is flagged singular.
        stuck = ~st["left"] & (t >= STUCK)
        finished = (stop | done | stuck) & st["live"]
        st["stopped"] |= finished & stop
        st["closed"] |= finished & done
        st["fin"] = torch.where(finished, t, st["fin"])
        st["live"] &= ~finished
        pending += 1
        if t == max_steps:
            break
        if pending >= 16 or t < 16:
            pending = 0
            live = st["live"]
            n_live = int(live.sum())
            if n_live == 0:
                break
            if n_live < 0.9 * live.numel():
                write_back()
                rows, q, u, rhs = rows[live], q[live], u[live], rhs[live]
                st = {k: v[live] for k, v in st.items()}
        jac, err = ctx.eval(q, st["x"], st.get("rt"))
        if t % SING_EVERY == 0:
            # Smallest singular value of W J from the eigenvalues of W J J^T W.
            sing = torch.linalg.eigvalsh(jac @ jac.transpose(-1, -2))[..., 0] < sing_tol**2
            st["singular"] |= sing & st["live"]
        rhs[:, : n - 1, 0] = err
        y = torch.linalg.solve(torch.cat([jac, u[:, None, :]], -2), rhs)
        tangent = y[..., 1] / torch.linalg.vector_norm(y[..., 1], dim=-1, keepdim=True).clamp_min(1e-300)
        corr = y[..., 0] - (y[..., 0] * tangent).sum(-1, keepdim=True) * tangent  # J^+ dx_e
        q = q + step * tangent + corr  # eq. (1)
        u = tangent
        hist.append((rows, q))
    write_back()
    kept = torch.nonzero(~stopped)[:, 0]
    slot = torch.full((a_count,), -1, dtype=torch.long, device=dev)
    slot[kept] = torch.arange(kept.numel(), device=dev)
    k_max = int(length[kept].max()) if kept.numel() else 1
    points = torch.full((kept.numel(), k_max, n), torch.nan, dtype=dt, device=dev)
    r_all = torch.cat([r for r, _ in hist])
    t_all = torch.cat([torch.full_like(r, t) for t, (r, _) in enumerate(hist)])
    m = (slot[r_all] >= 0) & (t_all < length[r_all])
    points[slot[r_all[m]], t_all[m]] = torch.cat([qt for _, qt in hist])[m]
    by_loc = torch.zeros(n_loc, n_seed, dtype=torch.long, device=dev).index_add_(0, loc, passed.to(torch.long)) > 0
    length = length.clamp_max(max_steps + 1)
    return Traces(loc=loc[kept], seed=idx[kept], points=points, length=length[kept], closed=closed[kept],
                  singular=singular[kept] | ~closed[kept], passed=by_loc)

def resample(points: torch.Tensor, length: torch.Tensor, closed: torch.Tensor, n_points: int) -> torch.Tensor:
    """n_points uniformly in arc length along unwrapped traces (T, K, n).

    A closed trace gets its closing segment back to the start (shifted by
    whole turns where the loop winds around a joint) and n_points over the
    whole loop, starting at the first point; an open trace is sampled from
    its first to its last point.
    """
    t_count, k, n = points.shape
    idx = torch.arange(k, device=points.device)
    last = points[torch.arange(t_count, device=points.device), length - 1]
    end = torch.where(closed[:, None], last + wrap_angle(points[:, 0] - last), last)
    pts = torch.where((idx[None, :] < length[:, None])[..., None], points, end[:, None, :])
    pts = torch.cat([pts, end[:, None, :]], 1)
    seg = torch.linalg.vector_norm(pts[:, 1:] - pts[:, :-1], dim=-1)
    s = torch.cat([torch.zeros(t_count, 1, dtype=pts.dtype, device=pts.device), torch.cumsum(seg, 1)], 1)
    frac = torch.arange(n_points, dtype=pts.dtype, device=pts.device)
    frac = torch.where(closed[:, None], frac / n_points, frac / max(n_points - 1, 1))
    target = s[:, -1:] * frac
    j = (torch.searchsorted(s.contiguous(), target.contiguous(), right=True) - 1).clamp(0, k - 1)
    s0 = torch.gather(s, 1, j)
    ds = torch.gather(seg, 1, j)
    u = torch.where(ds > 0, (target - s0) / ds.clamp_min(1e-300), torch.zeros_like(ds))
    p0 = torch.gather(pts, 1, j[..., None].expand(-1, -1, n))
    p1 = torch.gather(pts, 1, (j + 1)[..., None].expand(-1, -1, n))
    return p0 + u[..., None] * (p1 - p0)
