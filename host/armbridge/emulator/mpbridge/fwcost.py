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
    import bridgehal  # type: ignore[import-not-found]
    import bridgerigs  # type: ignore[import-not-found]
except ImportError:  # CPython: the package's modules
    from armbridge.emulator.mpbridge import bridgehal, bridgerigs

# The answer each item must get (fwcost measures nothing else).
EXPECT = {"W": "OK", "MV": "OK", "crc32 of a MV line": "int", "decode MV": "MV", "parse_command MV": "list",
          "PING": "OK", "STAT": "OK", "HOLD": "OK", "RESUME": "OK", "RATE": "OK", "LIM": "OK",
          "HELLO": "OK", "CRC error": "ER 2", "ER SEQ": "ER 7", "idle": "-", "RUN": "-", "RUN + telemetry": "T",
          "crc32 of a W line": "int", "decode W": "W", "parse_command W": "list", "encode an OK reply": "bytes"}
LINES = ("W", "PING", "STAT", "HOLD", "RESUME", "RATE", "LIM", "HELLO", "CRC error", "ER SEQ")
TICKS = {"idle": (0, False), "RUN": (0, True), "RUN + telemetry": (100, True)}  # (rate, moving)
CODEC_INNER = 20
ALLOC_SAMPLES = 100        # polls of each item whose allocation is counted (gc.mem_alloc() walks the whole heap)
CODEC = ("crc32 of a W line", "decode W", "parse_command W", "encode an OK reply")
ITEMS = LINES + tuple(TICKS) + CODEC
MA_LINK = 2                # the MA boots homed on link 2 (joint 2 at r_2), ...
MA_FROM_MM = 50            # ... this far along it, and moves between r_2 + 40 and r_2 + 160 mm
MA_VMAX_MM_S = 2           # slowly (SETLIM): one RUN item is one move, whatever reps is (up to 6,000)


def items(rig="arm"):
    """The items for a rig: the MA queues its moves with MV, the arm with W."""
    if rig == "ma":
        return tuple([_ma_name(x) for x in ITEMS])
    return ITEMS


def _ma_name(name):
    return "MV" if name == "W" else name.replace(" W", " MV")


def _stats(xs, overhead):
    """The stats of xs (us), less overhead. Both lists are emptied after: the collector is
    conservative, and a stale pointer to a list must not keep its floats in the live heap."""
    ys = sorted([x - overhead for x in xs])
    n = len(ys)
    st = {
        "n": n,
        "min_us": round(ys[0], 2),  # the least disturbed by other processes
        "median_us": round(ys[n // 2], 2),
        "p99_us": round(ys[min(n - 1, (n * 99) // 100)], 2),
        "mean_us": round(sum(ys) / n, 2),
    }
    ys.clear()
    xs.clear()
    return st


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
    def __init__(self, board_cls, cfg, proto, version, clock, reps, rig="arm", modules=None):
        self.clock = clock
        self.reps = reps
        self.cfg = cfg
        self.rig = rig
        self.n = cfg.N_JOINTS
        self.period = cfg.PERIOD_MS
        persist = b""
        if rig == "ma":
            self.verb = "MV"
            r = sum(cfg.LINK_LENGTHS_MM[:MA_LINK - 1])
            self.ma_span = (r + 40, r + 160)
            self.ma_0 = float(r + MA_FROM_MM)
            self.ma_mm = self.ma_0               # the MA's true d; the wheel counts from boot
            self.ma_u = 0.0
            persist = ("AB2 0 0 - - - - 0,%d,%d,0,%s" % (MA_LINK, MA_FROM_MM * 1000,
                                                          ",".join(["0"] * (self.n - 1)))).encode()
        else:
            self.verb = "W"
            self.mid = [(lo + hi) // 2 for lo, hi in cfg.LIMITS_MRAD]
        hal = bridgehal.make_hal(rig, self.n, persist)
        hal.asker = bridgerigs.RegisterFile().ask
        hal.firmware = modules
        hal.ms = 100000
        hal.us = hal.ms * 1000
        if rig != "ma":
            hal.q = [m / 1000.0 for m in self.mid]
        hal.start(cfg)
        self.hal = hal
        self.board = board_cls(hal, cfg)
        self.board.on_done = hal.on_done
        self.host = _Host(proto, version)
        self.wid = 0
        self.clock_alloc = 0
        self.clock_alloc = self._clock_alloc()
        self._poll(None)  # the first control tick is due at boot
        self.send(self.host.hello(True))
        self.send(self.host.line("RATE", (0,)))
        if rig == "ma":
            span = cfg.LIMITS[-1]
            self.send(self.host.line("SETLIM", (self.n, span[0], span[1], MA_VMAX_MM_S)))
        self.oh = self.overhead()  # the median cost of reading the clock, us

    # ------------------------------------------------------------ plumbing

    def _poll(self, data, count=True):
        """One poll -> (us, bytes allocated (0 unless count), the HAL's log)."""
        hal = self.hal
        hal.rx = data
        clock = self.clock
        a0 = _alloc() if count else 0   # outside the timed span: gc.mem_alloc() walks the heap's table
        t0 = clock()
        self.board.poll()
        t1 = clock()
        a1 = _alloc() if count else self.clock_alloc
        ops = hal.ops
        hal.ops = []
        if self.rig == "ma":
            for k, v in ops:
                if k == bridgerigs.LOCO:
                    self.ma_u = v
        return t1 - t0, a1 - a0 - self.clock_alloc, ops

    def _clock_alloc(self):
        """What reading the clock twice allocates (a float each under MicroPython):
        taken off every poll's allocation."""
        clock = self.clock
        a0 = _alloc()
        t0 = clock()
        t1 = clock()
        a1 = _alloc()
        return a1 - a0 if t1 >= t0 else 0

    def send(self, data):
        """One line, untimed -> the board's reply line(s) (bytes)."""
        ops = self._poll(data, False)[2]
        return b"".join([v for k, v in ops if k == bridgehal.TX])

    def advance(self):
        self.hal.ms += self.period
        self.hal.us = self.hal.ms * 1000
        if self.rig == "ma":  # the wheel: speed = effort / LOCO_KFF, no slip, no magnet on the way
            c = self.cfg
            self.ma_mm += self.ma_u / c.LOCO_KFF * self.period / 1000.0
            self.hal.wheel = int(round((self.ma_mm - self.ma_0) / c.WHEEL_MM_PER_COUNT))

    def new_session(self, rate=0):
        """Empty queue, IDLE, telemetry rate `rate` (untimed)."""
        self.send(self.host.hello(True))
        self.send(self.host.line("RATE", (rate,)))

    def w_line(self, dur, offset):
        """A waypoint line: W to mid-range + offset over dur; the MA: MV to the far end of its span."""
        wid = self.wid
        self.wid = (self.wid + 1) & 0xFFFF
        if self.rig == "ma":
            lo, hi = self.ma_span
            return self.host.line("MV", [wid, hi if self.ma_mm < (lo + hi) / 2 else lo])
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
        """Times `reps` polls of make(i)'s bytes (None: a tick), before(i) untimed
        -> (microseconds each, bytes allocated per poll, {answer: count}); the
        answer is the kind of the first line the board wrote ("OK", "ER 2", "T",
        "-" for none), so that a bench that measures the wrong path shows it."""
        xs = []
        answers = {}
        poll = self._poll
        tx = bridgehal.TX
        alloc = 0
        samples = min(self.reps, ALLOC_SAMPLES)
        for i in range(self.reps):
            if before is not None:
                before(i)
            dt, da, ops = poll(make(i), i < samples)
            xs.append(dt)
            alloc += da
            out = [v for k, v in ops if k == tx]
            a = _answer(out[0]) if out else "-"
            answers[a] = answers.get(a, 0) + 1
        return xs, alloc / samples, answers

    def series_fn(self, fn, inner=CODEC_INNER):
        """Times `reps` samples of `inner` calls fn(i) -> like series(), per call
        and less the clock's cost already; the answer is a name for what fn
        returned (_result_name). Some codec calls take about as long as
        reading the clock: hence the inner loop."""
        xs = []
        answers = {}
        clock = self.clock
        oh = self.oh
        alloc0 = _alloc()
        for i in range(self.reps):
            t0 = clock()
            for _ in range(inner):
                r = fn(i)
            t1 = clock()
            xs.append((t1 - t0 - oh) / inner)
            a = _result_name(r)
            answers[a] = answers.get(a, 0) + 1
        return xs, (_alloc() - alloc0) / (self.reps * inner), answers

    def codec_item(self, name):
        """The codec's share of a W line (the MA's: an MV line): firmware/common/proto.py alone."""
        name = name.replace(" MV", " W")
        proto = self.host.proto
        line = self.w_line(1000, 10)
        body = line[:line.rfind(b"*")]
        epoch = self.host.epoch
        if name == "crc32 of a W line":
            return self.series_fn(lambda i: proto.crc32(body, epoch))
        if name == "decode W":
            return self.series_fn(lambda i: proto.decode(line[:-1], proto.MAX_HOST_LINE, epoch))
        seq, verb, args = proto.decode(line[:-1], proto.MAX_HOST_LINE, epoch)
        if name == "parse_command W":
            return self.series_fn(lambda i: proto.parse_command(verb, args, self.n))
        if name == "encode an OK reply":
            return self.series_fn(lambda i: proto.encode(i, "OK", [seq, 31]))
        raise ValueError("unknown item %r" % name)

    def run_item(self, name):
        if name.replace(" MV", " W") in CODEC:
            return self.codec_item(name)
        host = self.host
        qsize = self.cfg.QSIZE
        if name in TICKS:
            rate, moving = TICKS[name]
            self.new_session(rate)
            if moving:
                # one long move, small enough that the still arm stays inside the
                # following-error limit: the trajectory and the PIDs run every tick
                self.send(self.w_line(60000, 250))
                self.advance()
                self.send(None)  # the tick that starts it (EV START), untimed

            def tick(i):
                if i % 20 == 19:
                    self.send(host.line("PING"))  # feeds the watchdog, between ticks
                self.advance()

            return self.series(lambda i: None, tick)
        if name == self.verb:
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


def _answer(data):
    f = data.split(b" ", 4)
    if len(f) > 3 and f[1] == b"ER":
        return "ER " + f[3].decode()
    return f[1].decode() if len(f) > 1 else "?"


def _result_name(r):
    if isinstance(r, tuple):
        return r[1]  # decode: the verb
    return type(r).__name__


def _alloc():
    try:
        return gc.mem_alloc()
    except AttributeError:  # CPython
        return 0


_bench = None
_result: dict = {}


def start(board_cls, cfg, proto, version, clock, reps, rig="arm", modules=None):
    """A board booted for the bench -> the names of the items to run(). modules: the
    firmware's modules by name where they cannot be imported (CPython)."""
    global _bench, _result
    _bench = Bench(board_cls, cfg, proto, version, clock, reps, rig, modules)
    _result = {"reps": reps, "rig": rig, "clock_overhead_us": round(_bench.oh, 3), "lines": {}, "ticks": {},
               "codec": {}}
    return items(rig)


def measure(name):
    """One item -> (its group, its stats)."""
    b = _bench
    xs, alloc, answers = b.run_item(name)
    codec = name.replace(" MV", " W") in CODEC
    st = _stats(xs, 0.0 if codec else b.oh)
    st["answers"] = answers
    if alloc:
        st["alloc_bytes"] = round(alloc)
    if name in TICKS:
        st["state"] = b.board.state
        return "ticks", st
    return ("codec" if codec else "lines"), st


def run(name):
    """One item (its own call from the host, so that garbage is collected between
    items; the WebAssembly port collects only when control is back in JS)."""
    group, st = measure(name)
    _result[group][name] = st


def result():
    return _result


def bench():
    return _bench
