"""Reading and running a flat int8 MLP weight file (format: `ik.export`'s docstring), numpy only.

Kept apart from `ik.export` (which needs torch to write the file) so the runtime
and the benchmarks can run the board's int8 net without the `train` extra.
"""
from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError

FLAT_MAGIC = b"AWI8"
FLAT_VERSION = 1


def read_flat_int8(path: Path) -> list[dict[str, Any]]:
    """Parse a flat int8 file: per layer rows, cols, activation, scale, bias, weight (int8)."""
    data = Path(path).read_bytes()
    if data[:4] != FLAT_MAGIC:
        raise ArmbridgeError(f"{path}: not a flat int8 weight file (magic {data[:4]!r})")
    version, n_layers, _n_in, _n_out = struct.unpack_from("<HHHH", data, 4)
    if version != FLAT_VERSION:
        raise ArmbridgeError(f"{path}: flat int8 version {version}, this reader knows {FLAT_VERSION}")
    off = 12
    layers = []
    for _ in range(n_layers):
        rows, cols, act = struct.unpack_from("<HHB3x", data, off)
        off += 8
        scale = np.frombuffer(data, "<f4", rows, off)
        off += 4 * rows
        bias = np.frombuffer(data, "<f4", rows, off)
        off += 4 * rows
        w = np.frombuffer(data, np.int8, rows * cols, off).reshape(rows, cols)
        off += rows * cols
        off += -off % 4
        layers.append({"rows": rows, "cols": cols, "activation": act, "scale": scale, "bias": bias, "weight": w})
    return layers


def flat_int8_forward(layers: list[dict[str, Any]], features: np.ndarray) -> np.ndarray:
    """Reference forward pass of the flat int8 MLP on features (B, n_in) -> z (B, n_out)."""
    h = np.asarray(features, dtype=np.float32)
    for lay in layers:
        h = (h @ lay["weight"].T.astype(np.float32)) * lay["scale"] + lay["bias"]
        a = lay["activation"]
        if a == 1:
            h = np.where(h > 0, h, 0.01 * h)
        elif a == 2:
            h = np.maximum(h, 0)
        elif a == 3:
            h = np.tanh(h)
        elif a == 4:
            h = h / (1 + np.exp(-h))
    return h
