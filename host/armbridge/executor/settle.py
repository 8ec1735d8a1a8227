"""The settle times' tolerance and the wait for an arm to come to rest (executor/run.py).

A board with a dead band (the syringe-pump board: the soft-arm paper's P controller,
eq. 24, drives nothing while |theta_r - theta_c| is inside it) is only
promised to rest inside the band: its firmware's finer settle (control.h
seek_control: within 6 mrad, re-seek past 20) is the board's business, and a joint
of a drawn rig or one still re-seeking may rest anywhere in the band, where the
bend sensor's reading dithers by one ADC count at the edge. The tolerance is
therefore the dead band plus one count of the joint's sensor (its calibration's
mrad per count), so that a reading flipping by a count at the edge is not taken
for the joint leaving the band.

The run waits (bounded, run.SETTLE_WAIT_S) until the arm rests inside that
tolerance (`resting`) and has stopped (`still`: the firmware's fine settle goes
on inside the band, and the goal is judged on the last sample; before, a paced
soft demo was judged while its pumps still crept, 1.5-2.5 mm from the goal,
then 0.3-1.9 mm).

Both are read from the board where its protocol can (Modbus: holding registers 12..14
and the calibration 24..35, docs/modbus.md); the line protocol has no query for them,
so the host takes the defaults of the board's firmware (its config's
DBAND_DEFAULT_MRAD and BEND_DEFAULT). A board without a dead band gets no settle times.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from armbridge.errors import ArmbridgeError


def count_mrad(bend: Sequence[Sequence[int]]) -> np.ndarray:
    """mrad per ADC count of each joint's linear calibration (adc_a, a, adc_b, b)."""
    return np.array([abs(b - a) / max(1, abs(adc_b - adc_a)) for adc_a, a, adc_b, b in bend], float)


def board_tolerance(band_mrad, bend, n: int) -> tuple[np.ndarray, str]:
    """The tolerance from what the board said (Modbus: its dead band per joint, its calibrations)."""
    return (np.asarray(band_mrad, float) + count_mrad([bend[4 * j:4 * j + 4] for j in range(n)])) / 1000.0, "board"


def settle_tolerance(fw: str, n: int) -> tuple[np.ndarray, str] | None:
    """(tolerance per joint in rad, "default") for a board of firmware `fw` whose protocol has
    no query for it (the line protocol), from its firmware's config; None (no dead band)."""
    from armbridge import boards

    try:
        cfg = boards.config(boards.of_identity(fw) or fw)
    except (ArmbridgeError, OSError):  # a board kind this host has no firmware of
        return None
    mrad = getattr(cfg, "DBAND_DEFAULT_MRAD", None)
    if mrad is None:
        return None
    bend = getattr(cfg, "BEND_DEFAULT", None)
    count = count_mrad(bend) if bend is not None and len(bend) == n else np.zeros(n)
    return (float(mrad) + count) / 1000.0, "default"


#: rad: how far a joint's reading may wander while it counts as still (a few counts of the bend
#: sensor's noise and steps), and s of board time it must stay so (the firmware's fine settle ends)
STILL_RAD = 0.005
STILL_S = 0.4


def still(samples, tol: float = STILL_RAD, hold_s: float = STILL_S) -> bool:
    """No joint's reading has moved more than `tol` over the last `hold_s` of board time:
    the arm has stopped, not only entered its band (a pump board's fine settle,
    control.h seek_control, goes on inside the dead band after the joint enters it)."""
    if not samples or samples[-1][0] - samples[0][0] < hold_s:
        return False
    t_end = samples[-1][0]
    recent = [s[2] for s in samples if t_end - s[0] <= hold_s]
    q = np.asarray(recent, float)
    return bool(np.all(q.max(axis=0) - q.min(axis=0) <= tol + 1e-12))


def resting(samples, target: np.ndarray, tol: np.ndarray, hold_s: float = 0.1) -> bool:
    """The telemetry samples (t, state, q, ...) have stayed within `tol` of `target` for
    the last `hold_s` of board time."""
    if not samples or samples[-1][0] - samples[0][0] < hold_s:
        return False
    t_end = samples[-1][0]
    for s in reversed(samples):
        if np.any(np.abs(s[2] - target) > tol + 1e-9):
            return False
        if t_end - s[0] >= hold_s:
            return True
    return False
