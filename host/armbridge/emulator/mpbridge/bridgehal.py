"""The firmware's HAL under the MicroPython bridge, and the step functions
bridge.mjs calls (MicroPython; also imports under CPython for fwcost.py).

The HAL holds plain values that one round trip per emulator tick fills and
drains: the emulator's clock (`ms`, `us`), the bytes the UART received since
the last poll (`rx`), the joint readings (`q`), and a log of what the firmware
did, in order (`ops`: UART writes, outputs written, outputs off, persisted
memory written, pen moves, completed waypoints). The CPython side replays that log on the
emulator's own HAL, so the plant, the UART lanes and the board's records see
exactly what they see when the firmware runs under CPython.

Request lines (one per round trip, from armbridge.emulator.micropython):
    F 0 0 DATA NAME             before a boot: write DATA to the file NAME of the
                                interpreter's filesystem (the board's files: the IK
                                weights); answered `OK`
    H 0 0 CAPS                  before a boot: the emulator HAL's optional parts, a
                                JSON object in hex ({"has_pen": bool, "uid": str,
                                "rig": "arm" | "ma" | "pca"}); answered `OK`
    B ms us PERSIST SENSORS     boot: import the firmware, construct the HAL of the
                                rig (make_hal) and the board
    S ms us RX SENSORS          one pass of the main loop: board.poll()
    E ms us - SENSORS           the board's estop()
PERSIST and RX are hex, "-" for none. SENSORS are the rig's (its HAL's
sense()): the joint readings q1 .. qn on the arm's rigs, `wheel gear level
edges` on the MA (bridgerigs.py). The answer is one line of tab-separated
fields: the board's state, then the log in order: `T<hex>` UART bytes,
`O<e1>,..,<en>` outputs written, `X` outputs off, `P<hex>` persisted memory
written, `N1` / `N0` pen down / up, `Y<up_us>,<down_us>` the pen's widths (PENPOS), `W<name> <hex>` a file the firmware wrote,
`D<json list>` the arguments of the completion hook, the rigs' own fields
(bridgerigs.py: `L`, `R`, `G`, `I`, `Z`, `Q`, `C`); and last, when the firmware
raised, `!<json string>` its traceback.

A question in the middle of a pass (an I2C read: the answer depends on the
writes before it) is one line `?<the log so far, tab-separated>\t<query>`
(the log is then no longer in the answer); the emulator replays that log,
answers the query (`r<addr>,<reg>,<n>`: the bytes read, hex) with one line,
and the pass goes on (`ask`; bridge.mjs's `jsbridge.ask` carries it).
"""

import binascii
import json
import sys

try:
    from time import ticks_add as _ticks_add  # type: ignore[attr-defined]
    from time import ticks_diff as _ticks_diff  # type: ignore[attr-defined]
except ImportError:  # CPython (fwcost.py's comparison run): MicroPython's semantics
    def _ticks_diff(a, b):
        return ((a - b + 0x20000000) & 0x3FFFFFFF) - 0x20000000

    def _ticks_add(t, delta):
        return (t + delta) & 0x3FFFFFFF

TX = 0
OUT = 1
OFF = 2
PERSIST = 3
DONE = 4
PEN = 5
FILE = 6
PENW = 7


class BridgeHal:
    """The HAL of docs/architecture.md over values set from outside."""

    def __init__(self, n, persist=b"", has_pen=False, uid="0"):
        self.has_pen = bool(has_pen)
        self._uid = str(uid)
        self.ms = 0
        self.us = 0
        self.rx = None
        self.q = [0.0] * n
        self.ops = []
        self.persist = persist

    def ticks_ms(self):
        return self.ms

    def ticks_us(self):
        return self.us

    def ticks_diff(self, a, b):
        return _ticks_diff(a, b)

    def ticks_add(self, t, delta):
        return _ticks_add(t, delta)

    def read_positions(self, out):
        q = self.q
        for i in range(len(out)):
            out[i] = q[i]

    def write_outputs(self, efforts):
        self.ops.append((OUT, tuple(efforts)))

    def outputs_off(self):
        self.ops.append((OFF, None))

    def uart_read(self):
        data = self.rx
        self.rx = None
        return data

    def uart_write(self, data):
        self.ops.append((TX, bytes(data)))

    def load_persist(self):
        return self.persist

    def save_persist(self, data):
        self.persist = bytes(data)
        self.ops.append((PERSIST, self.persist))

    def write_pen(self, down):
        self.ops.append((PEN, bool(down)))

    def set_pen_widths(self, up_us, down_us):
        self.ops.append((PENW, (int(up_us), int(down_us))))

    def read_file(self, name):
        """A file of the interpreter's filesystem (written by F requests), None if missing:
        the same call as the chip's HAL (firmware/esp32/hal_esp32.py)."""
        try:
            with open(name, "rb") as f:
                return f.read()
        except OSError:
            return None

    def write_file(self, name, data):
        """Writes the interpreter's file, and tells the emulator (its board filesystem keeps it)."""
        with open(name, "wb") as f:
            f.write(data)
        self.ops.append((FILE, (name, bytes(data))))

    def uid(self):
        return self._uid

    def sense(self, fields):
        """This pass's sensor readings from the request (the arm's: the joint readings)."""
        self.q = [float(x) for x in fields]

    def start(self, cfg):
        """After the clock and sensors of the boot request are set: the rig's own setup."""

    def ask(self, query):
        """A question to the emulator in the middle of a pass (see the module docstring)
        -> the bytes of its answer. `asker` (line -> answer line) carries it: bridge.mjs's
        jsbridge.ask under the bridge, fwcost's own in the bench."""
        line = "?" + "\t".join(_fields(self) + [query])
        return binascii.unhexlify(self.asker(line))

    asker = None

    def on_done(self, *args):
        """The board's completion hook (its arguments are passed on as they are)."""
        self.ops.append((DONE, args))


# ---------------------------------------------------------------- the bridge

_board = None
_hal = None
_modules = ("arm", "config")
_caps = {}  # type: dict


def setup(board_module, config_module):
    """Names of the firmware's board and config modules (bridge.mjs, at start)."""
    global _modules
    _modules = (board_module, config_module)


def _hex(data):
    return binascii.hexlify(data).decode()


# rig name -> its HAL class; bridgerigs.py adds its rigs, and their log fields to FIELDS
# (kind -> function(value) -> answer field), when it is imported (bridge.mjs, fwcost.py)
RIGS = {"arm": BridgeHal}
FIELDS = {}  # type: dict


def make_hal(rig, n, persist=b"", has_pen=False, uid="0"):
    """The bridge HAL of `rig` ("arm": this module's BridgeHal; "ma", "pca": bridgerigs.py's)."""
    if rig not in RIGS:
        raise ValueError("the bridge carries no rig %r" % rig)
    return RIGS[rig](n, persist, has_pen, uid)


def _fields(hal):
    """The log as answer fields, in order; the log is emptied."""
    out = []
    tx = b""
    for kind, v in hal.ops:
        if kind == TX:
            tx += v
            continue
        if tx:
            out.append("T" + _hex(tx))
            tx = b""
        if kind == OUT:
            out.append("O" + ",".join([repr(float(x)) for x in v]))
        elif kind == OFF:
            out.append("X")
        elif kind == PERSIST:
            out.append("P" + _hex(v))
        elif kind == PEN:
            out.append("N1" if v else "N0")
        elif kind == PENW:
            out.append("Y%d,%d" % v)
        elif kind == FILE:
            out.append("W%s %s" % (v[0], _hex(v[1])))
        elif kind == DONE:
            out.append("D" + json.dumps(list(v)))
        else:
            out.append(FIELDS[kind](v))
    if tx:
        out.append("T" + _hex(tx))
    hal.ops = []
    return out


def _drain(hal, state, error=None):
    out = [state] + _fields(hal)
    if error is not None:
        out.append("!" + json.dumps(error))
    return "\t".join(out)


def _traceback(e):
    try:
        import io
        buf = io.StringIO()
        sys.print_exception(e, buf)
        return buf.getvalue()
    except Exception:
        return "%s: %s" % (type(e).__name__, e)


def step(line):
    """One request line -> one answer line (see the module docstring)."""
    global _board, _hal, _caps
    parts = line.split(" ")
    cmd = parts[0]
    data = None if parts[3] == "-" else binascii.unhexlify(parts[3])
    if cmd == "F":
        with open(parts[4], "wb") as f:
            f.write(data or b"")
        return "OK"
    if cmd == "H":
        _caps = json.loads((data or b"{}").decode())
        return "OK"
    hal = _hal
    board = _board
    try:
        if cmd == "B":
            _board = None
            cfg = __import__(_modules[1])
            hal = make_hal(_caps.get("rig", "arm"), cfg.N_JOINTS, data or b"", _caps.get("has_pen", False),
                           _caps.get("uid", "0"))
            hal.asker = _asker
            _hal = hal
        if hal is None:
            return "RESET\t!" + json.dumps("the bridge got %r before a boot" % cmd)
        hal.ms = int(parts[1])
        hal.us = int(parts[2])
        hal.sense(parts[4:])
        if cmd == "B":
            hal.start(cfg)
            board = __import__(_modules[0]).Board(hal, cfg)
            board.on_done = hal.on_done
            _board = board
        elif board is None:
            raise RuntimeError("the board is not running")
        elif cmd == "S":
            hal.rx = data
            board.poll()
        elif cmd == "E":
            board.estop()
        else:
            raise ValueError("unknown bridge request %r" % cmd)
    except Exception as e:
        _board = None
        if hal is None:
            return "CRASHED\t!" + json.dumps(_traceback(e))
        return _drain(hal, "CRASHED", _traceback(e))
    return _drain(hal, board.state)


def _asker(line):
    import jsbridge  # type: ignore[import-not-found]  # bridge.mjs registers it

    return jsbridge.ask(line)
