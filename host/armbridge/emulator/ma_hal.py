"""The emulated MASR actuator's HAL: the MA HAL of the issue-11 contract over `MaPlant`.

Clock, UART, persisted memory and files are SimHal's (this class subclasses
it and takes its keywords, `files=` included). What the MA adds, each call
bringing the plant up to the sim clock first:

    loco(u)         locomotion effort in [-1, 1], + away from the base
    wheel_count()   signed wheel-encoder count
    hall_edges()    wheel counts latched at each hall rising edge since the last call
    hall_level()    1 while a magnet is under the sensor
    rot(u)          joint-rotation effort, + increases the engaged joint's angle
    gear_count()    signed gear-encoder count of the rotation drive
    grip(open)      the gripper servo
    outputs_off()   both motors off (the worms hold the joints), the gripper holds

Records for the tests (besides SimHal's outputs_off_at, outputs_on_at,
estop_byte_at): `track` ((t, true q, board q) at every telemetry line the
firmware writes: the plant's (theta_1..theta_{n-1}, d) in rad and m beside the
board's estimates from the T line's first n columns, same units), `telemetry`
((t, every T column as int) of those lines), `loco_log`, `rot_log` ((t, u) of
every write that changed the effort), `grip_log` ((t, open)), and the plant's
`hall_log` ((t, joint, latched count, true d) of every rising edge) and
`faults_applied` ((t, kind, detail): missed magnets, slip bursts on and off,
stalls taking effect).
"""
from __future__ import annotations

from collections import deque
from typing import Any, Callable, cast

import numpy as np

from armbridge.emulator.ma_plant import MaPlant
from armbridge.emulator.simhal import SimHal
from armbridge.errors import ArmbridgeError


class MaSimHal(SimHal):
    """The MA's HAL in the emulator; see the module docstring."""

    has_pen = False

    def __init__(self, clock, plant: MaPlant, uart, persist=None, *,
                 on_line: Callable[[float, bytes], None] | None = None, **kw: Any) -> None:
        super().__init__(clock, cast(Any, plant), uart, persist, on_line=self._watch, **kw)
        self.ma = plant
        self._forward = on_line
        max_log = int(kw.get("max_log", 200_000))
        self.track: deque[tuple[float, tuple[float, ...], tuple[float, ...]]] = deque(maxlen=max_log)
        self.telemetry: deque[tuple[float, tuple[int, ...]]] = deque(maxlen=max_log)
        self.loco_log: deque[tuple[float, float]] = deque(maxlen=max_log)
        self.rot_log: deque[tuple[float, float]] = deque(maxlen=max_log)
        self.grip_log: list[tuple[float, bool]] = []

    # records ---------------------------------------------------------------
    def _watch(self, t: float, line: bytes) -> None:
        """Every line the firmware writes: a T line's estimates go beside the truth."""
        parts = line.split(b"*", 1)[0].split()
        if len(parts) > 6 + self.ma.n and parts[1] == b"T":
            try:
                cols = tuple(int(x) for x in parts[6:])
            except ValueError:
                cols = ()
            if cols:
                self._sync()
                self.telemetry.append((t, cols))
                est = np.asarray(cols[:self.ma.n], float) / 1000.0
                self.track.append((t, tuple(float(x) for x in self.ma.q), tuple(float(x) for x in est)))
        if self._forward is not None:
            self._forward(t, line)

    @property
    def hall_log(self) -> list[tuple[float, int, int, float]]:
        return self.ma.edges

    @property
    def faults_applied(self) -> list[tuple[float, str, Any]]:
        return self.ma.faults_applied

    def _on(self) -> None:
        if not self.outputs_enabled:
            self.outputs_on_at.append(self.clock.t)
        self.outputs_enabled = True

    # outputs -----------------------------------------------------------------
    def loco(self, u) -> None:
        self._sync()
        u = float(u)
        if not -1.0 <= u <= 1.0:
            self.saturation_violations += 1
        if not self.loco_log or self.loco_log[-1][1] != u:
            self.loco_log.append((self.clock.t, u))
        self.ma.set_loco(u)
        self._on()

    def rot(self, u) -> None:
        self._sync()
        u = float(u)
        if not -1.0 <= u <= 1.0:
            self.saturation_violations += 1
        if not self.rot_log or self.rot_log[-1][1] != u:
            self.rot_log.append((self.clock.t, u))
        self.ma.set_rot(u)
        self._on()

    def grip(self, open_) -> None:
        self._sync()
        self.grip_log.append((self.clock.t, bool(open_)))
        self.ma.set_grip(bool(open_))

    def outputs_off(self) -> None:
        self._sync()
        self.ma.off()
        if self.outputs_enabled:
            self.outputs_off_at.append(self.clock.t)
            self.loco_log.append((self.clock.t, 0.0))
            self.rot_log.append((self.clock.t, 0.0))
        self.outputs_enabled = False

    # sensors -----------------------------------------------------------------
    def wheel_count(self) -> int:
        self._sync()
        return self.ma.wheel_count()

    def gear_count(self) -> int:
        self._sync()
        return self.ma.gear_count()

    def hall_edges(self) -> list:
        self._sync()
        return self.ma.pop_edges()

    def rot_load(self) -> float:
        self._sync()
        return self.ma.rot_load()

    def hall_level(self) -> int:
        self._sync()
        return 1 if self.ma.level else 0

    # the arm's HAL calls: not on this board ---------------------------------
    def read_positions(self, out) -> None:
        raise ArmbridgeError("the MASR actuator's HAL has no read_positions: read wheel_count, gear_count, "
                             "hall_edges and hall_level")

    def write_outputs(self, efforts) -> None:
        raise ArmbridgeError("the MASR actuator's HAL has no write_outputs: drive loco(u) and rot(u)")
