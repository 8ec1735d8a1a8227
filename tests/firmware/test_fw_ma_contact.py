"""The MA's joint estimate through the worm's play with the current sense
(firmware/masr_ma/drive.py `contact`), pure: against a worm of unknown play and
a gear met anywhere in it. Runs under CPython and under MicroPython
(tests/mpy), so the cases come from a seeded generator of our own."""

import math

from drive import contact


def _run(play, gap0, moves, step):
    """A true worm and joint (the emulator's model: the gap in [-play/2, play/2]) and the
    firmware's estimate, the worm turned `moves` (mrad) in periods of at most `step`
    -> the true and the estimated joint, and the slack, after each move."""
    half = play / 2.0
    gap, theta = gap0, 0.0
    est, side, slack = 0.0, 0, 0.0
    out = []
    for m in moves:
        n = max(1, int(math.ceil(abs(m) / step)))
        for _ in range(n):
            dw = m / n
            g = gap + dw
            push = g - half if g > half else (g + half if g < -half else 0.0)
            if push:
                theta += push
                g = half if push > 0 else -half
            gap = g
            loaded = (dw > 0 and gap >= half) or (dw < 0 and gap <= -half)
            est, side, slack = contact(est, side, slack, dw, loaded)
        out.append((theta, est, slack))
    return out


class _Lcg:
    """A seeded uniform generator (the same numbers under both interpreters)."""

    def __init__(self, seed):
        self.x = seed

    def uniform(self, a, b):
        self.x = (1103515245 * self.x + 12345) % 2147483648
        return a + (b - a) * self.x / 2147483648.0


def test_the_estimate_follows_the_joint_within_half_a_period():
    """Moves longer than the play (each one meets the gear): each meeting misplaces the
    estimate by at most half a period's travel (the load came on somewhere inside the
    period), whatever the play's width and wherever the fresh mesh began in it; so
    after k meetings (the first move, then every reversal) it is within k half periods.
    300 cases: plays 1-30 mrad, the mesh anywhere in it, 1-6 moves of 35-300 mrad
    either way, periods of 0.2-2.8 mrad (the worm at up to 280 mrad/s, 10 ms)."""
    rng = _Lcg(2024)
    for _ in range(300):
        play = rng.uniform(1.0, 30.0)
        gap0 = rng.uniform(-0.5, 0.5) * play
        step = rng.uniform(0.2, 2.8)
        moves = []
        for _ in range(1 + int(rng.uniform(0.0, 6.0))):
            m = rng.uniform(35.0, 300.0)
            moves.append(m if rng.uniform(0.0, 1.0) < 0.5 else -m)
        k = 0
        prev = 0.0
        for m, (theta, est, slack) in zip(moves, _run(play, gap0, moves, step)):
            k += 1 if m * prev <= 0 else 0
            prev = m
            assert abs(est - theta) <= k * 0.5 * step + 1e-9 * (1 + abs(theta)), (play, gap0, moves, step)
            assert slack == 0.0


def test_a_fresh_mesh_at_either_end_of_its_play():
    """The worst starts: the gear already against the worm (it moves at once) and the
    whole play to cross first (it moves only after `play`)."""
    for play in (3.0, 15.0, 30.0):
        for gap0, crossed in ((play / 2, 0.0), (-play / 2, play)):
            theta, est, slack = _run(play, gap0, [100.0], 1.0)[0]
            assert abs(theta - (100.0 - crossed)) < 1e-9
            assert abs(est - theta) <= 0.5


def test_in_the_play_nothing_moves_and_the_slack_grows():
    est, side, slack = contact(10.0, 0, 0.0, 2.0, False)
    assert (est, side, slack) == (10.0, 0, 2.0)
    est, side, slack = contact(est, side, slack, 2.0, True)     # the load comes on: half the period counts
    assert (est, side, slack) == (11.0, 1, 0.0)
    est, side, slack = contact(est, side, slack, 2.0, False)    # still pushing, the load read low (braking)
    assert (est, side, slack) == (13.0, 1, 0.0)
    est, side, slack = contact(est, side, slack, -1.0, False)   # it turns back: into the play again
    assert (est, side, slack) == (13.0, 0, 1.0)
