"""Helpers for the firmware unit tests; MicroPython-compatible (no pytest).

The tests run under CPython (pytest, tests/firmware/conftest.py sets sys.path)
and under the MicroPython WebAssembly interpreter (tests/mpy/run_tests.mjs
mirrors the repo layout in its filesystem, so paths relative to this file work
in both).
"""

import json

import proto
import protodef

TICKS_PERIOD = protodef.TICKS_PERIOD
_HALF = TICKS_PERIOD // 2


def _here() -> str:
    f = __file__
    i = f.rfind("/")
    return f[:i] if i >= 0 else "."


def load_vectors() -> dict:
    """tests/vectors/lines.json, found relative to this file."""
    d = _here()
    i = d.rfind("/")
    tests = d[:i] if i >= 0 else ".."
    with open(tests + "/vectors/lines.json") as f:
        return json.load(f)


def latin1(s: str) -> bytes:
    """The bytes a vector string stands for (its latin-1 encoding)."""
    return bytes([ord(c) for c in s])


def raises(fn, *args):
    """Calls fn(*args) -> the ProtocolError it raised, or None."""
    try:
        fn(*args)
    except proto.ProtocolError as e:
        return e
    return None


class FakeHal:
    """The HAL of docs/architecture.md over a scripted UART and a simple servo
    plant: joint velocity = effort * 5 rad/s behind a 30 ms first-order lag."""

    def __init__(self, q=(1.0, -1.0, 0.0), persist=b"", t0=0) -> None:
        self.t = t0
        self.q = list(q)
        self.v = [0.0] * len(self.q)
        self.u = [0.0] * len(self.q)
        self.on = False
        self.off_calls = 0
        self.rx = b""
        self.tx = []          # every uart_write, in order
        self.persist = persist
        self.stalled = False  # True: joints do not move whatever the effort
        self.files: dict = {}  # the board's filesystem (calstore.py's cal.txt)

    # time
    def ticks_ms(self) -> int:
        return self.t % TICKS_PERIOD

    def ticks_us(self) -> int:
        return (self.t * 1000) % TICKS_PERIOD

    def ticks_diff(self, a: int, b: int) -> int:
        return ((a - b + _HALF) % TICKS_PERIOD) - _HALF

    # joints
    def read_positions(self, out) -> None:
        for j in range(len(self.q)):
            out[j] = self.q[j]

    def write_outputs(self, efforts) -> None:
        self.on = True
        self.u = list(efforts)

    def outputs_off(self) -> None:
        self.on = False
        self.off_calls += 1

    # link
    def uart_read(self):
        d = self.rx
        self.rx = b""
        return d or None

    def uart_write(self, data) -> None:
        self.tx.append(bytes(data))

    # persistence
    def load_persist(self) -> bytes:
        return self.persist

    def save_persist(self, data) -> None:
        self.persist = bytes(data)

    # files and identity (firmware/common/calstore.py)
    def read_file(self, name):
        return self.files.get(name)

    def write_file(self, name, data) -> None:
        self.files[name] = bytes(data)

    def uid(self) -> str:
        return "fa4e0001"

    # test side
    def send(self, data) -> None:
        self.rx += data

    def step_plant(self, ms: int = 1) -> None:
        for _ in range(ms):
            for j in range(len(self.q)):
                target = 5.0 * self.u[j] if (self.on and not self.stalled) else 0.0
                self.v[j] += (target - self.v[j]) * (1.0 / 30.0)
                self.q[j] += self.v[j] * 0.001
            self.t += 1

    def take(self) -> list:
        """Board lines written since the last take(), decoded: (seq, verb, args)."""
        out = []
        for data in self.tx:
            for raw in data.split(b"\n"):
                if raw:
                    out.append(proto.decode(raw, proto.MAX_BOARD_LINE))
        self.tx = []
        return out


def run(board, hal, ms: int) -> None:
    """Lets ms milliseconds pass: plant step, then one poll, per ms."""
    for _ in range(ms):
        hal.step_plant(1)
        board.poll()


def replies(lines, verb=None) -> list:
    """Lines other than telemetry (optionally only those of one verb)."""
    out = []
    for ln in lines:
        if ln[1] == "T":
            continue
        if verb is None or ln[1] == verb:
            out.append(ln)
    return out


def events(lines, kind=None) -> list:
    """The args of EV lines without the time: [kind, args...]."""
    out = []
    for ln in lines:
        if ln[1] == "EV" and (kind is None or ln[2][1] == kind):
            out.append(ln[2][1:])
    return out


class Host:
    """A scripted host on a FakeHal: frames its lines with its link epoch (HELLO
    always with epoch 0, as proto.encode does), answer() polls once and returns
    the board's OK/ER line to it."""

    def __init__(self, hal, board, epoch: int = 1) -> None:
        self.hal = hal
        self.board = board
        self.epoch = epoch

    def send(self, seq, verb, *args) -> None:
        self.hal.send(proto.encode(seq, verb, args, self.epoch))

    def answer(self, seq, verb, *args):
        self.send(seq, verb, *args)
        self.board.poll()
        lines = replies(self.hal.take())
        for ln in lines:
            if ln[1] in ("OK", "ER"):
                return ln
        raise AssertionError("no answer: %r" % (lines,))

    def hello(self, seq, sid, epoch=None):
        """HELLO 2 sid epoch (default: this host's epoch) -> the answer; an OK
        makes that epoch the host's."""
        if epoch is None:
            epoch = self.epoch
        ans = self.answer(seq, "HELLO", protodef.PROTOCOL_VERSION, sid, epoch)
        if ans[1] == "OK":
            self.epoch = epoch
        return ans
