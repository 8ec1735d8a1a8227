"""The MA's joint estimate through the worm's play with the current sense
(firmware/masr_ma/drive.py `contact`), pure: against a worm of unknown play
and a gear met anywhere in it, with hypothesis."""

from drive import contact
from hypothesis import given, settings
from hypothesis import strategies as st


def _run(play: float, gap0: float, moves: list[float], step: float):
    """A true worm and joint (the emulator's model: the gap in [-play/2, play/2]) and the
    firmware's estimate, the worm turned `moves` (mrad) in periods of `step` -> the
    true and the estimated joint after each move."""
    half = play / 2.0
    gap, theta = gap0, 0.0
    est, side, slack = 0.0, 0, 0.0
    out = []
    for m in moves:
        n = max(1, int(abs(m) / step + 0.5))
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


@settings(max_examples=200, deadline=None)
@given(play=st.floats(1.0, 30.0), where=st.floats(-1.0, 1.0),
       moves=st.lists(st.floats(-300.0, 300.0).filter(lambda x: abs(x) > 35.0), min_size=1, max_size=6),
       step=st.floats(0.2, 2.8))
def test_the_estimate_follows_the_joint_within_half_a_period(play, where, moves, step):
    """Moves longer than the play (each one meets the gear): each meeting misplaces the
    estimate by at most half a period's travel (the load came on somewhere inside the
    period), whatever the play's width and wherever the fresh mesh began in it; so
    after k meetings (the first move, then every reversal) it is within k half periods."""
    k = 0
    prev = 0.0
    for m, (theta, est, slack) in zip(moves, _run(play, where * play / 2.0, moves, step)):
        k += 1 if m * prev <= 0 else 0
        prev = m
        assert abs(est - theta) <= k * 0.5 * step + 1e-9 * (1 + abs(theta)), (k, theta, est)
        assert slack == 0.0


def test_in_the_play_nothing_moves_and_the_slack_grows():
    est, side, slack = contact(10.0, 0, 0.0, 2.0, False)
    assert (est, side, slack) == (10.0, 0, 2.0)
    est, side, slack = contact(est, side, slack, 2.0, True)     # the load comes on: half the period counts
    assert (est, side, slack) == (11.0, 1, 0.0)
    est, side, slack = contact(est, side, slack, 2.0, False)    # still pushing, the load read low (braking)
    assert (est, side, slack) == (13.0, 1, 0.0)
    est, side, slack = contact(est, side, slack, -1.0, False)   # it turns back: into the play again
    assert (est, side, slack) == (13.0, 0, 1.0)
