"""What the firmware costs per received line and per control tick
(`armbridge bench firmware`; MicroPython and CPython alike).

Drives a `Board(hal, cfg)` on the bridge HAL with lines a host would send,
encoded with the firmware's own codec, and times one `board.poll()` per line
(the whole path: UART bytes -> line reader -> decode -> session -> verb ->
reply encoded and written) with the clock held still, so that no control tick
runs; then times the ticks themselves (poll with the clock one period on, no
bytes): idle, RUN (trajectory and PID), RUN with a T line every tick. Each item
is repeated `reps` times; results are microseconds (median, p99, mean), less
the cost of reading the clock, which is given too.

Under MicroPython the clock is the host's performance.now() through the
`jsclock` module bridge.mjs registers (this port's time.ticks_us counts whole
milliseconds); under CPython time.perf_counter_ns.
"""

import gc

try:
    import bridgehal
except ImportError:  # CPython: the package's module
    from armbridge.emulator.mpbridge import bridgehal


def _stats(xs, overhead):
    xs = sorted([x - overhead for x in xs])
    n = len(xs)
    return {
        "n": n,
        "median_us": round(xs[n // 2], 2),
        "p99_us": round(xs[min(n - 1, (n * 99) // 100)], 2),
        "mean_us": round(sum(xs) / n, 2),
    }


class _Host:
    """A host that follows the protocol (docs/protocol.md): HELLO opens an
    epoch, every other line is framed with it."""

    def __init__(self, proto, version):
        self.proto = proto
        self.version = version
        self.seq = 0
        self.session = 0
        self.epoch = 0

    def line(self, verb, args=()):
        epoch = 0 if verb == "HELLO" else self.epoch
        data = self.proto.encode(self.seq, verb, list(args), epoch)
        self.seq = (self.seq + 1) & 0xFFFF
        return data

    def hello(self, new_session):
        if new_session:
            self.session = self.session % 65535 + 1
        self.epoch += 1
        return self.line("HELLO", (self.version, self.session, self.epoch))


class Bench:
    def __init__(self, board_cls, cfg, proto, version, clock, reps):
        self.clock = clock
        self.reps = reps
        self.cfg = cfg
        self.n = cfg.N_JOINTS
        self.period = cfg.PERIOD_MS
        self.mid = [(lo + hi) // 2 for lo, hi in cfg.LIMITS_MRAD]
        hal = bridgehal.BridgeHal(self.n)
        hal.ms = 100000
        hal.us = hal.ms * 1000
        hal.q = [m / 1000.0 for m in self.mid]
        self.hal = hal
        self.board = board_cls(hal, cfg)
        self.board.on_done = hal.on_done
        self.host = _Host(proto, version)
        self.wid = 0
        self._poll(None)  # the first control tick is due at boot
        self.send(self.host.hello(True))
        self.send(self.host.line("RATE", (0,)))

    # ------------------------------------------------------------ plumbing

    def _poll(self, data):
        hal = self.hal
        hal.rx = data
        clock = self.clock
        t0 = clock()
        self.board.poll()
        t1 = clock()
        ops = hal.ops
        hal.ops = []
        return t1 - t0, ops

    def send(self, data):
        """One line, untimed -> the board's reply line(s) (bytes)."""
        ops = self._poll(data)[1]
        return b"".join([v for k, v in ops if k == bridgehal.TX])

    def timed(self, data):
        return self._poll(data)[0]

    def advance(self):
        self.hal.ms += self.period
        self.hal.us = self.hal.ms * 1000

    def new_session(self, rate=0):
        """Empty queue, IDLE, telemetry rate `rate` (untimed)."""
        self.send(self.host.hello(True))
        self.send(self.host.line("RATE", (rate,)))

    def w_line(self, dur, offset):
        wid = self.wid
        self.wid = (self.wid + 1) & 0xFFFF
        return self.host.line("W", [wid, dur] + [m + offset for m in self.mid])

    def overhead(self):
        clock = self.clock
        xs = []
        for _ in range(self.reps):
            t0 = clock()
            t1 = clock()
            xs.append(t1 - t0)
        xs.sort()
        return xs[len(xs) // 2]

    # ------------------------------------------------------------ items

    def series(self, make, before=None):
        """Times `reps` polls of make(i)'s bytes (None: a tick) ->
        (microseconds each, bytes allocated per poll, untimed)."""
        xs = []
        timed = self.timed
        alloc0 = _alloc()
        for i in range(self.reps):
            if before is not None:
                before(i)
            xs.append(timed(make(i)))
        return xs, (_alloc() - alloc0) / self.reps

    def run_item(self, name):
        host = self.host
        qsize = self.cfg.QSIZE
        if name in TICKS:
            rate, moving = TICKS[name]
            self.new_session(rate)
            if moving:
                # one long move, small enough that the still arm stays inside the
                # following-error limit: the trajectory and the PIDs run every tick
                self.send(self.w_line(60000, 250))

            def tick(i):
                if i % 20 == 19:
                    self.send(host.line("PING"))  # feeds the watchdog, between ticks
                self.advance()

            return self.series(lambda i: None, tick)
        if name == "W":
            def drain(i):
                if i % (qsize - 1) == 0:
                    self.new_session()

            return self.series(lambda i: self.w_line(1000, 10), drain)
        self.new_session()
        if name in ("PING", "STAT"):
            return self.series(lambda i: host.line(name))
        if name == "HOLD":
            return self.series(lambda i: host.line("HOLD"), lambda i: self.send(host.line("RESUME")))
        if name == "RESUME":
            return self.series(lambda i: host.line("RESUME"), lambda i: self.send(host.line("HOLD")))
        if name == "RATE":
            return self.series(lambda i: host.line("RATE", (25 + i % 2,)))
        if name == "LIM":
            return self.series(lambda i: host.line("LIM", (1 + i % self.n,)))
        if name == "HELLO":  # a resync: the same session, the next epoch
            return self.series(lambda i: host.hello(False))
        if name == "CRC error":
            def bad_crc(i):
                data = bytearray(host.line("PING"))
                star = data.rfind(b"*")
                data[star + 1] = 0x30 if data[star + 1] != 0x30 else 0x31
                return bytes(data)

            return self.series(bad_crc)
        if name == "ER SEQ":  # a valid line far ahead of the seq the board expects
            return self.series(lambda i: host.proto.encode((host.seq + 1000) & 0xFFFF, "PING", [], host.epoch))
        raise ValueError("unknown item %r" % name)


LINES = ("W", "PING", "STAT", "HOLD", "RESUME", "RATE", "LIM", "HELLO", "CRC error", "ER SEQ")
TICKS = {"idle": (0, False), "RUN": (0, True), "RUN + telemetry": (100, True)}  # (rate, moving)
ITEMS = LINES + tuple(TICKS)


def _alloc():
    try:
        return gc.mem_alloc()
    except AttributeError:  # CPython
        return 0


_bench = None
_result = {}


def start(board_cls, cfg, proto, version, clock, reps):
    """A board booted for the bench -> the names of the items to run()."""
    global _bench, _result
    _bench = Bench(board_cls, cfg, proto, version, clock, reps)
    _result = {"reps": reps, "clock_overhead_us": round(_bench.overhead(), 3), "lines": {}, "ticks": {}}
    return ITEMS


def run(name):
    """One item (its own call from the host, so that garbage is collected between
    items; the WebAssembly port collects only when control is back in JS)."""
    b = _bench
    xs, alloc = b.run_item(name)
    st = _stats(xs, _result["clock_overhead_us"])
    if alloc:
        st["alloc_bytes"] = round(alloc)
    if name in TICKS:
        st["state"] = b.board.state
        _result["ticks"][name] = st
    else:
        _result["lines"][name] = st


def result():
    return _result


# ---------------------------------------------------------------- MicroPython entry (bridge.mjs)

def mp_start(params):
    """params: JSON {"reps": N} -> JSON list of item names."""
    import json

    import jsclock

    cfg = __import__(bridgehal._modules[1])
    board_mod = __import__(bridgehal._modules[0])
    proto = __import__("proto")
    protodef = __import__("protodef")
    gc.collect()
    imported = gc.mem_alloc()
    items = start(board_mod.Board, cfg, proto, protodef.PROTOCOL_VERSION, jsclock.us, int(json.loads(params)["reps"]))
    _result["heap_after_import"] = imported
    return json.dumps(list(items))


def mp_run(name):
    run(name)


def mp_result():
    import json
    import sys

    gc.collect()
    _result["heap_live_after_bench"] = gc.mem_alloc()
    _result["interpreter"] = "MicroPython %d.%d.%d (WebAssembly)" % sys.implementation.version[:3]
    return json.dumps(_result)
