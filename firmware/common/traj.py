"""Waypoint queue and set-point generator.

Positions are in milli-units (mrad), durations in ms, speeds in milli-units/s.
Each waypoint (id, dur_ms, targets) is a straight segment from where the
previous one ended (or from the current set point when idle, which the board
sets to the measured position) to its targets: the set point never jumps.
A segment that would exceed a joint's vmax is stretched in time (event SLOW).
step(dt_ms) advances segment time by dt; a segment that ends mid-step hands the
leftover time to the next one in the same step. A segment taken up from rest
starts at the step that takes it up (its set point is its start there). While
`hold` is set, time is frozen.

Each joint has a range [lo, hi] (set_range). At rest, a set point outside its
range moves into it at vmax, never in one jump (event LIMIT when that starts):
so narrowing a range, or a stop at a measured position just outside it, moves
the arm no faster than its speed limit. The caller keeps queued targets inside
the ranges (excludes() tells whether a new range would leave one outside).
DONE events carry the waypoint's targets as they were pushed.

A waypoint may carry a `dwell` (ms the set point waits at the segment's start
before it moves: a pen lift settling) and an `aux` value (the pen state it is
drawn with): when a segment begins whose aux differs from the last one begun,
step() reports ("AUX", aux) before its START, so the board switches the
output at the segment boundary, in order with the motion (G-code's M3/M5).
"""


class Traj:
    def __init__(self, n: int, qsize: int = 32, vmax=None) -> None:
        self.n = n
        self.qsize = qsize
        self.vmax = list(vmax) if vmax is not None else [1000000] * n
        self.lo = [-(1 << 30)] * n
        self.hi = [1 << 30] * n
        self._ramping = [False] * n
        self.sp = [0.0] * n      # set point
        self.vel = [0.0] * n     # set-point velocity (milli-units/s)
        self.hold = False
        self._queue: list = []   # waypoints not yet started: (id, dur, targets)
        self.active_id = -1      # id of the active segment, -1 when none
        self._targets: list = []  # targets of the active segment, as pushed
        self._dur = 0             # dwell + motion time of the active segment
        self._dwell = 0
        self._scale = 1.0         # 1000 / motion time (ms)
        self._t = 0
        self.aux = None           # aux of the last segment begun
        self._start = [0.0] * n
        self._end = [0.0] * n

    # ------------------------------------------------------------ queue

    def free(self) -> int:
        return self.qsize - len(self._queue)

    def queued(self) -> int:
        return len(self._queue)

    def busy(self) -> bool:
        return self.active_id >= 0 or len(self._queue) > 0

    def push(self, wid: int, dur: int, targets, dwell: int = 0, aux=None) -> bool:
        """Queues a waypoint; False when the queue is full."""
        if len(self._queue) >= self.qsize:
            return False
        self._queue.append((wid, dur, list(targets), dwell, aux))
        return True

    def last_aux(self):
        """The aux of the last waypoint queued (or begun, when none is queued)."""
        if self._queue:
            return self._queue[-1][4]
        return self.aux

    def set_range(self, j: int, lo: int, hi: int, vmax: int) -> None:
        """Joint j's (0-based) range and speed limit. A lower vmax re-plans the
        active segment from where the set point is (no jump), stretched so that
        it obeys the new limit."""
        slower = vmax < self.vmax[j]
        self.lo[j] = lo
        self.hi[j] = hi
        self.vmax[j] = vmax
        if slower and self.active_id >= 0:
            for k in range(self.n):
                self._start[k] = self.sp[k]
            wait = self._dwell - self._t
            self._plan(self._dur - self._t - (wait if wait > 0 else 0), wait if wait > 0 else 0)

    def excludes(self, j: int, lo: int, hi: int) -> bool:
        """True when a queued or active target of joint j lies outside [lo, hi]."""
        for w in self._queue:
            if not lo <= w[2][j] <= hi:
                return True
        return self.active_id >= 0 and not lo <= self._targets[j] <= hi

    def flush(self) -> None:
        """Drops the queue and the active segment; the set point stays."""
        self._queue = []
        self.active_id = -1
        for j in range(self.n):
            self.vel[j] = 0.0

    def set_point(self, q) -> None:
        """Stops and puts the set point at q (e.g. the measured position)."""
        self.flush()
        for j in range(self.n):
            self.sp[j] = float(q[j])

    # ------------------------------------------------------------ motion

    def step(self, dt_ms: int) -> list:
        """Advances by dt_ms -> events [("START", id), ("SLOW", id, j),
        ("DONE", id, targets), ("LIMIT", j)] (j 1-based)."""
        events: list = []
        if self.hold:
            for j in range(self.n):
                self.vel[j] = 0.0
            return events
        if self.active_id < 0 and not self._queue:
            self._ramp(dt_ms, events)
            return events
        # from rest, a segment starts at this step (set point = its start);
        # otherwise the step's time, and any leftover, goes to the segments
        left = 0 if self.active_id < 0 else dt_ms
        while True:
            if self.active_id < 0:
                if not self._queue:
                    for j in range(self.n):
                        self.vel[j] = 0.0
                    break
                self._begin(events)
            self._t += left
            if self._t < self._dur:
                self._interpolate()
                break
            left = self._t - self._dur
            self._finish(events)
            if left <= 0 and not self._queue:
                break
        return events

    def _ramp(self, dt_ms: int, events: list) -> None:
        """At rest: each set point outside its range moves toward it at vmax."""
        if dt_ms <= 0:
            return
        for j in range(self.n):
            x = self.sp[j]
            lo = self.lo[j]
            hi = self.hi[j]
            if lo <= x <= hi:
                self._ramping[j] = False
                self.vel[j] = 0.0
                continue
            if not self._ramping[j]:
                self._ramping[j] = True
                events.append(("LIMIT", j + 1))
            reach = self.vmax[j] * dt_ms / 1000.0
            if x < lo:
                y = float(lo) if lo - x <= reach else x + reach
            else:
                y = float(hi) if x - hi <= reach else x - reach
            self.vel[j] = (y - x) * 1000.0 / dt_ms
            self.sp[j] = y

    def _begin(self, events: list) -> None:
        wid, dur, targets, dwell, aux = self._queue.pop(0)
        if aux is not None and aux != self.aux:
            events.append(("AUX", aux))
        self.aux = aux
        self._targets = targets
        for j in range(self.n):
            self._ramping[j] = False
            self._start[j] = self.sp[j]
            self._end[j] = float(targets[j])
        self.active_id = wid
        events.append(("START", wid))
        worst = self._plan(dur, dwell)
        if worst >= 0:
            events.append(("SLOW", wid, worst + 1))

    def _plan(self, dur: int, dwell: int = 0) -> int:
        """Times the active segment _start -> _end: `dwell` ms at the start, then
        dur ms of motion, or longer where a joint would exceed its vmax -> the
        joint that set the time, or -1."""
        worst = -1
        for j in range(self.n):
            need = abs(self._end[j] - self._start[j]) * 1000.0 / self.vmax[j]
            need_ms = int(need)
            if need_ms < need:
                need_ms += 1
            if need_ms > dur:
                dur = need_ms
                worst = j
        if dur < 1:
            dur = 1
        self._dwell = dwell
        self._dur = dwell + dur
        self._t = 0
        self._scale = 1000.0 / dur
        for j in range(self.n):
            self.vel[j] = 0.0 if dwell > 0 else (self._end[j] - self._start[j]) * self._scale
        return worst

    def _interpolate(self) -> None:
        t = self._t - self._dwell
        if t <= 0:
            return                # dwelling: the set point waits at the start
        f = t / (self._dur - self._dwell)
        for j in range(self.n):
            a = self._start[j]
            self.sp[j] = a + (self._end[j] - a) * f
            self.vel[j] = (self._end[j] - a) * self._scale

    def _finish(self, events: list) -> None:
        for j in range(self.n):
            self.sp[j] = self._end[j]
            self.vel[j] = 0.0
        events.append(("DONE", self.active_id, self._targets))
        self.active_id = -1
