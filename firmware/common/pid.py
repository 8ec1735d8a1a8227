"""PID with output clamp, integrator anti-windup and derivative on measurement,
plus a velocity feed-forward term. Units are the caller's (the board uses rad,
rad/s and an effort in [-1, 1])."""


class PID:
    def __init__(self, kp: float, ki: float = 0.0, kd: float = 0.0, kff: float = 0.0,
                 out_min: float = -1.0, out_max: float = 1.0) -> None:
        self.kp = kp
        self.ki = ki
        self.kd = kd
        self.kff = kff
        self.out_min = out_min
        self.out_max = out_max
        self.integ = 0.0        # integral term, already multiplied by ki
        self.prev = 0.0         # last measurement
        self.primed = False     # False until the first update (no derivative kick)
        self.out = 0.0

    def set_gains(self, kp: float, ki: float, kd: float) -> None:
        self.kp = kp
        self.ki = ki
        self.kd = kd

    def reset(self) -> None:
        self.integ = 0.0
        self.primed = False
        self.out = 0.0

    def update(self, sp: float, meas: float, dt: float, sp_vel: float = 0.0) -> float:
        """One step of dt seconds -> output in [out_min, out_max]."""
        err = sp - meas
        d = 0.0
        if self.primed and dt > 0:
            d = -self.kd * (meas - self.prev) / dt
        self.prev = meas
        self.primed = True
        rest = self.kp * err + d + self.kff * sp_vel
        integ = self.integ + self.ki * err * dt
        lo = self.out_min
        hi = self.out_max
        # anti-windup: the integral term alone never exceeds the output range,
        # and it only grows while the output is not saturated in that direction
        if integ > hi:
            integ = hi
        elif integ < lo:
            integ = lo
        u = rest + integ
        if (u > hi and integ > self.integ) or (u < lo and integ < self.integ):
            integ = self.integ
            u = rest + integ
        self.integ = integ
        if u > hi:
            u = hi
        elif u < lo:
            u = lo
        self.out = u
        return u
