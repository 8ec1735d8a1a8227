"""Shard results on disk: one .npz per finished shard, a manifest, a done-log.

A folder holds the shards of one job:

* manifest.json: the job's name, its parameters and their hash. A rerun with
  other parameters is refused (its shards would mix with these), so a folder
  is resumed only by the job that made it.
* <id>.npz: a finished shard's arrays, written to a temporary name and moved
  into place (os.replace), so a shard file is either whole or absent, however
  the job was stopped. It also holds "__key", the hash of the shard's own
  spec (seed, parameters, inputs): a file made from another spec is refused.
  Arrays only, read back with allow_pickle=False: the files hold no pickles
  and can travel between machines.
* done.jsonl: one line per shard computed (id, seconds, host, pid, device,
  time), appended after its file is in place. A resumed run appends only the
  shards it computed itself, so the log tells which run did which shard.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError

MANIFEST = "manifest.json"
DONE_LOG = "done.jsonl"
KEY = "__key"
VERSION = 1


def digest(obj: Any) -> str:
    """sha256 of a JSON-able object (sorted keys) with numpy arrays by dtype, shape and bytes."""
    h = hashlib.sha256()
    _feed(h, obj)
    return h.hexdigest()


def _feed(h: Any, obj: Any) -> None:
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(f"array {a.dtype.str} {a.shape}".encode())
        h.update(a.tobytes())
    elif isinstance(obj, Mapping):
        h.update(b"{")
        for k in sorted(obj):
            h.update(json.dumps(str(k)).encode())
            _feed(h, obj[k])
        h.update(b"}")
    elif isinstance(obj, (list, tuple)):
        h.update(b"[")
        for v in obj:
            _feed(h, v)
        h.update(b"]")
    else:
        h.update(json.dumps(obj.item() if isinstance(obj, np.generic) else obj).encode())


class ShardStore:
    """The checkpoint folder of one job (see the module docstring)."""

    def __init__(self, root: str | Path, job: str, params: Mapping[str, Any]):
        self.root = Path(root)
        self.job = job
        self.params_hash = digest({"job": job, "params": params})
        self.root.mkdir(parents=True, exist_ok=True)
        manifest = self.root / MANIFEST
        if manifest.exists():
            try:
                old = json.loads(manifest.read_text())
            except (OSError, ValueError) as e:
                raise ArmbridgeError(f"{manifest}: unreadable shard manifest ({e}); delete the folder to start over") from e
            if old.get("job") != job or old.get("params_hash") != self.params_hash:
                raise ArmbridgeError(
                    f"{self.root} holds shards of job {old.get('job')!r} made with other parameters "
                    f"(hash {str(old.get('params_hash'))[:12]}, this run {self.params_hash[:12]}); "
                    "pass another --checkpoint folder, or delete it to start over")
        else:
            _write_text(manifest, json.dumps({"version": VERSION, "job": job, "params_hash": self.params_hash,
                                              "params": _jsonable(params), "created": time.time()}, indent=2) + "\n")

    def path(self, shard_id: int) -> Path:
        return self.root / f"{int(shard_id):06d}.npz"

    def done(self, shard_id: int, key: str) -> bool:
        """Whether the shard's file is in place; a file of another spec is an error."""
        p = self.path(shard_id)
        if not p.exists():
            return False
        with np.load(p, allow_pickle=False) as z:
            have = str(z[KEY]) if KEY in z.files else ""
        if have != key:
            raise ArmbridgeError(f"{p}: shard {shard_id} was made from another spec (key {have[:12]}, expected "
                                 f"{key[:12]}); delete {self.root} to start over")
        return True

    def write(self, shard_id: int, key: str, arrays: Mapping[str, np.ndarray], record: Mapping[str, Any]) -> None:
        """Write the shard's arrays atomically, then append its line to the done-log."""
        out: dict[str, np.ndarray] = {}
        for name, value in arrays.items():
            a = np.asarray(value)
            if a.dtype.hasobject:
                raise ArmbridgeError(f"shard {shard_id}: result {name!r} is an object array (would need a pickle)")
            out[name] = a
        out[KEY] = np.asarray(key)
        p = self.path(shard_id)
        tmp = p.with_name(f".{p.stem}.{os.getpid()}.tmp.npz")
        np.savez(tmp, allow_pickle=False, **out)  # type: ignore[arg-type]  # (the stub's **kwds: bool)
        os.replace(tmp, p)
        with open(self.root / DONE_LOG, "a") as f:
            f.write(json.dumps({"shard": int(shard_id), **_jsonable(record), "finished": time.time()}) + "\n")

    def read(self, shard_id: int) -> dict[str, np.ndarray]:
        p = self.path(shard_id)
        try:
            with np.load(p, allow_pickle=False) as z:
                return {k: z[k] for k in z.files if k != KEY}
        except (OSError, ValueError) as e:
            raise ArmbridgeError(f"{p}: cannot read shard ({e}); delete it to compute it again") from e

    def log(self) -> list[dict[str, Any]]:
        """The done-log's records, oldest first."""
        p = self.root / DONE_LOG
        if not p.exists():
            return []
        return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return {"array": obj.dtype.str, "shape": list(obj.shape), "sha256": digest(obj)[:16]}
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
