"""The flat int8 MLP on the board: the IK net of ik3r.py (issue 10 section 3).

The file is the host's flat int8 format (host/armbridge/ik/export.py docstring,
written by write_flat_int8, read there by ik/flat_int8.py), little-endian:

    b"AWI8"  u16 version=1  u16 n_layers  u16 n_in  u16 n_out
    per layer: u16 rows  u16 cols  u8 activation  u8[3] pad
               f32 scale[rows]  f32 bias[rows]  i8 weight[rows * cols] (row-major)
               zero padding to a multiple of 4 bytes
    activation: 0 none, 1 leaky_relu(0.01), 2 relu, 3 tanh, 4 silu

It is parsed once into `array` buffers (int8 weights stay int8: 1 byte per
weight in RAM). The forward pass keeps the multiply-adds in integers: each
layer's input vector is quantised with one scale (x_q = round(x * Q / max|x|),
Q = levels(cols)), the product with the int8 weights is exact, and
y = scale[r] * (max|x| / Q) * acc[r] + bias[r]. Integers are what viper runs
natively on the chip and what allocates nothing under the bytecode VM; with
|acc| <= 127 * Q * cols < 2**30 they stay small ints / machine words. The host's
numpy reference is host/armbridge/ik/board_ik.py (board_forward): same steps.

`_dot_viper` is the viper kernel (at most four arguments, so the shape is
packed as rows << 16 | cols; ptr8 reads bytes unsigned, hence the sign
fix ((b + 128) & 255) - 128, which is also right for signed values); where the
native emitter is missing (the WebAssembly port strips the decorator, CPython
runs it as plain Python) `NATIVE` is False and the plain `_dot_plain` runs.
"""

import math
import struct
from array import array

import micropython

MAGIC = b"AWI8"
VERSION = 1
ACC_LIMIT = 1073741823  # 2**30 - 1: MicroPython's small-int range on a 32-bit port
Q_MAX = 32767
ACTIVATIONS = (0, 1, 2, 3, 4)

try:
    ptr8  # viper's pointer types are names only the native compiler knows
except NameError:
    globals()["ptr8"] = globals()["ptr32"] = None  # CPython evaluates annotations at def time


def levels(cols: int) -> int:
    """Q of a layer with `cols` inputs: the largest <= Q_MAX with 127 * Q * cols <= 2**30 - 1."""
    q = ACC_LIMIT // (127 * cols)
    return Q_MAX if q > Q_MAX else q


@micropython.viper
def _wraps() -> int:
    x = 0x20000000
    x = x + x
    x = x + x  # 2**31: a 32-bit machine word wraps negative, a Python int does not
    return x


@micropython.viper
def _dot_viper(w: ptr8, x: ptr32, acc: ptr32, shape: int):
    rows = shape >> 16
    cols = shape & 0xFFFF
    i = 0
    r = 0
    while r < rows:
        s = 0
        c = 0
        while c < cols:
            s += (((w[i] + 128) & 255) - 128) * x[c]
            i += 1
            c += 1
        acc[r] = s
        r += 1


def _dot_plain(w, x, acc, shape):
    rows = shape >> 16
    cols = shape & 0xFFFF
    nz = [c for c in range(cols) if x[c]]  # after a ReLU about half the inputs are 0:
    i = 0
    if 3 * len(nz) < 2 * cols:  # skip them (a sparse step costs about 1.5 dense ones)
        for r in range(rows):
            s = 0
            for c in nz:
                s += w[i + c] * x[c]
            acc[r] = s
            i += cols
        return
    mv = memoryview(w)
    for r in range(rows):
        s = 0
        c = 0
        for b in mv[i:i + cols]:  # a C iterator over the int8 row: the cheapest loop the VM has
            s += b * x[c]
            c += 1
        acc[r] = s
        i += cols


NATIVE = _wraps() < 0
_dot = _dot_viper if NATIVE else _dot_plain


class FlatMLP:
    """A flat int8 file parsed into arrays; forward(x) -> list of n_out floats."""

    def __init__(self, data) -> None:
        if data is None:
            raise ValueError("no weight file")
        n = len(data)
        if n < 12 or data[:4] != MAGIC:
            raise ValueError("not a flat int8 weight file (magic %r)" % (bytes(data[:4]),))
        version, n_layers, n_in, n_out = struct.unpack_from("<HHHH", data, 4)
        if version != VERSION:
            raise ValueError("flat int8 version %d, this reader knows %d" % (version, VERSION))
        if n_layers < 1:
            raise ValueError("flat int8 file with no layers")
        off = 12
        self.layers = []
        width = n_in
        widest = 0
        for k in range(n_layers):
            if off + 8 > n:
                raise ValueError("weight file truncated at layer %d header (%d bytes)" % (k, n))
            rows, cols, act = struct.unpack_from("<HHB", data, off)
            off += 8
            if cols != width or rows < 1:
                raise ValueError("layer %d is %dx%d, its input has %d values" % (k, rows, cols, width))
            if act not in ACTIVATIONS:
                raise ValueError("layer %d: unknown activation %d" % (k, act))
            end = off + 8 * rows + rows * cols
            if end > n:
                raise ValueError("weight file truncated in layer %d: needs %d bytes, has %d" % (k, end, n))
            scale = array("f", data[off:off + 4 * rows])
            bias = array("f", data[off + 4 * rows:off + 8 * rows])
            weight = array("b", data[off + 8 * rows:end])
            off = end + (-end) % 4
            self.layers.append((rows, cols, act, levels(cols), scale, bias, weight))
            width = rows
            widest = max(widest, rows, cols)
        if width != n_out:
            raise ValueError("the last layer gives %d values, the header says %d" % (width, n_out))
        if off != n:
            raise ValueError("weight file has %d bytes, its layers need %d" % (n, off))
        self.n_in = n_in
        self.n_out = n_out
        self._xq = array("i", bytes(4 * widest))
        self._acc = array("i", bytes(4 * widest))

    def macs(self) -> int:
        """Multiply-adds per forward pass."""
        return sum(lay[0] * lay[1] for lay in self.layers)

    def ram_bytes(self) -> int:
        """Bytes of the parsed buffers (weights, scales, biases, work vectors), without object headers."""
        return sum(lay[0] * (lay[1] + 8) for lay in self.layers) + 8 * len(self._xq)

    def forward(self, x) -> list:
        """The net on the n_in features x; a new list of n_out floats."""
        if len(x) != self.n_in:
            raise ValueError("the net takes %d inputs, got %d" % (self.n_in, len(x)))
        h = list(x)
        xq = self._xq
        acc = self._acc
        for rows, cols, act, q, scale, bias, weight in self.layers:
            m = 0.0
            for v in h:
                a = abs(v)
                if a > m:
                    m = a
            k = q / m if m > 0 else 0.0
            for c in range(cols):
                xq[c] = round(h[c] * k)
            _dot(weight, xq, acc, (rows << 16) | cols)  # type: ignore[arg-type]  # arrays are the viper kernel's pointers
            step = m / q
            h = [acc[r] * step * scale[r] + bias[r] for r in range(rows)]
            if act == 2:
                h = [v if v > 0 else 0.0 for v in h]
            elif act == 1:
                h = [v if v > 0 else 0.01 * v for v in h]
            elif act == 3:
                h = [math.tanh(v) for v in h]
            elif act == 4:
                h = [v / (1.0 + math.exp(-v)) for v in h]
        return h
