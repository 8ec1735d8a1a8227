"""A fake MA HAL for the masr_ma firmware tests; MicroPython-compatible.

FakeMaHal is fwutil.FakeHal (clock, scripted UART, persistence) plus a simple
kinematic MA on its arm, stepped 1 ms at a time:
  locomotion  v -> u * V_FULL behind a TAU lag, |dv/dt| <= A_MAX; the wheel
              travels v dt, the MA v dt (1 + slip); both stop at the ends 0, l;
              wheel count = floor(wheel travel / WHEEL_MM_PER_COUNT)
  slip        a seeded LCG, uniform in +-slip (set per test), or a burst
  hall        high once |d - r_j| <= fire * window for a present magnet
              (fire in (0, 1], per test: 1 fires entering the window), low
              beyond window + HYST; the wheel count latched at each rising
              edge; `extra`: true d where a spurious edge fires once
  rotation    worm rate -> u * W_FULL behind a lag; the worm meshes with joint
              j while |d - r_j| <= ENGAGE_MM, through play +-backlash/2
              (gap at `gap0` on a fresh mesh); gear count = floor(worm / q)
  faults      missing magnets, an extra edge, a stalled wheel or joint
The config is masr_ma's, loaded under another name (load_config): under
MicroPython the esp32 board's config.py owns the flat name `config`.
"""

import ma
from fwutil import TICKS_PERIOD, FakeHal, Host

V_FULL = 120.0      # mm/s at full effort
TAU = 0.04          # s
A_MAX = 1000.0      # mm/s^2
W_FULL = 350.0      # mrad/s at full effort
W_TAU = 0.03
MESH_LOAD = 0.03    # the current sense while the worm drives a gear (effort)
HYST = 0.5          # mm
ENGAGE_MM = 3.0


def _here() -> str:
    f = __file__
    i = f.rfind("/")
    return f[:i] if i >= 0 else "."


class _Cfg:
    pass


def load_config(**over):
    """firmware/masr_ma/config.py as an object (the board takes any object with
    its names), with attributes overridden by keyword."""
    d = _here()
    root = d[:d.rfind("/")]
    root = root[:root.rfind("/")]
    with open(root + "/firmware/masr_ma/config.py") as f:
        src = f.read()
    g: dict = {}
    exec(src, g)
    cfg = _Cfg()
    for k in g:
        if k[:1] != "_":
            setattr(cfg, k, g[k])
    for k in over:
        setattr(cfg, k, over[k])
    return cfg


def _floor(x: float) -> int:
    i = int(x)
    return i - 1 if i > x else i


class FakeMaHal(FakeHal):
    def __init__(self, cfg, d=0.0, theta=None, persist=b"", t0=0, slip=0.0, seed=1) -> None:
        FakeHal.__init__(self, q=(0.0,), persist=persist, t0=t0)
        self.cfg = cfg
        r = [0.0]
        for ln in cfg.LINK_LENGTHS_MM[:-1]:
            r.append(r[-1] + ln)
        self.r = r
        self.length = float(sum(cfg.LINK_LENGTHS_MM))
        nj = len(r)
        self.d = float(d)                  # true MA position, mm
        self.theta = list(theta) if theta is not None else [0.0] * nj   # true angles, mrad
        self.v = 0.0
        self.s = 0.0                       # wheel travel, mm
        self.w = 0.0                       # worm, joint mrad
        self.om = 0.0
        self.gap = [0.0] * nj
        self.gap0 = 0.0                    # the play of a fresh mesh
        self.mesh = -1
        self.backlash = cfg.BACKLASH_MRAD
        self.sense_dead = False            # the current sense reads nothing (a broken wire)
        self.u_loco = 0.0
        self.u_rot = 0.0
        self.grip_open = None
        self.slip = slip                   # |slip| bound of the noise
        self.burst = None                  # (d_from, d_to, slip): forced slip between two true d
        self._seed = seed
        self.fire = 1.0                    # edge at fire * window before the magnet (1: entering)
        self.present = [True] * nj
        self.extra = []                    # true d where a spurious edge fires once
        self.wheel_stalled = False
        self.joint_stalled = -1            # 0-based joint that seizes
        self.level = 1 if self._near() <= cfg.HALL_WINDOW_MM else 0
        self.ring: list = []
        self.edges: list = []              # (true d, joint) of every rising edge
        self.max_err = 0.0                 # set by tests
        self.loco_log: list = []           # efforts written

    # ---------------------------------------------------------- the MA HAL
    def loco(self, u: float) -> None:
        self.on = True
        self.u_loco = max(-1.0, min(1.0, u))

    def rot(self, u: float) -> None:
        self.on = True
        self.u_rot = max(-1.0, min(1.0, u))

    def grip(self, open_: bool) -> None:
        self.grip_open = bool(open_)

    def outputs_off(self) -> None:
        FakeHal.outputs_off(self)
        self.u_loco = 0.0
        self.u_rot = 0.0

    def wheel_count(self) -> int:
        return _floor(self.s / self.cfg.WHEEL_MM_PER_COUNT + 1e-9)

    def rot_load(self) -> float:
        """The rotation driver's current sense: MESH_LOAD while the worm drives the engaged
        gear (the play taken up on the side it pushes), 0 in the play or off a joint."""
        j = self.mesh
        if j < 0 or not self.on or self.u_rot == 0.0 or self.sense_dead:
            return 0.0
        half = self.backlash / 2.0
        g = self.gap[j]
        return MESH_LOAD if (self.u_rot > 0 and g >= half) or (self.u_rot < 0 and g <= -half) else 0.0

    def gear_count(self) -> int:
        return _floor(self.w / self.cfg.GEAR_MRAD_PER_COUNT + 1e-9)

    def hall_edges(self) -> list:
        out = self.ring
        self.ring = []
        return out

    def hall_level(self) -> int:
        return self.level

    # ---------------------------------------------------------- the plant
    def _rand(self) -> float:
        self._seed = (self._seed * 1103515245 + 12345) % 2147483648
        return self._seed / 2147483648.0 * 2.0 - 1.0

    def _near(self) -> float:
        best = 1e9
        for k in range(len(self.r)):
            if self.present[k]:
                x = abs(self.d - self.r[k])
                if x < best:
                    best = x
        return best

    def true_jd(self) -> int:
        j = 1
        for k in range(1, len(self.r)):
            if self.r[k] <= self.d:
                j = k + 1
        return j

    def step_plant(self, ms: int = 1) -> None:
        for _ in range(ms):
            self._step(0.001)
            self.t = (self.t + 1) % TICKS_PERIOD

    def _step(self, h: float) -> None:
        cfg = self.cfg
        # locomotion
        target = V_FULL * self.u_loco if self.on else 0.0
        dv = (target - self.v) * h / TAU
        lim = A_MAX * h
        dv = max(-lim, min(lim, dv))
        self.v += dv
        if self.wheel_stalled:
            self.v = 0.0
        ds = self.v * h
        slip = self.slip * self._rand()
        b = self.burst
        if b is not None and b[0] <= self.d <= b[1]:
            slip = b[2]
        nd = self.d + ds * (1.0 + slip)
        if nd < 0.0 or nd > self.length:
            end = 0.0 if nd < 0.0 else self.length
            ds = (end - self.d) / (1.0 + slip)
            nd = end
            self.v = 0.0
        self.d = nd
        self.s += ds
        # hall
        w = cfg.HALL_WINDOW_MM
        near = self._near()
        if self.level == 0 and near <= w * self.fire:
            self.level = 1
            self.ring.append(self.wheel_count())
            self.edges.append((self.d, self._nearest()))
        elif self.level == 1 and near > w + HYST:
            self.level = 0
        for x in list(self.extra):
            if abs(self.d - x) < 0.5:
                self.extra.remove(x)
                self.ring.append(self.wheel_count())
        # rotation
        target = W_FULL * self.u_rot if self.on else 0.0
        self.om += (target - self.om) * h / W_TAU
        dw = self.om * h
        j = -1
        for k in range(len(self.r)):
            if abs(self.d - self.r[k]) <= ENGAGE_MM:
                j = k
        if j != self.mesh and j >= 0:
            self.gap[j] = self.gap0
        self.mesh = j
        if j >= 0 and dw != 0.0:
            half = self.backlash / 2.0
            g = self.gap[j] + dw
            push = g - half if g > half else (g + half if g < -half else 0.0)
            if push != 0.0:
                if self.joint_stalled == j:
                    dw -= push
                    self.om = 0.0
                    g = half if push > 0 else -half
                else:
                    self.theta[j] += push
                    g = half if push > 0 else -half
            self.gap[j] = g
        self.w += dw

    def _nearest(self) -> int:
        best = 0
        for k in range(len(self.r)):
            if abs(self.d - self.r[k]) < abs(self.d - self.r[best]):
                best = k
        return best + 1


def new_board(cfg=None, **kw):
    """(board, hal, host) with a HELLO accepted (session 7, epoch 1)."""
    if cfg is None:
        cfg = load_config()
    hal = FakeMaHal(cfg, **kw)
    board = ma.Board(hal, cfg)
    host = Host(hal, board)
    ans = host.hello(1, 7)
    assert ans[1] == "OK", ans
    hal.take()
    return board, hal, host


def run_until(board, hal, pred, ms_max: int, each=None) -> int:
    """Runs 1 ms at a time until pred() -> the ms it took (fails past ms_max)."""
    for i in range(ms_max):
        hal.step_plant(1)
        board.poll()
        if each is not None:
            each()
        if pred():
            return i + 1
    raise AssertionError("not within %d ms: d=%.2f state=%s" % (ms_max, hal.d, board.state))


def done_ids(lines) -> list:
    out = []
    for ln in lines:
        if ln[1] == "EV" and ln[2][1] == "DONE":
            out.append(int(ln[2][2]))
    return out
