"""The MA's two drives (pure control, no I/O): a ramped reference, the
locomotion speed loop and the joint-rotation angle loop (masr paper, section
II-A: "velocity d-dot is regulated by a PID controller, which uses the click
rate of the motor encoder"; "angle and velocity are regulated through a PID
controller that uses the encoder information").

Ramp: a 1-D reference (x, v) that moves toward a target at no more than vmax,
accelerating and braking at `accel` (v <= sqrt(2 accel |target - x|)), never
below `vmin` until it gets there (the creep onto a target or a magnet; a vmin
above vmax creeps at vmax: docs/protocol.md section 11, every set-point change
obeys the speed limit), and lands on the target exactly; under a vmax lowered
while it moves faster it brakes at `accel` down to it. hold: it brakes to rest
at `accel` and waits. `dir` remembers which way it last moved (kept across
resets): the side of a magnet the MA stopped short of (ma_act's seek).

Loco: effort u = PID(v_cmd - v) + kff (v_cmd + kaff a), v_cmd = ramp.v +
kpos (ramp.x - d): the speed loop, with the position it has fallen behind added
as speed; kaff (the drive's lag, s) feeds the reference's acceleration forward
so that a lagging drive brakes in time. The joint loop feeds forward the same way.
Two details keep the speed within a few per cent of vmax at the ramp's corner
(it overshot by 20 %): the acceleration fed forward is the next period's,
which stops at vmax (not the last step's 800 mm/s^2 once more), and the speed
error is taken against the command as it was when the speed was measured
(the encoder's SPEED_TICKS window is `delay` old: v_cmd - delay * a).

Joint angle through the worm's play: the gear encoder measures the worm; the
joint follows it only once the play is taken up. With the rotation driver's
current sense (ROT_ISENSE_PIN, `contact`), the board sees that happen: the
worm turning in the play loads its motor with nothing, driving the gear it
loads it with the mesh's and the joint's friction. So the estimate moves
only while the worm drives the gear (`side`, the way it pushes, kept until
the worm turns back), and counts half the period's travel in the period
the load first comes on (the contact came somewhere inside it: on average
half-way). That holds whatever the play's width and wherever in it a fresh
mesh lands (the MA arriving on a joint meets the gear anywhere in its play,
which the gear encoder cannot tell: masr paper, Table II's error). The worm
turning PLAY_MAX_MRAD in the play without a load means no gear there (not
meshed, or the sense is dead): FAULT MESH:j (ma_act `check`).
Without a current sense (`play`), the model of BACKLASH_MRAD: gap in [-B/2,
B/2], worm minus joint, a reversal crosses it before the joint moves, a fresh
mesh starts at 0 (off by up to B/2 of the true play, every engagement).
Either way the joint loop, a PID on the estimated angle, takes the play up on
every reversal by itself, and the worm gear holds the joint between
engagements, so nothing else moves it.
"""

from pid import PID


class Ramp:
    def __init__(self) -> None:
        self.x = 0.0
        self.v = 0.0
        self.a = 0.0          # the acceleration of the last step
        self.dir = 0          # the way it last moved (+-1; 0: never), kept across resets

    def reset(self, x: float) -> None:
        self.x = float(x)
        self.v = 0.0
        self.a = 0.0

    def step(self, dt: float, target: float, vmax: float, accel: float, vmin: float = 0.0,
             early: float = 0.0) -> bool:
        """One period of dt s toward target -> True once x is on it (v = 0).
        `early`: brake as if the target were this much nearer (then creep on
        at vmin over the rest)."""
        rem = target - self.x
        v0 = self.v
        if rem == 0.0:
            self.v = 0.0
            self.a = 0.0
            return True
        a = abs(rem) - early
        h = 0.5 * accel * dt       # the discrete braking curve: lands at rest, on time
        vd = (h * h + 2.0 * accel * a) ** 0.5 - h if a > 0.0 else 0.0
        if vd < vmin:
            vd = vmin
        if vd > vmax:
            vd = vmax
        if rem < 0:
            vd = -vd
        dv = accel * dt
        if vd > self.v + dv:
            vd = self.v + dv
        elif vd < self.v - dv:
            vd = self.v - dv
        step = vd * dt
        if (rem > 0 and step >= rem) or (rem < 0 and step <= rem):
            self.dir = 1 if rem > 0 else -1
            self.x = target          # lands: the last step's braking is not fed forward
            self.v = 0.0
            self.a = 0.0
            return True
        self.x += step
        self.v = vd
        self.a = (vd - v0) / dt
        if vd != 0.0:
            self.dir = 1 if vd > 0 else -1
        return False

    def brake(self, dt: float, accel: float) -> bool:
        """One period of braking to rest (HOLD) -> True at rest."""
        dv = accel * dt
        v = self.v
        if v > dv:
            v -= dv
        elif v < -dv:
            v += dv
        else:
            v = 0.0
        self.x += v * dt
        self.a = (v - self.v) / dt
        self.v = v
        return v == 0.0


class Loco:
    """The locomotion speed loop (mm, mm/s, effort in [-1, 1])."""

    def __init__(self, cfg) -> None:
        self.pid = PID(cfg.LOCO_KP, cfg.LOCO_KI, cfg.LOCO_KD, cfg.LOCO_KFF)
        self.kpos = cfg.LOCO_KPOS
        self.kaff = cfg.LOCO_KAFF
        self.delay = cfg.SPEED_TICKS * cfg.PERIOD_MS / 2000.0   # s: the measured speed's age (its window's middle)
        self.ramp = Ramp()
        self.u = 0.0

    def reset(self, d: float) -> None:
        self.ramp.reset(d)
        self.pid.reset()
        self.u = 0.0

    def effort(self, dt: float, d: float, v: float, vmax: float, cap: float = 1.0) -> float:
        """The effort that makes the MA follow the ramp (its speed command
        within +-vmax: the board's speed limit), at most cap."""
        r = self.ramp
        v_cmd = r.v + self.kpos * (r.x - d)
        if v_cmd > vmax:
            v_cmd = vmax
        elif v_cmd < -vmax:
            v_cmd = -vmax
        self.pid.out_min = -cap
        self.pid.out_max = cap
        a = r.a                     # the ramp's acceleration, fed forward for the next period:
        if a > 0.0 and r.v + a * dt > vmax:      # not past vmax, where it stops accelerating
            a = (vmax - r.v) / dt if r.v < vmax else 0.0
        elif a < 0.0 and r.v + a * dt < -vmax:
            a = (-vmax - r.v) / dt if r.v > -vmax else 0.0
        # the speed error against the command as it was when v was measured (delay ago)
        self.u = self.pid.update(v_cmd - self.delay * r.a, v, dt, v_cmd + self.kaff * a)
        return self.u

    def off(self) -> None:
        self.pid.reset()
        self.u = 0.0


def play(theta: float, gap: float, dw: float, half: float):
    """The worm turns dw (joint mrad) against a joint at theta through play
    +-half (gap: worm minus joint) -> (theta, gap). Pure."""
    g = gap + dw
    if g > half:
        return theta + g - half, half
    if g < -half:
        return theta + g + half, -half
    return theta, g


def contact(theta: float, side: int, slack: float, dw: float, loaded: bool):
    """The worm turns dw (joint mrad) with the load sensed `loaded` at the end of the
    period -> (theta, side, slack): side +-1 the way the worm drives the gear, 0 in
    the play; slack the worm's travel in the play since it left the gear. Pure."""
    s = 1 if dw > 0 else -1
    if side == s:
        return theta + dw, side, 0.0
    if side == -s:
        side = 0
        slack = 0.0
    if loaded:
        return theta + 0.5 * dw, s, 0.0
    return theta, 0, slack + (dw if dw > 0 else -dw)


class Rot:
    """The joint-rotation angle loop on the engaged joint (mrad, effort)."""

    def __init__(self, cfg, n_joints: int) -> None:
        self.gains = [[cfg.ROT_KP, cfg.ROT_KI, cfg.ROT_KD] for _ in range(n_joints)]
        self.pid = PID(cfg.ROT_KP, cfg.ROT_KI, cfg.ROT_KD, cfg.ROT_KFF)
        self.q = cfg.GEAR_MRAD_PER_COUNT
        self.kaff = cfg.ROT_KAFF
        self.half = cfg.BACKLASH_MRAD / 2.0
        self.ramp = Ramp()
        self.j = 0                 # engaged joint (1-based), 0: none
        self.gap = 0.0             # estimated worm-minus-joint play of the mesh (no current sense)
        self.sense = getattr(cfg, "ROT_ISENSE_PIN", None) is not None
        self.contact_load = getattr(cfg, "ROT_CONTACT_LOAD", 0.0)
        self.side = 0              # the way the worm drives the gear (+-1), 0: in the play (current sense)
        self.slack = 0.0           # the worm's travel in the play since it left the gear
        self.g = 0                 # last gear count
        self.u = 0.0

    def engage(self, j: int, theta: float, count: int) -> None:
        """The MA stands on joint j: a fresh mesh unless it is still on it."""
        if j != self.j:
            self.gap = 0.0
            self.side = 0
            self.slack = 0.0
        self.j = j
        self.g = count
        g = self.gains[j - 1]
        self.pid.set_gains(g[0], g[1], g[2])
        self.pid.reset()
        self.ramp.reset(theta)
        self.u = 0.0

    def release(self) -> None:
        """The MA leaves the joint (locomotion): the mesh is gone."""
        self.j = 0
        self.off()

    def track(self, theta: float, count: int, load: float = 0.0) -> float:
        """The engaged joint's angle after the gear moved to count (load: the current
        sense's reading, with one)."""
        dw = (count - self.g) * self.q
        self.g = count
        if dw == 0.0:
            return theta
        if self.sense:
            theta, self.side, self.slack = contact(theta, self.side, self.slack, dw, load >= self.contact_load)
            return theta
        theta, self.gap = play(theta, self.gap, dw, self.half)
        return theta

    def effort(self, dt: float, theta: float) -> float:
        r = self.ramp
        self.u = self.pid.update(r.x / 1000.0, theta / 1000.0, dt, (r.v + self.kaff * r.a) / 1000.0)
        return self.u

    def off(self) -> None:
        self.pid.reset()
        self.u = 0.0
