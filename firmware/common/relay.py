"""Relay feedback for auto-tuning one loop (the RELAY verb; docs/calibration.md).

Why: Astrom and Hagglund's relay experiment (Automatica 20(5), 1984) finds a
loop's ultimate gain and period without a model and without driving it
unstable: an on/off output of +-d about the set point makes the joint oscillate
in a limit cycle whose amplitude a and period Tu give the ultimate gain
Ku = 4 d / (pi sqrt(a^2 - h^2)) (describing function of a relay with
hysteresis h). Klipper's PID_CALIBRATE runs the same experiment on a heater.
The board runs the relay at its control period (the host's line is far too
slow to close this loop) and reports Tu and a; the host turns them into gains
(armbridge.calibrate.tuning).

Units are the caller's (the boards use rad or m, and an effort in [-1, 1]).
`step(sp, meas, now_ms)` -> the output, or None once `cycles` whole cycles
after the first (settling) one have been seen; `result()` is then
(period_ms, amplitude): the mean period and the mean half peak-to-peak.
`step` also gives up (None, result() None) after `timeout_ms` without a switch.
"""


class Relay:
    def __init__(self, amp: float, hyst: float, cycles: int, now_ms: int, timeout_ms: int = 10000) -> None:
        self.amp = amp
        self.hyst = hyst
        self.cycles = cycles
        self.timeout_ms = timeout_ms
        self.out = amp            # starts pushing up
        self.last_switch = now_ms
        self.ups: list = []       # times of the switches to +amp (one per cycle)
        self.peaks: list = []     # (max, min) of each whole cycle
        self.hi: float | None = None
        self.lo: float | None = None
        self.done = False
        self.failed = False

    def step(self, sp: float, meas: float, now_ms: int):
        if self.done:
            return None
        if now_ms - self.last_switch > self.timeout_ms:
            self.done = True
            self.failed = True
            return None
        e = sp - meas
        if self.hi is None or meas > self.hi:
            self.hi = meas
        if self.lo is None or meas < self.lo:
            self.lo = meas
        if self.out > 0 and e < -self.hyst:
            self.out = -self.amp
            self.last_switch = now_ms
        elif self.out < 0 and e > self.hyst:
            self.out = self.amp
            self.last_switch = now_ms
            self.ups.append(now_ms)
            if len(self.ups) >= 2:        # a whole cycle since the last up switch
                self.peaks.append((self.hi, self.lo))
            self.hi = meas
            self.lo = meas
            if len(self.ups) >= self.cycles + 2:   # the first cycle settles, then `cycles` counted
                self.done = True
                return None
        return self.out

    def result(self):
        """(period_ms, amplitude) over the counted cycles, None if it gave up."""
        if self.failed or len(self.ups) < 3:
            return None
        ups = self.ups[1:]
        period = (ups[-1] - ups[0]) / (len(ups) - 1)
        peaks = self.peaks[1:]
        amp = sum((hi - lo) for hi, lo in peaks) / (2 * len(peaks))
        return period, amp
