"""The shape-static nullspace tracer: fixed-size batches, one host synchronisation per block of
steps, and on CUDA each block replayed as a CUDA graph.

Why: on a GPU the compacting tracer (stepping.trace) is bound by kernel
launches (about 177 a step) and by a host synchronisation each step (the
live count that decides when to compact), not by arithmetic: an H200 spent
about 2 ms a step at every batch size (issue 27). Here

- the batch has a fixed size B: a finished trace is masked (its q and
  tangent frozen, it passes no seed), not removed, so every step has the same
  shapes and no data-dependent control flow;
- batch sizes are powers of two (at least MIN_BATCH on CUDA), the rows past the
  traces dead from the start; the host looks at the batch once per block of
  BLOCK steps (is any trace live, how many): when at most half are live the
  batch moves to the next smaller power of two that holds them (a few sizes
  per wave, each its own graph, reused by the next waves and chunks);
- nothing in a step synchronises: the linear solve is solve_ex without its
  error check, and the singular test is a Cholesky factorisation of
  W J J^T W - sing_tol^2 I (it fails exactly when the smallest singular value
  of W J is below sing_tol, the module doc of nullspace), cholesky_ex
  reporting failure in a tensor instead of raising;
- on CUDA a block of BLOCK steps is captured once per batch size
  (torch.cuda.CUDAGraph) and replayed: one launch per block.

A trace steps exactly the arithmetic of stepping.trace (eq. 1 with eq. 6's
sign fixed by the first step, eq. 18's J^+ dx_e in the same solve), so it
gives the same loops: the tests compare branch counts, singular flags and
points (within 1e-8) with the compacting path on the CPU, where the graphs
are off. The stop, closure and stuck rules are stepping.trace's.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import torch

from armbridge.smm.stepping import SING_EVERY, STUCK, Ctx, Traces, embed, null_vector, start_state

BLOCK = 16  # steps between two looks of the host (a multiple of SING_EVERY)
MIN_BATCH = 64  # smallest batch size on CUDA (fewer sizes, fewer graphs; on the CPU a dead row costs its ops)


def _bucket(n_live: int, floor: int) -> int:
    """The power of two that holds n_live rows, at least floor."""
    return max(floor, 1 << max(0, n_live - 1).bit_length())


@dataclass
class _Block:
    """One batch size's state (fixed tensors, updated in place) and, on CUDA, its captured graph."""

    state: dict[str, torch.Tensor]
    size: int
    graph: torch.cuda.CUDAGraph | None = None


def _run_block(ctx: Ctx, st: dict[str, torch.Tensor], step: float, sing_tol: float, max_steps: int) -> None:
    """BLOCK steps of eq. (1) on the state, in place; st["hist"][k] gets q after step k + 1.

    No host synchronisation: every decision is a mask. A trace finished at
    step t keeps fin = t and is frozen from then on.
    """
    n = st["q"].shape[-1]
    near, far = n - step * step / 2, n - 9 * step * step / 2
    q, u, t0 = st["q"], st["u"], st["t"]
    live, left, fin = st["live"], st["left"], st["fin"]
    closed, stopped, singular, passed = st["closed"], st["stopped"], st["singular"], st["passed"]
    rt = st.get("rt")
    b = q.shape[0]
    e_last = torch.zeros(b, n, 1, dtype=q.dtype, device=q.device)
    e_last[:, n - 1, 0] = 1
    eye = torch.eye(ctx.w.numel(), dtype=q.dtype, device=q.device)
    for k in range(BLOCK):
        t = t0 + k
        e = embed(q)
        hit = ((st["es"] @ e[:, :, None])[..., 0] > near) & live[:, None]
        passed = passed | hit
        stop = (hit & st["stopper"]).any(-1)
        dot = (st["start"] * e).sum(-1)
        left = left | (dot < far)
        done = left & (dot > near) & ~stop
        stuck = ~left & (t >= STUCK)
        finished = (stop | done | stuck) & live
        stopped = stopped | (finished & stop)
        closed = closed | (finished & done)
        fin = torch.where(finished, t, fin)
        live = live & ~finished & (t < max_steps)  # at max_steps: checked, never stepped (stepping.trace)
        jac, err = ctx.eval(q, st["x"], rt)
        if k % SING_EVERY == 0:  # block starts are multiples of BLOCK, so this is t % SING_EVERY == 0
            info = torch.linalg.cholesky_ex(jac @ jac.transpose(-1, -2) - sing_tol**2 * eye).info
            singular = singular | ((info > 0) & live)
        rhs = torch.cat([torch.cat([err[..., None], torch.zeros_like(err[:, :1, None])], -2), e_last], -1)
        y = torch.linalg.solve_ex(torch.cat([jac, u[:, None, :]], -2), rhs).result
        tangent = y[..., 1] / torch.linalg.vector_norm(y[..., 1], dim=-1, keepdim=True).clamp_min(1e-300)
        corr = y[..., 0] - (y[..., 0] * tangent).sum(-1, keepdim=True) * tangent  # J^+ dx_e
        q = torch.where(live[:, None], q + step * tangent + corr, q)  # eq. (1)
        u = torch.where(live[:, None], tangent, u)
        st["hist"][k].copy_(q)
    for name, v in (("q", q), ("u", u), ("live", live), ("left", left), ("fin", fin), ("closed", closed),
                    ("stopped", stopped), ("singular", singular), ("passed", passed)):
        st[name].copy_(v)
    t0.add_(BLOCK)


@dataclass
class Tracer:
    """stepping.trace's contract (nullspace._branches calls it per wave), shape-static.

    graphs: capture each batch size's block as a CUDA graph (CUDA only; on
    the CPU there is nothing to capture; a capture that fails turns them off,
    capture_error says why). `captured` counts the graphs made,
    `blocks` the blocks run, `sizes` the batch sizes in the order used
    (measurements for the benches and tests).
    """

    graphs: bool = False
    capture_error: str | None = None  # why graphs were turned off (a capture failed), if they were
    sync_free: bool | None = None  # CUDA: a block ran with no host synchronisation (checked once)
    sync_error: str | None = None
    captured: int = 0
    blocks: int = 0
    sizes: list[int] = field(default_factory=list)
    _graphs: dict[tuple[object, ...], tuple[Ctx, _Block]] = field(default_factory=dict, repr=False)

    def __call__(self, ctx: Ctx, x: torch.Tensor, seeds: torch.Tensor, pick: torch.Tensor, origin: torch.Tensor,
                 step: float, sing_tol: float, max_steps: int) -> Traces:
        n_loc, n_seed, n = seeds.shape
        dev, dt = seeds.device, seeds.dtype
        loc, idx = torch.nonzero(pick, as_tuple=True)
        a_count = loc.numel()
        if a_count == 0:
            return _traces(loc, idx, loc, {k: loc.bool() for k in ("closed", "stopped", "singular")},
                           torch.zeros(0, n_seed, dtype=torch.bool, device=dev), [], n_loc, n_seed, n, dt)
        rt_all = ctx.target_rotations(x)
        # Results per trace, written when a batch shrinks and at the end; the last entry, `sink`, takes the
        # padding rows' (a batch is a power of two; its rows past the traces are dead and written there).
        sink = a_count
        length = torch.full((a_count + 1,), max_steps + 1, dtype=torch.long, device=dev)
        flags = {k: torch.zeros(a_count + 1, dtype=torch.bool, device=dev) for k in ("closed", "stopped", "singular")}
        passed = torch.zeros(a_count + 1, n_seed, dtype=torch.bool, device=dev)
        q = seeds[loc, idx]
        jac, _ = ctx.eval(q, x[loc], None if rt_all is None else rt_all[loc])
        u = null_vector(jac)  # eq. (6) fixes the direction; later steps keep its sign
        u = u / torch.linalg.vector_norm(u, dim=-1, keepdim=True).clamp_min(1e-300)
        full = {"q": q, "u": u, **start_state(q, x, seeds, pick, origin, loc, idx, rt_all, max_steps)}
        hist: list[tuple[torch.Tensor, int, torch.Tensor]] = [(torch.arange(a_count, device=dev), 0, q[None])]
        rows = torch.arange(a_count, device=dev)  # trace of each row of `full` (sink: padding)
        live_rows = torch.arange(a_count, device=dev)  # rows of `full` live at the block's start
        blk: _Block | None = None
        t = 0

        def write_back(st: dict[str, torch.Tensor], rows: torch.Tensor) -> None:
            # real traces appear once in rows, so these scatters have no duplicate index but the sink's
            length[rows] = torch.minimum(st["fin"] + 1, length[rows])
            for name, out in flags.items():
                out[rows] |= st[name]
            passed[rows] |= st["passed"]

        while t <= max_steps:
            n_live = live_rows.numel()  # counted at the last look (one synchronisation per block)
            if n_live == 0:
                break
            size = _bucket(n_live, MIN_BATCH if dev.type == "cuda" else 1)
            if blk is None or size < blk.size:
                if blk is not None:
                    write_back(blk.state, rows)
                    full = blk.state
                # live rows first, then padding: rows of the source (frozen, numerically sane) written to the sink
                src = torch.cat([live_rows, live_rows[:1].expand(size - n_live)])
                rows = torch.cat([rows[live_rows], torch.full((size - n_live,), sink, dtype=torch.long, device=dev)])
                state = {k: v[src] for k, v in full.items() if k not in ("hist", "t")}
                state["live"][n_live:] = False
                blk = self._block(ctx, state, t, step, sing_tol, max_steps)
                self.sizes.append(size)
                live_rows = torch.arange(n_live, device=dev)
            st = blk.state
            if self.sync_free is None and st["q"].is_cuda:
                self._check_sync(ctx, st, step, sing_tol, max_steps)
            if blk.graph is not None:
                blk.graph.replay()
            else:
                _run_block(ctx, st, step, sing_tol, max_steps)
            self.blocks += 1
            hist.append((rows[live_rows], t + 1, st["hist"][:, live_rows]))  # indexing copies
            t += BLOCK
            live_rows = torch.nonzero(st["live"])[:, 0]  # the block's one synchronisation
        if blk is not None:
            write_back(blk.state, rows)
        return _traces(loc, idx, length[:a_count].clamp_max(max_steps + 1), {k: v[:a_count] for k, v in flags.items()},
                       passed[:a_count], hist, n_loc, n_seed, n, dt)

    def _check_sync(self, ctx: Ctx, st: dict[str, torch.Tensor], step: float, sing_tol: float, max_steps: int
                    ) -> None:
        """Whether a block runs without a host synchronisation: one block on a copy of the state with
        torch's sync debug mode set to raise (sets sync_free, and sync_error on failure)."""
        mode = torch.cuda.get_sync_debug_mode()
        torch.cuda.set_sync_debug_mode("error")
        try:
            _run_block(ctx, {k: v.clone() for k, v in st.items()}, step, sing_tol, max_steps)
            self.sync_free = True
        except RuntimeError as e:
            self.sync_free, self.sync_error = False, str(e).splitlines()[0]
        finally:
            torch.cuda.set_sync_debug_mode(mode)

    def _block(self, ctx: Ctx, state: dict[str, torch.Tensor], t: int, step: float, sing_tol: float,
               max_steps: int) -> _Block:
        """The block runner of this state at step t: eager, or a CUDA graph. A graph captured for this batch
        size (and arm, seeds per location, step settings) is reused across waves and chunks, its buffers
        loaded with the state; a new one is warmed up on a copy first, so the capture leaves the state as
        it was."""
        state["t"] = torch.tensor(t, dtype=torch.long, device=state["q"].device)
        size, n = state["q"].shape
        state["hist"] = torch.empty(BLOCK, size, n, dtype=state["q"].dtype, device=state["q"].device)
        if not (self.graphs and state["q"].is_cuda):
            return _Block(state, size)
        key = (size, tuple((k, tuple(v.shape)) for k, v in sorted(state.items())), step, sing_tol, max_steps)
        cached = self._graphs.get(key)
        if cached is not None and cached[0] is ctx:
            blk = cached[1]
            for k, v in state.items():
                blk.state[k].copy_(v)
            return blk
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            _run_block(ctx, {k: v.clone() for k, v in state.items()}, step, sing_tol, max_steps)
        torch.cuda.current_stream().wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        try:
            with torch.cuda.graph(graph):
                _run_block(ctx, state, step, sing_tol, max_steps)
        except Exception as e:  # noqa: BLE001 - an op that cannot be captured (a batched solver): run eager
            self.graphs, self.capture_error = False, f"{type(e).__name__}: {str(e).splitlines()[0]}"
            self._graphs.clear()
            torch.cuda.synchronize()
            return _Block(state, size)
        self.captured += 1
        self._graphs[key] = (ctx, _Block(state, size, graph))
        return self._graphs[key][1]


def _traces(loc: torch.Tensor, idx: torch.Tensor, length: torch.Tensor, flags: dict[str, torch.Tensor],
            passed: torch.Tensor, hist: list[tuple[torch.Tensor, int, torch.Tensor]], n_loc: int, n_seed: int,
            n: int, dt: torch.dtype) -> Traces:
    """stepping.trace's result from the recorded blocks: the traces that were not stopped, their points."""
    dev = loc.device
    closed, stopped, singular = flags["closed"], flags["stopped"], flags["singular"]
    kept = torch.nonzero(~stopped)[:, 0]
    slot = torch.full((loc.numel(),), -1, dtype=torch.long, device=dev)
    slot[kept] = torch.arange(kept.numel(), device=dev)
    k_max = int(length[kept].max()) if kept.numel() else 1
    points = torch.full((kept.numel(), k_max, n), torch.nan, dtype=dt, device=dev)
    for r, t0, block in hist:  # block (K, R, n): q at steps t0 .. t0 + K - 1 of the traces r
        steps = t0 + torch.arange(block.shape[0], device=dev)
        m = (slot[r][None, :] >= 0) & (steps[:, None] < length[r][None, :])
        k_idx, r_idx = torch.nonzero(m, as_tuple=True)
        points[slot[r[r_idx]], steps[k_idx]] = block[k_idx, r_idx]
    by_loc = torch.zeros(n_loc, n_seed, dtype=torch.long, device=dev).index_add_(0, loc, passed.to(torch.long)) > 0
    return Traces(loc=loc[kept], seed=idx[kept], points=points, length=length[kept], closed=closed[kept],
                  singular=singular[kept] | ~closed[kept], passed=by_loc)
