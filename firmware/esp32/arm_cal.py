"""The 3R arm's calibration on the board: RELAY, CAL and what CALID saves (arm.Board's `cal`).

Why here and not in arm.py: the calibration verbs run rarely, at a bench, and
arm.py is the arm's control; Board keeps one `ArmCal` and calls it from its
tick and its position read. `armbridge calibrate esp32` (host
armbridge/calibrate/arm3r.py, docs/drawing.md "Calibration") drives them.

RELAY j amp hyst cycles (effort rig only; the positional servos close their
own loops, so the pca9685 rig answers VERB): Astrom-Hagglund relay feedback
(common/relay.py) in place of joint j's PID, inside the control tick: effort
+-amp/1000 about the set point, switching when the error passes +-hyst mrad.
The other joints keep their PIDs. After `cycles` whole cycles (the first one
settles and is not counted) the board sends `EV RELAY j period_ms amp_mrad`
(the mean period and half peak-to-peak, in the pots' terms) and joint j's PID
holds the set point again (integrator reset). Refused LATCHED while latched
(a motion verb), RANGE while waypoints are queued; a waypoint queued while it
runs, a stop or a latch ends it, and a relay that sees no switch for 10 s
gives up: both report `EV RELAY j 0 0`.

CAL j us_a a us_b b:
  * pca9685 rig: the servo's two-point calibration (servos.py), as before;
    refused RANGE when its slope is not within 0.5..2 times the config's
    (SERVO_CAL: a mistyped point would swing the joint far off).
  * effort rig (no positional servos): the pot's two-point calibration, a
    documented reuse of the verb's shape: "pulse" us stands for the pot
    reading mid + (us - 1500) mrad, mid the middle of joint j's hard limits
    (1 us per mrad, so 500..2500 covers +-1000 mrad about mid), and the board
    takes the joint to be at angle a (mrad) where the pot reads that of us_a,
    at b where it reads that of us_b, linear between and beyond. Every
    position the board uses (its loops, following error, telemetry) is the
    corrected one. Refused RANGE when the slope (b - a) / (reading_b -
    reading_a) is outside 0.8..1.25 (a pot reads its joint within +-6 %).
    The identity (`CAL j 1000 mid-500 2000 mid+500`) undoes it.
  Both RAM only until CALID.

DBAND j mrad (pca9685 rig only): servo j's hysteresis width, the difference
between where its joint rests for one pulse coming from above and from below
(its dead band on both sides and its gear play, 0..LEAD_MAX_MRAD); servos.py
leads the pulse by half of it toward the side it moves to. RAM until CALID.

cal_text() / cal_apply(tokens) (common/calstore.py): the settings CALID saves
and a boot loads back, as tokens `G<j>=kp,ki,kd` (thousandths, as GAIN),
`C<j>=us_a,a,us_b,b` (as CAL, for either rig) and `D<j>=mrad` (as DBAND). A token that does not fit
(unknown, malformed, a joint out of range, a CAL the verb would refuse) raises
ValueError and the boot keeps the config's defaults.
"""

import proto
import protodef as P
from relay import Relay

RELAY_TIMEOUT_MS = 10000
POT_SLOPE = (0.8, 1.25)         # pot CAL: corrected per read mrad
SERVO_SLOPE = (0.5, 2.0)        # servo CAL: its us per mrad against the config's
LEAD_MAX_MRAD = 100            # DBAND on the servo rig: a hysteresis wider than this is no servo's


class ArmCal:
    def __init__(self, board) -> None:
        self.b = board
        cfg = board.cfg
        n = board.n
        self.n = n
        self.positional = board.positional
        self.mid = [(cfg.LIMITS_MRAD[j][0] + cfg.LIMITS_MRAD[j][1]) / 2.0 for j in range(n)]
        # CAL in force per joint (us_a, a, us_b, b); the pot's is None while it is the identity
        self.cal = [None] * n  # type: list
        if self.positional:
            self.cal = [tuple(c) for c in cfg.SERVO_CAL]
        self.pot = [None] * n  # type: list  # effort rig: (r0 rad, a0 rad, slope) per joint, or None
        self.lead = [0] * n             # pca9685 rig: DBAND, each servo's hysteresis width (mrad)
        self.relay = None  # type: Relay | None
        self.relay_j = -1
        self.relay_sp = 0.0
        self.ms = 0                     # the relay's own clock: control ticks, in ms

    # ------------------------------------------------------------ verbs
    def cmd_relay(self, v: list) -> list:
        j, amp, hyst, cycles = v
        b = self.b
        if b.traj.busy():
            raise proto.ProtocolError(P.RANGE, "", "queued")
        self.relay = Relay(amp / 1000.0, hyst / 1000.0, cycles, self.ms, RELAY_TIMEOUT_MS)
        self.relay_j = j - 1
        self.relay_sp = b.traj.sp[j - 1] / 1000.0
        return []

    def cmd_dband(self, v: list) -> list:
        """DBAND j mrad on the pca9685 rig: servo j's hysteresis width (its dead band, both
        sides, and its gear play), which servos.py leads the pulse by half of."""
        if v[1] > LEAD_MAX_MRAD:
            raise proto.ProtocolError(P.RANGE, "", "mrad")
        self.set_lead(v[0] - 1, v[1])
        return []

    def set_lead(self, j0: int, mrad: int) -> None:
        self.b.hal.set_lead(j0, mrad)
        self.lead[j0] = mrad

    def cmd_cal(self, v: list) -> list:
        j = v[0]
        try:
            self.set_cal(j - 1, v[1], v[2], v[3], v[4])
        except ValueError:
            raise proto.ProtocolError(P.RANGE, "", str(j))
        return []

    def set_cal(self, j0: int, us_a: int, a: int, us_b: int, b: int) -> None:
        """Checks and sets joint j0's CAL (see the module docstring); ValueError if it does not fit."""
        if not 0 <= j0 < self.n or us_a == us_b or a == b:
            raise ValueError("cal")
        if self.positional:
            c = self.b.cfg.SERVO_CAL[j0]
            k0 = (c[2] - c[0]) / (c[3] - c[1])
            r = ((us_b - us_a) / (b - a)) / k0
            if not SERVO_SLOPE[0] <= r <= SERVO_SLOPE[1]:
                raise ValueError("cal slope")
            self.b.hal.set_calibration(j0, us_a, a, us_b, b)
        else:
            slope = (b - a) / (us_b - us_a)
            if not POT_SLOPE[0] <= slope <= POT_SLOPE[1]:
                raise ValueError("cal slope")
            r0 = (self.mid[j0] + us_a - 1500) / 1000.0
            if us_b - us_a == b - a and us_a - 1500 == a - self.mid[j0]:
                self.pot[j0] = None         # the identity
            else:
                self.pot[j0] = (r0, a / 1000.0, slope)
        self.cal[j0] = (us_a, a, us_b, b)

    # ------------------------------------------------------------ the board's hooks
    def correct(self, q: list) -> None:
        """Pot readings (rad) -> joint angles, in place (effort rig, after CAL)."""
        for j in range(self.n):
            p = self.pot[j]
            if p is not None:
                q[j] = p[1] + (q[j] - p[0]) * p[2]

    def tick(self, u: list, q: list, period_ms: int) -> None:
        """After the PIDs (DRIVE, effort rig): the relay's output replaces joint j's."""
        self.ms += period_ms
        r = self.relay
        if r is None:
            return
        j = self.relay_j
        out = r.step(self.relay_sp, q[j], self.ms)
        if out is not None:
            u[j] = out
            return
        self.finish()

    def finish(self) -> None:
        """The relay is over (done, given up or stopped): its event, and the PID holds again."""
        r = self.relay
        if r is None:
            return
        j = self.relay_j
        self.relay = None
        res = r.result() if r.done else None
        b = self.b
        b.pids[j].reset()
        b.caps[j].reset(b.q[j])
        if res is None:
            b.link.event("RELAY", [j + 1, 0, 0])
        else:
            b.link.event("RELAY", [j + 1, int(round(res[0])), int(round(res[1] * 1000.0))])

    # ------------------------------------------------------------ CALID
    def cal_text(self) -> list:
        out = []
        for j in range(self.n):
            p = self.b.pids[j]
            out.append("G%d=%d,%d,%d" % (j + 1, int(round(p.kp * 1000)), int(round(p.ki * 1000)),
                                        int(round(p.kd * 1000))))
        for j in range(self.n):
            c = self.cal[j]
            if c is not None:
                out.append("C%d=%d,%d,%d,%d" % (j + 1, c[0], c[1], c[2], c[3]))
        for j in range(self.n):
            if self.lead[j]:
                out.append("D%d=%d" % (j + 1, self.lead[j]))
        return out

    def cal_apply(self, tokens: list) -> None:
        gains = []
        cals = []
        leads = []
        for t in tokens:            # all parsed and checked before any is set
            if len(t) < 3 or t[0] not in "GCD" or t[1:].find("=") < 0:
                raise ValueError("token")
            k, vals = t[1:].split("=", 1)
            j = int(k)
            x = [int(s) for s in vals.split(",")]
            if not 1 <= j <= self.n:
                raise ValueError("joint")
            if t[0] == "G":
                if len(x) != 3 or min(x) < 0 or max(x) > 1000000:
                    raise ValueError("gain")
                gains.append((j, x))
            elif t[0] == "D":
                if len(x) != 1 or not 0 <= x[0] <= LEAD_MAX_MRAD or not self.positional:
                    raise ValueError("dband")
                leads.append((j, x[0]))
            else:
                if len(x) != 4 or not (500 <= x[0] <= x[2] <= 2500):
                    raise ValueError("cal")
                cals.append((j, x))
        saved = [tuple(c) if c is not None else None for c in self.cal]
        try:
            for j, x in cals:
                self.set_cal(j - 1, x[0], x[1], x[2], x[3])
        except ValueError:
            for j in range(self.n):     # none of it: the defaults stay whole
                c = saved[j]
                if c is not None:
                    self.set_cal(j, c[0], c[1], c[2], c[3])
                else:
                    self.pot[j] = None
                    self.cal[j] = None
            raise
        for j, x in gains:
            self.b.pids[j - 1].set_gains(x[0] / 1000.0, x[1] / 1000.0, x[2] / 1000.0)
        for j, m in leads:
            self.set_lead(j - 1, m)
