"""Embarrassingly parallel jobs as shards: in this process, or as Ray tasks on a cluster.

A Job is a module-level shard function fn(params, shard) -> {name: array}
and the job's parameters; a Shard is one piece of it (id, seed, its own
parameters and input arrays). Runner.map runs the shards and returns their
results in shard order:

* Runner() (workers 1, no ray): the serial path, in this process, one shard
  after the other.
* Runner(workers=N), N > 1: a Ray of N CPUs started on this machine;
  Runner(workers=N, pool="process"): N worker processes of this machine
  (concurrent.futures, spawned, one torch thread each), no Ray needed:
  lighter to start, and what `bench shards --pool process` measures.
* Runner(ray="auto" | "HOST:PORT"): the running Ray cluster
  (`ray start --head`, `ray start --address`), see docs/cluster.md.

Every backend calls the same function on the same shard, so the results are
the serial run's whatever the placement: a shard's randomness comes from its
own seed only. With a checkpoint folder (store.ShardStore) every shard is
written to disk as it finishes and a rerun reads the finished ones instead of
computing them again: a job stopped anywhere (Ctrl-C, a lost node, a killed
driver) resumes where it was.

On Ray each shard is a task of num_cpus=1 (Ray sets OMP_NUM_THREADS to match),
num_gpus=1 when the job can use a GPU and the cluster has one (Ray then makes
that GPU the task's visible CUDA device).
A task whose worker dies is retried by Ray (max_retries); a task that raises
ends the job with an ArmbridgeError naming the shard, after the finished ones
are on disk.

Ray is imported only when a Ray backend is asked for: the serial path and the
CLI's start-up do not load it.
"""
from __future__ import annotations

import os
import shutil
import socket
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.shards.progress import ShardBar
from armbridge.shards.store import MANIFEST, ShardStore, digest

Arrays = dict[str, np.ndarray]
ShardFn = Callable[[Mapping[str, Any], "Shard"], Mapping[str, Any]]
OnResult = Callable[["Shard", Arrays], None]
Stop = Callable[["Shard", Arrays], bool]
MAX_RETRIES = 3  # Ray's retries of a task whose worker died
POOLS = ("ray", "process")  # what Runner(workers=N > 1) starts on this machine


@dataclass(frozen=True)
class Shard:
    """One piece of a job: id (its place in the result list), seed, parameters (JSON-able), input arrays."""

    id: int
    seed: Any = 0
    params: Mapping[str, Any] = field(default_factory=dict)
    inputs: Mapping[str, np.ndarray] = field(default_factory=dict)

    @property
    def key(self) -> str:
        """Hash of the whole spec: a shard file made from another spec is refused (store.ShardStore.done)."""
        return digest({"id": self.id, "seed": self.seed, "params": self.params, "inputs": dict(self.inputs)})


@dataclass(frozen=True)
class Job:
    """What the shards run: a module-level fn (Ray sends it by reference), the job's parameters.

    params (JSON-able, arrays allowed) are hashed into the checkpoint's
    manifest; gpu marks a function that uses a CUDA device when it sees one.
    """

    name: str
    fn: ShardFn
    params: Mapping[str, Any] = field(default_factory=dict)
    gpu: bool = False


def execute(fn: ShardFn, params: Mapping[str, Any], shard: Shard) -> tuple[Arrays, dict[str, Any]]:
    """Run one shard: its arrays and a record (seconds, host, pid, device) for the done-log."""
    t0 = time.perf_counter()
    out = {str(k): np.asarray(v) for k, v in fn(params, shard).items()}
    cuda = os.environ.get("CUDA_VISIBLE_DEVICES")
    return out, {"seconds": time.perf_counter() - t0, "host": socket.gethostname(), "pid": os.getpid(),
                 "cuda_visible_devices": cuda}


@dataclass
class Runner:
    """Where shards run (see the module docstring) and where they are checkpointed."""

    ray: str | None = None
    workers: int = 1
    checkpoint: Path | None = None
    progress: bool = False
    pool: str = "ray"
    _started: bool = field(default=False, init=False, repr=False)
    _remote: Any = field(default=None, init=False, repr=False)
    _pool: Any = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.workers, int) or self.workers < 1:
            raise ArmbridgeError(f"--workers must be an integer >= 1, got {self.workers!r}")
        if self.ray is not None and not str(self.ray).strip():
            raise ArmbridgeError("--ray needs 'auto' or the cluster head's address HOST:PORT")
        if self.pool not in POOLS:
            raise ArmbridgeError(f"--pool must be one of {', '.join(POOLS)}, got {self.pool!r}")

    @property
    def backend(self) -> str:
        if self.ray is not None:
            return "ray"
        return "serial" if self.workers == 1 else self.pool

    def start(self) -> None:
        """Start the workers now (a local Ray, or the process pool with torch imported in every
        worker), so that a timed job does not include their start-up. Optional: map starts them."""
        if self.backend == "ray":
            self._connect()
        elif self.backend == "process":
            pool = self._processes()
            list(pool.map(_ready, range(self.workers)))

    def __enter__(self) -> Runner:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        """Disconnect from (or stop, if this runner started it) the Ray this runner initialised; stop
        its process pool."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if self._started:
            import ray

            ray.shutdown()
            self._started = False
            self._remote = None

    def store(self, job: Job, shards: Sequence[Shard]) -> ShardStore | None:
        """The job's checkpoint folder, CHECKPOINT/<job name>; its manifest hashes the job's parameters
        and every shard's spec, so a rerun of another job (or of other shards) there is refused."""
        if self.checkpoint is None:
            return None
        params = {**job.params, "shard_specs": digest([s.key for s in shards])}
        return ShardStore(Path(self.checkpoint) / job.name, job.name, params)

    def discard(self, job: str) -> None:
        """Delete a job's checkpoint folder: for a job whose product is saved (the folder is then
        only a copy of it, and shard files of SMMs are large)."""
        if self.checkpoint is not None:
            folder = Path(self.checkpoint) / job
            if (folder / MANIFEST).exists():
                shutil.rmtree(folder)

    def map(self, job: Job, shards: Sequence[Shard], on_result: OnResult | None = None, stop: Stop | None = None,
            label: str = "") -> list[Arrays]:
        """The shards' results in shard order.

        on_result(shard, arrays) is called in shard order as results come
        in. stop(shard, arrays), also in shard order, may end the job early:
        the shards after the one it accepted are not started (those already
        running are cancelled) and the result list ends there.
        """
        ids = [s.id for s in shards]
        if len(set(ids)) != len(ids):
            raise ArmbridgeError(f"job {job.name}: shard ids must be unique")
        store = self.store(job, shards)
        done = {i for i, s in enumerate(shards) if store is not None and store.done(s.id, s.key)}
        results: list[Arrays | None] = [None] * len(shards)
        delivered = 0
        stopped = False

        def deliver() -> None:
            nonlocal delivered, stopped
            while not stopped and delivered < len(shards):
                i = delivered
                if results[i] is None:
                    if i not in done or store is None:
                        return
                    results[i] = store.read(shards[i].id)
                arrays = results[i]
                assert arrays is not None
                delivered += 1
                if on_result is not None:
                    on_result(shards[i], arrays)
                if stop is not None and stop(shards[i], arrays):
                    stopped = True

        def finished(i: int, arrays: Arrays, record: dict[str, Any]) -> None:
            if store is not None:
                store.write(shards[i].id, shards[i].key, arrays, record)
            results[i] = arrays
            bar.advance()
            deliver()

        todo = [i for i in range(len(shards)) if i not in done]
        with ShardBar(label or job.name, len(shards), len(done), self.progress) as bar:
            deliver()
            if self.backend == "serial":
                bar.cluster("serial, 1 worker")
                for i in todo:
                    if stopped:
                        break
                    if results[i] is None:
                        finished(i, *_call(job, shards[i]))
            elif todo and not stopped and self.backend == "process":
                bar.cluster(f"{self.workers} local processes")
                self._pool_map(job, shards, todo, finished, lambda: stopped)
            elif todo and not stopped:
                self._ray_map(job, shards, todo, finished, lambda: stopped, bar)
            if stopped:
                bar.ended()
        kept = results[:delivered]
        if stop is None and delivered < len(shards):
            raise ArmbridgeError(f"job {job.name}: {len(shards) - delivered} shards have no result")
        return [r for r in kept if r is not None]

    # ------------------------------------------------------------------ processes

    def _processes(self) -> Any:
        if self._pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            # spawn: a fork of a parent with torch's thread pools running can hang
            self._pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                             initializer=_one_thread)
        return self._pool

    def _pool_map(self, job: Job, shards: Sequence[Shard], todo: list[int],
                  finished: Callable[[int, Arrays, dict[str, Any]], None], stopped: Callable[[], bool]) -> None:
        from concurrent.futures import FIRST_COMPLETED, wait

        pool = self._processes()
        queue: Iterator[int] = iter(todo)
        running: dict[Any, int] = {}
        try:
            while True:
                while not stopped() and len(running) < 2 * self.workers:
                    i = next(queue, None)
                    if i is None:
                        break
                    running[pool.submit(execute, job.fn, dict(job.params), shards[i])] = i
                if not running or stopped():
                    break
                ready, _ = wait(list(running), return_when=FIRST_COMPLETED)
                for fut in ready:
                    i = running.pop(fut)
                    try:
                        arrays, record = fut.result()
                    except ArmbridgeError as e:
                        raise type(e)(f"job {job.name}, shard {shards[i].id}: {e}") from None
                    except Exception as e:  # noqa: BLE001 - a worker's error, re-raised with its shard named
                        raise ArmbridgeError(f"job {job.name}, shard {shards[i].id} failed in a worker process: "
                                             f"{type(e).__name__}: {e}") from None
                    finished(i, arrays, record)
        finally:
            for fut in running:
                fut.cancel()

    # ------------------------------------------------------------------ ray

    def _connect(self) -> Any:
        from armbridge.extras import require

        ray = require("ray", "ray", "running shards on Ray (--ray, --workers > 1)")
        if not ray.is_initialized():
            import logging

            if self.ray is not None:
                if self.ray != "auto":
                    reachable(self.ray)
                ray.init(address=self.ray, logging_level=logging.WARNING, log_to_driver=False)
            else:
                ray.init(num_cpus=self.workers, include_dashboard=False, logging_level=logging.WARNING,
                         log_to_driver=False)
            self._started = True
        if self._remote is None:
            self._remote = ray.remote(execute)
        return ray

    def _ray_map(self, job: Job, shards: Sequence[Shard], todo: list[int],
                 finished: Callable[[int, Arrays, dict[str, Any]], None], stopped: Callable[[], bool],
                 bar: ShardBar) -> None:
        try:
            ray = self._connect()
        except ConnectionError as e:
            raise ArmbridgeError(f"--ray {self.ray}: no Ray cluster there ({e}); start one with "
                                 "`ray start --head` (docs/cluster.md)") from None
        res = ray.cluster_resources()
        cpus, gpus = int(res.get("CPU", 0)), int(res.get("GPU", 0))
        nodes = sum(1 for n in ray.nodes() if n.get("Alive"))
        bar.cluster(f"ray, {nodes} node{'s' if nodes != 1 else ''}, {cpus} CPU{'s' if cpus != 1 else ''}"
                    + (f", {gpus} GPU{'s' if gpus != 1 else ''}" if gpus else ""))
        if cpus < 1:
            raise ArmbridgeError(f"--ray {self.ray}: the cluster has no CPUs")
        task = self._remote.options(num_cpus=1, num_gpus=1 if job.gpu and gpus else 0, max_retries=MAX_RETRIES)
        fn_ref, params_ref = ray.put(job.fn), ray.put(dict(job.params))
        window = max(2, 2 * cpus)  # in flight: enough to keep every CPU busy, few to cancel on a stop
        queue: Iterator[int] = iter(todo)
        running: dict[Any, int] = {}
        try:
            while True:
                while not stopped() and len(running) < window:
                    i = next(queue, None)
                    if i is None:
                        break
                    running[task.remote(fn_ref, params_ref, shards[i])] = i
                if not running or stopped():
                    break
                ready, _ = ray.wait(list(running), num_returns=1)
                for ref in ready:
                    i = running.pop(ref)
                    try:
                        arrays, record = ray.get(ref)
                    except Exception as e:  # noqa: BLE001 - a task's error, re-raised with its shard named
                        raise _task_error(job, shards[i], e) from None
                    finished(i, arrays, record)
        finally:
            for ref in running:
                ray.cancel(ref, force=True)


def _one_thread() -> None:
    """A process-pool worker: one thread for numpy's and torch's kernels (the shards are the parallelism;
    a second thread per worker only competes for the same cores)."""
    os.environ["OMP_NUM_THREADS"] = "1"
    try:
        import torch
    except ImportError:
        return
    torch.set_num_threads(1)


def _ready(_: int) -> int:
    return os.getpid()


def reachable(address: str, timeout: float = 5.0) -> None:
    """A clear error at once for a head that is not there (ray.init retries a dead address for minutes)."""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ArmbridgeError(f"--ray {address}: need 'auto' or the cluster head's address HOST:PORT")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as e:
        raise ArmbridgeError(f"--ray {address}: no Ray head answers there ({e}); start one with "
                             "`ray start --head` (docs/cluster.md)") from None


def _call(job: Job, shard: Shard) -> tuple[Arrays, dict[str, Any]]:
    return execute(job.fn, job.params, shard)


def _task_error(job: Job, shard: Shard, e: Exception) -> ArmbridgeError:
    cause = getattr(e, "cause", None) or e
    if isinstance(cause, ArmbridgeError):
        return type(cause)(f"job {job.name}, shard {shard.id}: {cause}")
    return ArmbridgeError(f"job {job.name}, shard {shard.id} failed on the cluster: {type(cause).__name__}: {cause}; "
                          "finished shards are kept in --checkpoint, a rerun resumes from them")
