"""A tiny stand-in MASR actuator firmware for the emulator's own tests: the
board's real link (firmware/common), one verb (MV), a P loop on the wheel
encoder, re-zeroed at every hall edge. It exercises the emulated MA's HAL
(ma_hal.MaSimHal) end to end without depending on firmware/masr_ma."""
from __future__ import annotations

import shutil

from armbridge.resources import firmware_dir

CONFIG = '''
FW_NAME = "masr_ma"
FW_VERSION = "0.0.1-standin"
N_JOINTS = 6
LINK_LENGTHS_MM = (200, 200, 200, 100, 100)
LIMITS = ((-873, 873),) * 5 + ((0, 800),)
VMAX = (280,) * 5 + (100,)
PERIOD_MS = 10
QSIZE = 1
TELEMETRY_HZ = 25
UART_BAUD = 115200
WDOG_MS = 1000
WHEEL_MM_PER_COUNT = 0.05
GEAR_MRAD_PER_COUNT = 0.1
HALL_WINDOW_MM = 1.5
BACKLASH_MRAD = 3.0
SLIP_MAX = 0.01
'''

BOARD = '''
import link as L
import proto
import protodef as P

R_MM = (0, 200, 400, 600, 700)


class Board:
    def __init__(self, hal, cfg):
        self.hal = hal
        self.cfg = cfg
        self.n = cfg.N_JOINTS
        self.qsize = 1
        self.lim = [list(x) + [v] for x, v in zip(cfg.LIMITS, cfg.VMAX)]
        self.verbs = {"MV": self._mv}
        self.motion_verbs = ["MV"]
        self.c0 = hal.wheel_count()
        self.d0 = 0.0
        self.dir = 1
        self.target = None
        self.id = -1
        self.u = 0.0
        self.on_done = None
        self.link = L.BoardLink(hal, cfg, self)

    def poll(self):
        return self.link.poll()

    @property
    def state(self):
        return self.link.state

    def d(self):
        return self.d0 + (self.hal.wheel_count() - self.c0) * self.cfg.WHEEL_MM_PER_COUNT

    def _mv(self, v):
        if self.target is not None:
            raise proto.ProtocolError(P.FULL)
        self.id, self.target = v[0], v[1]
        self.link.queued = v[0]
        return []

    def free(self):
        return 0 if self.target is not None else 1

    def busy(self):
        return self.target is not None

    def halt(self):
        self.target = None
        self.u = 0.0

    def hold_here(self):
        self.halt()

    def set_hold(self, on):
        pass

    def control(self, mode):
        for c in self.hal.hall_edges():
            at = self.d0 + (c - self.c0) * self.cfg.WHEEL_MM_PER_COUNT
            j = min(range(len(R_MM)), key=lambda k: abs(R_MM[k] - at))
            self.d0 = R_MM[j] - self.dir * self.cfg.HALL_WINDOW_MM
            self.c0 = c
            self.link.event("MAGNET", [j + 1])
        if mode != L.DRIVE:
            self.u = 0.0
            if mode == L.ZERO:
                self.hal.loco(0.0)
            return
        if self.target is not None:
            e = self.target - self.d()
            if abs(e) < 0.3:
                self.u = 0.0
                wid = self.id
                self.target = None
                if self.on_done is not None:
                    self.on_done(wid, [])
                self.link.completed(wid)
            else:
                self.u = max(-0.8, min(0.8, 0.05 * e + (0.1 if e > 0 else -0.1)))
                self.dir = 1 if e > 0 else -1
        self.hal.loco(self.u)

    def telemetry(self):
        d = int(round(self.d()))
        sp = d if self.target is None else self.target
        jd = 1
        for k in range(len(R_MM)):
            if d >= R_MM[k]:
                jd = k + 1
        return [0] * 5 + [d] + [0] * 5 + [sp] + [0] * 5 + [int(self.u * 1000), jd, d - R_MM[jd - 1], 0]
'''


def standin_firmware(root) -> None:
    """A masr_ma firmware folder under `root` (with firmware/common beside it)."""
    (root / "masr_ma").mkdir()
    shutil.copytree(firmware_dir() / "common", root / "common")
    (root / "masr_ma" / "config.py").write_text(CONFIG)
    (root / "masr_ma" / "ma.py").write_text(BOARD)
