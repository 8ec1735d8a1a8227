"""The 3R arm's pen-lift servo on the board: PEN, PENPOS and the pen's part of CALID (arm.Board's `pen`).

Why here and not in arm.py: the pen is a capability of its own (hal.has_pen),
with its own verbs and calibration; Board keeps one `ArmPen` and asks it for
the dwell of each waypoint it queues and for the settle event in its tick.

PEN down (modal): the state of the waypoints queued after it (traj's aux); at
rest it moves the pen now. A change of state dwells `settle_ms` before the next
move (the waypoint that changes it starts that much later).

PENPOS up_us down_us settle_ms (the plotter's pen_pos_up / pen_pos_down and
delay, Klipper's SET_SERVO): the pen servo's two pulse widths and the settle
dwell, all at once (hal.set_pen_widths); a pen at rest moves to the new width
of its state now and settles again. Refused RANGE (detail "queued") while
waypoints are queued: widths changed under a stroke would move the pen
mid-line. Either order is allowed (a servo mounted the other way round lifts
with the longer pulse). RAM only until CALID, which saves it as the token
`P=up_us,down_us,settle_ms`; a boot loads it back.
"""

import link as L
import proto
import protodef as P

US_MIN = 500
US_MAX = 2500
SETTLE_MAX_MS = 2000


class ArmPen:
    def __init__(self, board) -> None:
        self.b = board
        cfg = board.cfg
        self.hal = board.hal
        self.up_us = cfg.PEN_UP_US
        self.down_us = cfg.PEN_DOWN_US
        self.settle_ms = cfg.PEN_SETTLE_MS
        self.state = 0            # pen state written to the servo (0 up, 1 down)
        self.next = 0             # the state waypoints queued from now on draw with
        self.settling = False     # a pen move has not settled yet ...
        self.settle_at = 0        # ... until this ticks_ms
        self.saved = False        # PENPOS was given (CALID saves it)

    # ------------------------------------------------------------ verbs
    def cmd_pen(self, v: list) -> list:
        """PEN down: the state of the waypoints queued after it; at rest, now."""
        self.next = v[0]
        if not self.b.traj.busy() and v[0] != self.state:
            self.set(v[0])
        return []

    def cmd_penpos(self, v: list) -> list:
        """PENPOS up_us down_us settle_ms (see the module docstring)."""
        if self.b.traj.busy():
            raise proto.ProtocolError(P.RANGE, "", "queued")
        self.set_widths(v[0], v[1], v[2])
        self.saved = True
        return []

    def set_widths(self, up_us: int, down_us: int, settle_ms: int) -> None:
        moved = (self.down_us if self.state else self.up_us) != (down_us if self.state else up_us)
        self.up_us = up_us
        self.down_us = down_us
        self.settle_ms = settle_ms
        self.hal.set_pen_widths(up_us, down_us)
        if moved:
            self._settle()

    def set(self, down: int) -> None:
        self.state = down
        self.hal.write_pen(down == 1)
        self._settle()

    def _settle(self) -> None:
        self.settling = True
        self.settle_at = (self.hal.ticks_ms() + self.settle_ms) & L.TICKS_MASK

    # ------------------------------------------------------------ the board's hooks
    def dwell(self) -> int:
        """The dwell (ms) of a waypoint queued now: the settle time when it changes the
        pen's state, what is left of a pen move at rest, else 0."""
        traj = self.b.traj
        busy = traj.busy()
        before = traj.last_aux() if busy else self.state
        if before is None:
            before = self.state
        if self.next != before:
            return self.settle_ms
        if not busy and self.settling:
            left = self.hal.ticks_diff(self.settle_at, self.hal.ticks_ms())
            return left if left > 0 else 0
        return 0

    def tick(self) -> None:
        """Each control tick: `EV PEN state` once the pen has settled."""
        if self.settling and self.hal.ticks_diff(self.hal.ticks_ms(), self.settle_at) >= 0:
            self.settling = False
            self.b.link.event("PEN", [self.state])

    # ------------------------------------------------------------ CALID
    def cal_text(self) -> list:
        if not self.saved:
            return []
        return ["P=%d,%d,%d" % (self.up_us, self.down_us, self.settle_ms)]

    @staticmethod
    def parse(t: str) -> list:
        """A `P=up,down,settle` token's values, checked as PENPOS checks them; ValueError else."""
        x = [int(s) for s in t[2:].split(",")]
        if (t[:2] != "P=" or len(x) != 3 or not US_MIN <= x[0] <= US_MAX or not US_MIN <= x[1] <= US_MAX
                or not 0 <= x[2] <= SETTLE_MAX_MS):
            raise ValueError("pen")
        return x

    def apply(self, x: list) -> None:
        """At boot (the pen is not driven yet: nothing moves, nothing settles)."""
        self.up_us, self.down_us, self.settle_ms = x[0], x[1], x[2]
        self.hal.set_pen_widths(x[0], x[1])
        self.saved = True
