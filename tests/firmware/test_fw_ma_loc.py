"""The MA's localisation (firmware/masr_ma/loc.py), pure: a wheel with slip
along the 5R arm, hall edges at the magnets within the window."""

from fwma import load_config
from loc import MISSED, OK, SPURIOUS, Loc

CFG = load_config()
Q = CFG.WHEEL_MM_PER_COUNT
W = CFG.HALL_WINDOW_MM


def _loc() -> Loc:
    return Loc(CFG.LINK_LENGTHS_MM, Q, W, CFG.SLIP_MAX)


class _Walk:
    """A true MA moving in 0.1 mm wheel steps with a slip pattern, firing the
    hall edge inside a magnet's window at `fire` * window before the magnet
    (1: entering the window, -1: leaving it), feeding a Loc as the board does
    (edges, then the count)."""

    def __init__(self, loc, d=0.0, slip=0.0, fire=1.0) -> None:
        self.loc = loc
        self.d = d
        self.s = 0.0
        self.slip = slip
        self.fire = fire
        self.level = 1 if self._near() <= W else 0
        self.errs = []          # (true d, |est - d|, bound) after every step
        self.events = []

    def _near(self) -> float:
        return min([abs(self.d - r) for r in self.loc.r])

    def count(self) -> int:
        x = self.s / Q + 1e-9
        i = int(x)
        return i - 1 if i > x else i

    def go(self, to: float, present=None) -> None:
        step = 0.1 if to > self.d else -0.1
        while (to - self.d) * step > 0:
            self.s += step
            self.d += step * (1.0 + self.slip)
            near = 1e9
            fires = False
            for k in range(len(self.loc.r)):
                if present is None or present[k]:
                    x = self.d - self.loc.r[k]
                    near = min(near, abs(x))
                    if abs(x) <= W and x * step >= -self.fire * W * 0.1:
                        fires = True
            if self.level == 0 and fires:
                self.level = 1
                self.events.append(self.loc.edge(self.count()))
            elif self.level == 1 and near > W + 0.5:
                self.level = 0
            kind, k = self.loc.update(self.count(), self.level)
            if kind != OK:
                self.events.append((kind, k))
                return
            self.errs.append((self.d, abs(self.loc.d() - self.d), self.loc.err()))


def test_magnet_positions_and_links():
    loc = _loc()
    assert loc.r == [0.0, 200.0, 400.0, 600.0, 700.0]
    loc.home(0)
    assert loc.d() == 0.0 and loc.jd() == 1 and loc.dlink() == 0.0
    loc.restore(650.0, 1.0, 0)
    assert loc.jd() == 4 and abs(loc.dlink() - 50.0) < 1e-9
    loc.restore(800.0, 1.0, 0)
    assert loc.jd() == 5 and abs(loc.dlink() - 100.0) < 1e-9


def test_bound_holds_with_slip_and_drops_at_each_magnet():
    # the worst slip the bound allows, over the whole arm and back
    for slip in (CFG.SLIP_MAX, -CFG.SLIP_MAX):
        for fire in (1.0, 0.1):       # the edge on entering the window (where the board anchors: w before the
                                      # magnet), or late, 0.1 w before the magnet (a true window of 0.1 w)
            loc = _loc()
            loc.home(0)
            walk = _Walk(loc, 0.0, slip, fire)
            walk.go(799.9)
            walk.go(-1.6)
            assert all([e[0] == OK for e in walk.events]), walk.events
            mags = [e[1] for e in walk.events]
            assert mags == [2, 3, 4, 5, 5, 4, 3, 2, 1], mags
            for d, err, bound in walk.errs:
                assert err <= bound + 1e-6, (slip, fire, d, err, bound)
            worst = max([e[1] for e in walk.errs])
            assert worst > 1.0          # the slip shows ...
            # ... and each magnet re-zeroes it: right after an edge the error is
            # at most the window and a count
            for i in range(1, len(walk.errs)):
                if walk.errs[i][2] < walk.errs[i - 1][2] - 0.5:
                    assert walk.errs[i][1] <= W + 2 * Q + 0.2


def test_bound_over_a_link_is_within_the_host_margin():
    """e(l_max) + the stop tolerance <= the host's d_margin (5 mm)."""
    loc = _loc()
    loc.home(0)
    loc.travel = int(max(CFG.LINK_LENGTHS_MM) / Q)
    bound = loc.err()
    assert abs(bound - (W + Q + CFG.SLIP_MAX * max(CFG.LINK_LENGTHS_MM))) < 1e-6
    assert bound + CFG.STOP_TOL_MM <= 5.0, bound


def test_missed_magnet_is_detected_past_the_window():
    loc = _loc()
    loc.home(0)
    walk = _Walk(loc, 0.0, 0.0)
    walk.go(300.0, present=[True, False, True, True, True])
    assert walk.events and walk.events[-1] == (MISSED, 2), walk.events
    # it stopped right past the window, not at the next magnet
    assert 200.0 + W < walk.d < 200.0 + W + loc.err() + W + 0.5, walk.d


def test_slip_burst_beyond_the_bound_is_a_missed_magnet():
    # the wheel spins (the MA advances 10 % less than the encoder says)
    loc = _loc()
    loc.home(0)
    walk = _Walk(loc, 0.0, -0.10)
    walk.go(250.0)
    assert walk.events and walk.events[-1] == (MISSED, 2), walk.events
    assert walk.d < 200.0 - W        # the MA never reached the magnet


def test_spurious_edge_faults():
    loc = _loc()
    loc.home(0)
    c = int(100.0 / Q)
    assert loc.update(c, 0) == (OK, 0)
    kind, k = loc.edge(c)
    assert kind == SPURIOUS and k in (1, 2)


def test_reverse_inside_the_window_needs_no_new_edge():
    loc = _loc()
    loc.home(0)
    walk = _Walk(loc, 0.0, 0.0)
    walk.go(199.0)                   # into magnet 2's window, edge at 198.5
    assert walk.events == [(OK, 2)]
    walk.go(150.0)                   # back out, the sensor still high at first
    assert walk.events == [(OK, 2)]
    walk.go(260.0)                   # over it again: a fresh edge, re-zeroed
    assert walk.events == [(OK, 2), (OK, 2)]
    walk.go(150.0)
    assert walk.events == [(OK, 2), (OK, 2), (OK, 2)]


def test_unknown_checks_nothing():
    loc = _loc()
    assert not loc.known
    assert loc.edge(1000) == (OK, 0)
    assert loc.update(99999, 0) == (OK, 0)
