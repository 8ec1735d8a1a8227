"""Export a trained MASR IK-NN: float ONNX, int8 ONNX, flat int8 weights, model card.

Files, for a model called NAME in the output folder:

- NAME.onnx: float32, input "input" (batch, 3 + n + 1) = (x, y, phi, theta_c, d_c)
  in SI units, output "q" (batch, n + 1); input features and the output map
  into the limits are part of the graph. Exported with the dynamo exporter,
  dynamic batch, no external data file.
- NAME-int8.onnx: the better (by measured accuracy) of two int8 schemes:
  "weight-only": every Linear weight stored as int8 with one float scale per
  output row and a DequantizeLinear in front of its matmul (activations stay
  float); "ort-dynamic": onnxruntime's quant_pre_process + quantize_dynamic
  (int8 weights and dynamically quantised uint8 activations). Both are measured
  and the card records both.
- NAME-int8.bin: the weight-only int8 MLP as a flat little-endian file that a
  MicroPython board can read with `struct` (format below; docs/models.md).
- NAME.json: the model card.

Flat int8 format (version 1), little-endian:

    b"AWI8"  u16 version=1  u16 n_layers  u16 n_in  u16 n_out
    per layer: u16 rows  u16 cols  u8 activation  u8[3] pad
               f32 scale[rows]  f32 bias[rows]  i8 weight[rows * cols] (row-major)
               zero padding to a multiple of 4 bytes
    activation: 0 none, 1 leaky_relu(0.01), 2 relu, 3 tanh, 4 silu

    y = act(scale[r] * sum_c weight[r, c] * x[c] + bias[r])

The layers take the features [x/l, y/l, cos phi, sin phi, theta_c/theta_b,
2 d_c/l - 1] and the last layer's z maps to theta = theta_b tanh(z_theta),
d = l sigmoid(z_d) (card "scaling").
"""
from __future__ import annotations

import hashlib
import struct
import tempfile
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np
import torch

from armbridge.errors import ArmbridgeError
from armbridge.ik.flat_int8 import FLAT_MAGIC, FLAT_VERSION, flat_int8_forward, read_flat_int8  # noqa: F401

class ExportableMLP(Protocol):
    """What the exporters need of a network (the MASR IK-NN, the 3R arm's ANN):
    an nn.Module whose Linear layers, in order, hold its weights, with one
    activation (a key of ACT_CODES) between them."""

    activation: str

    def linear_layers(self) -> list[torch.nn.Linear]: ...

    def eval(self) -> Any: ...


ACT_CODES = {"none": 0, "leaky_relu": 1, "relu": 2, "tanh": 3, "silu": 4}


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def file_entry(path: Path, folder: Path) -> dict[str, Any]:
    return {"path": str(Path(path).relative_to(folder)), "sha256": sha256(path), "bytes": Path(path).stat().st_size}


# ------------------------------------------------------------------ float ONNX


def export_float(model: ExportableMLP, path: Path, example: torch.Tensor | None = None) -> Path:
    """Dynamo export, dynamic batch, weights inside the .onnx; example: an input batch of
    two rows (default: the MASR IK-NN's; the 3R arm's ANN passes its own)."""
    model = model.eval()
    if example is None:  # the MASR IK-NN's input: n + 4 features
        n = int(getattr(model, "n"))
        example = torch.zeros(2, n + 4)
        example[:, n + 3] = 0.1
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(
        cast(torch.nn.Module, model),
        (example,),
        str(path),
        dynamo=True,
        external_data=False,
        input_names=["input"],
        output_names=["q"],
        dynamic_shapes=({0: "batch"},),
        verbose=False,
    )
    side = Path(str(path) + ".data")
    if side.exists():
        raise ArmbridgeError(f"ONNX export wrote a side file {side}; expected weights inside the model")
    return path


# ------------------------------------------------------------ int8 quantisation


def quantize_rows(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric per-row int8: w ~ scale[:, None] * q, q in [-127, 127]."""
    w = np.asarray(w, dtype=np.float64)
    amax = np.abs(w).max(axis=1)
    scale = np.where(amax > 0, amax / 127.0, 1.0)
    q = np.clip(np.round(w / scale[:, None]), -127, 127).astype(np.int8)
    return q, scale.astype(np.float32)


def export_weight_only_int8(model: ExportableMLP, float_path: Path, path: Path) -> Path:
    """The float ONNX with every Linear weight replaced by int8 + per-row scale + DequantizeLinear."""
    import onnx
    from onnx import helper, numpy_helper

    m = onnx.load(str(float_path))
    g = m.graph
    weights = [lin.weight.detach().numpy() for lin in model.linear_layers()]
    inits = {init.name: init for init in g.initializer}
    new_nodes = []
    done = 0
    for init in list(g.initializer):
        a = numpy_helper.to_array(init)
        if a.ndim != 2:
            continue
        match = [i for i, w in enumerate(weights) if (w.shape == a.shape and np.array_equal(w, a)) or (w.shape == a.T.shape and np.array_equal(w.T, a))]
        if not match:
            continue
        w = weights[match[0]]
        transposed = w.shape != a.shape or not np.array_equal(w, a)
        q, scale = quantize_rows(w)
        q_arr = q.T if transposed else q
        axis = 1 if transposed else 0
        qn, sn, zn = init.name + "_int8", init.name + "_scale", init.name + "_zero"
        g.initializer.remove(inits[init.name])
        g.initializer.extend([
            numpy_helper.from_array(np.ascontiguousarray(q_arr), qn),
            numpy_helper.from_array(scale, sn),
            numpy_helper.from_array(np.zeros(scale.shape, np.int8), zn),
        ])
        new_nodes.append(helper.make_node("DequantizeLinear", [qn, sn, zn], [init.name], axis=axis, name=init.name + "_dq"))
        done += 1
    if done != len(weights):
        raise ArmbridgeError(f"weight-only int8: found {done} of {len(weights)} Linear weights in {float_path}")
    nodes = list(g.node)
    del g.node[:]
    g.node.extend(new_nodes + nodes)
    onnx.checker.check_model(m)
    onnx.save(m, str(path))
    return path


def export_ort_dynamic_int8(float_path: Path, path: Path) -> Path:
    """onnxruntime quant_pre_process, then quantize_dynamic (QInt8 weights)."""
    from onnxruntime.quantization import QuantType, quantize_dynamic  # type: ignore[import-untyped]
    from onnxruntime.quantization.shape_inference import quant_pre_process  # type: ignore[import-untyped]

    with tempfile.TemporaryDirectory() as tmp:
        pre = Path(tmp) / "pre.onnx"
        quant_pre_process(str(float_path), str(pre), skip_symbolic_shape=True)
        quantize_dynamic(str(pre), str(path), weight_type=QuantType.QInt8, per_channel=False)
    return path


def write_flat_int8(model: ExportableMLP, path: Path) -> Path:
    """The weight-only int8 MLP in the flat format of the module docstring."""
    layers = model.linear_layers()
    act = ACT_CODES[model.activation]
    buf = bytearray(FLAT_MAGIC)
    buf += struct.pack("<HHHH", FLAT_VERSION, len(layers), layers[0].in_features, layers[-1].out_features)
    for i, lin in enumerate(layers):
        q, scale = quantize_rows(lin.weight.detach().numpy())
        rows, cols = q.shape
        buf += struct.pack("<HHB3x", rows, cols, act if i < len(layers) - 1 else 0)
        buf += scale.astype("<f4").tobytes()
        buf += lin.bias.detach().numpy().astype("<f4").tobytes()
        buf += q.tobytes()
        buf += b"\x00" * (-len(buf) % 4)
    path.write_bytes(bytes(buf))
    return path


def flat_int8_solve(layers: list[dict[str, Any]], card: dict[str, Any], x_goal: np.ndarray, q_c: np.ndarray) -> np.ndarray:
    """What a board computes: features from the card's scaling, the int8 MLP, the output map."""
    sc = card["scaling"]
    length, tb = float(sc["total_length"]), np.asarray(sc["theta_b"], dtype=np.float32)
    n = tb.size
    feats = np.concatenate([
        x_goal[:, :2] / length, np.cos(x_goal[:, 2:3]), np.sin(x_goal[:, 2:3]),
        q_c[:, :n] / tb, q_c[:, n:] * (2 / length) - 1,
    ], axis=1)
    z = flat_int8_forward(layers, feats)
    return np.concatenate([tb * np.tanh(z[:, :n]), length / (1 + np.exp(-z[:, n:]))], axis=1)


def onnx_run(path: Path, inp: np.ndarray) -> np.ndarray:
    import onnxruntime as ort  # type: ignore[import-untyped]

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    return sess.run(None, {sess.get_inputs()[0].name: np.ascontiguousarray(inp, dtype=np.float32)})[0]
