"""Localisation of the MASR mobile actuator along its arm (pure: counts in, mm out).

The MA's position is d = r_{j_d} + d_link (masr paper, section II-A, Fig. 2b):
r_j = l_1 + ... + l_{j-1} is joint j's position (r_1 = 0), j_d the link the MA
is on (the largest j with r_j <= d) and d_link its distance along that link.
d_link is integrated from the wheel encoder and re-zeroed at every magnet: at a
hall rising edge, latched with the wheel count c_e, the magnet k that can have
fired there is identified from the estimate (|d(c_e) - r_k| <= w + e) and the
estimate is re-anchored where the edge fires: w before the magnet on the way
the wheel was counting (`way`), d := r_k - way * w at c_e (anchoring on r_k
itself put the estimate w ahead of the MA, on the side it came from, and a
reversal doubled it). The passage is direction-aware
because the counts are signed: going down the arm the same edge makes j_d the
link below. Slip therefore never accumulates past one magnet.

Error bound. With the hall window w (calibrated where the sensor turns on: the
anchor r_k - way w is within w of the truth for a turn-on point anywhere from
the magnet to 2w before it), the encoder quantum q (one count: the latched count is a floor) and a
slip bound s (|wheel travel - MA travel| <= s * wheel travel), the estimate
after a wheel travel T since the last magnet satisfies

    |d_est - d| <= e(T) = w + q + s * T.

Travelling along one link (T <= l_max) it stays below e(l_max); with the config
(w = 1.5 mm, q = 0.05 mm, s = 1 %, l_max = 200 mm): e <= 3.55 mm, and MV stops
within STOP_TOL_MM = 0.5 mm of its target on the estimate, so the MA ends within
4.05 mm of the commanded d: inside the host's d_margin of 5 mm. T counts all
wheel travel, so back-and-forth moves on one link without a magnet grow it (the
bound is reported, `err()`, never assumed).

What the bound rests on: s is a model of the wheel on the link, not something
the MA measures. Its only position references are the magnets, so a slip beyond
s (a burst: dirt, oil) shows at the next magnet, where the edge is not where the
count says (MISSED or SPURIOUS below: every ROT, and every MV onto a joint,
re-anchors on its magnet first, so no joint is turned with the MA off it); after
the last magnet before a stop nothing the MA senses shows it, and e(T) is then a
bound only under the model. The host reports that leg as dead reckoning
(executor/masr.py `dead_reckoning`, the run summary's `masr` section).

Faults, never silently wrong (the board stops and latches FAULT):
  * MISSED k: the estimate is on the far side of magnet k by more than w + e,
    coming from the anchor's side, and no edge came (the encoder says the MA
    went through the window, where the sensor must fire);
  * SPURIOUS: an edge where no magnet can be (|d(c_e) - r_k| > w + e for every k).
The anchor's own magnet is excused until the sensor has gone low away from it
(`level` 0 and beyond w + e): the MA may reverse inside the window, where no new
edge comes; once it has left, coming back over it must fire again.
"""

OK = 0
MISSED = 1
SPURIOUS = 2


class Loc:
    def __init__(self, link_lengths_mm, mm_per_count: float, window_mm: float, slip: float) -> None:
        r = [0.0]
        for length in link_lengths_mm[:-1]:
            r.append(r[-1] + length)
        self.r = r                    # joint k (1-based) at r[k - 1], mm (the arm's kinematics)
        self.m = list(r)              # magnet k's centre, mm from home (MAG; nominal: on its joint)
        self.win = [float(window_mm)] * len(r)   # magnet k's hall half window, mm (MAG; nominal: the config's)
        self.length = float(sum(link_lengths_mm))
        self.q = float(mm_per_count)
        self.w = float(window_mm)     # the bound's window (the config's: a calibration does not change the bound)
        self.c_home = 0               # the wheel count at d = 0 (HOME; a restore infers it)
        self.slip = float(slip)
        self.known = False            # False: d unknown (UNHOMED); no checks
        self.c = 0                    # last wheel count seen
        self.d_a = 0.0                # anchor: the estimate d_a at count c_a ...
        self.c_a = 0
        self.e_a = self.w             # ... known within e_a
        self.mag = 0                  # the anchor's magnet (1-based), 0: none
        self.side = 0                 # which side of it the MA has gone to (+-1), 0: not yet
        self.travel = 0               # wheel counts travelled since the anchor
        self.way = 0                  # the way the wheel last counted (+-1; 0: not yet)
        self.jump = 0.0               # what the last re-zero moved the estimate by (mm)

    # ------------------------------------------------------------ estimate

    def at(self, count: int) -> float:
        """The estimate of d (mm) at a wheel count."""
        return self.d_a + (count - self.c_a) * self.q

    def d(self) -> float:
        return self.at(self.c)

    def err(self) -> float:
        """The error bound e = w + q + s * T of the estimate now (mm)."""
        return self.e_a + self.q + self.slip * self.travel * self.q

    def jd(self) -> int:
        """The link the MA is on (1-based): the largest j with r_j <= d."""
        d = self.d()
        j = 1
        for k in range(1, len(self.r)):
            if self.r[k] <= d:
                j = k + 1
        return j

    def dlink(self) -> float:
        return self.d() - self.r[self.jd() - 1]

    def near(self, d: float) -> int:
        """The joint (1-based) closest to d."""
        return _nearest(self.r, d)

    def near_mag(self, d: float) -> int:
        """The magnet (1-based) whose centre is closest to d."""
        return _nearest(self.m, d)

    # ------------------------------------------------------------ calibration (MAG, WHEEL)

    def set_scale(self, mm_per_count: float) -> None:
        """A new travel per count; the estimate now stays where it is."""
        if self.known:
            self.d_a = self.d()
            self.c_a = self.c
        self.q = float(mm_per_count)

    def set_magnet(self, k: int, pos_mm: float, win_mm: float) -> None:
        self.m[k - 1] = float(pos_mm)
        self.win[k - 1] = float(win_mm)

    # ------------------------------------------------------------ anchors

    def home(self, count: int) -> None:
        """At the base stop on magnet 1: d := 0."""
        self._anchor(0.0, count, self.w, 1)
        self.c_home = count

    def restore(self, d: float, e: float, count: int) -> None:
        """A d known within e (a persisted record) at this count."""
        k = self.near_mag(d)
        self._anchor(d, count, e, k if abs(d - self.m[k - 1]) <= self.win[k - 1] + e else 0)
        self.c_home = count - int(round(d / self.q))

    def lose(self) -> None:
        self.known = False

    def _anchor(self, d: float, count: int, e: float, mag: int) -> None:
        self.known = True
        self.d_a = d
        self.c_a = count
        self.c = count
        self.e_a = e
        self.mag = mag
        self.side = 0
        self.travel = 0

    # ------------------------------------------------------------ updates

    def update(self, count: int, level: int):
        """The wheel count of this period and the hall level -> (OK, 0) or
        (MISSED, k)."""
        self._counted(count)
        if not self.known:
            return OK, 0
        return self._check(self.at(count), level)

    def edge(self, count: int):
        """A hall rising edge latched at `count` -> (OK, k) the magnet re-zeroed
        at, (MISSED, k) a magnet passed before it, (SPURIOUS, k) no magnet can
        be there (k: the nearest), or (OK, 0) while d is unknown (ignored).
        The edge fires w before the magnet on the way the MA comes: d := r_k - way w."""
        self._counted(count)
        if not self.known:
            return OK, 0
        est = self.at(count)
        kind, k = self._check(est, 1)
        if kind != OK:
            return kind, k
        k = self.near_mag(est)
        if abs(est - self.m[k - 1]) > self.w + self.err():
            return SPURIOUS, k
        d = self.m[k - 1] - self.way * self.win[k - 1]
        self.jump = d - est
        self._anchor(d, count, self.w, k)
        return OK, k

    def _counted(self, count: int) -> None:
        if count != self.c:
            self.way = 1 if count > self.c else -1
            self.travel += abs(count - self.c)
        self.c = count

    def _check(self, est: float, level: int):
        tol = self.w + self.err()
        m = self.mag
        if m and self.side == 0 and level == 0 and abs(est - self.m[m - 1]) > tol:
            self.side = 1 if est > self.m[m - 1] else -1
        for k in range(1, len(self.m) + 1):
            rk = self.m[k - 1]
            if k == m:
                s = self.side
            else:
                s = 1 if self.d_a > rk else (-1 if self.d_a < rk else 0)
            if s != 0 and (est - rk) * s < -tol:
                return MISSED, k
        return OK, 0


def _nearest(xs, d: float) -> int:
    best = 1
    for k in range(2, len(xs) + 1):
        if abs(xs[k - 1] - d) < abs(xs[best - 1] - d):
            best = k
    return best
