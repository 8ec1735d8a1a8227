"""The emulated PCA9685 rig: the firmware's own servo code over a simulated I2C bus.

`PcaSimHal` is the SimHal of the positional rig (config SERVOS = "pca9685",
firmware/esp32/hal_pca9685.py on the chip). It loads the firmware's
pca9685.py and servos.py from the folder of the board's config (with
runner.load_firmware: fresh module objects, nothing shared with the board's)
and runs them against `i2c.SimI2C` with a `pca9685.Pca9685Model` at
PCA9685_ADDR, so the bytes the chip would get are the ones the firmware writes.
The plant (`servo_plant.PositionalPlant`, built by `rig_plant`) sees the
PCA9685's channel pulse widths: the bus brings it up to the time of every
transfer first, and after every write hands it the new widths from the start
of the next PWM period. Its busy-waits (the oscillator's 500 us after wake)
advance the sim clock.

Records, besides SimHal's (outputs_off_at / outputs_on_at, estop_byte_at, and
pen_log: (t, down) of every write_pen): `positions` ((t, q) of every
write_positions), `calibrations` ((t, j0, us_a, mrad_a, us_b, mrad_b)) and
`pen_changes` ((t, down) when the pen servo's angle reached or left that of
its contact width, the plant's `pen_contact_us`: where the tip meets the paper);
`pen_down_at(t)` answers from those, the servo's own travel, whatever widths
the firmware sends (PENPOS: `pen_widths_log`, (t, up_us, down_us)).
"""
from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import Any, cast

import numpy as np

from armbridge.boards import joint_limits_rad
from armbridge.emulator.i2c import SimI2C
from armbridge.emulator.pca9685 import Pca9685Model
from armbridge.emulator.servo_plant import PenServo, PositionalPlant, ServoParams
from armbridge.emulator.simhal import PEN_CONTACT_US, SimHal
from armbridge.errors import ArmbridgeError


def _firmware_dir(cfg: Any) -> Path:
    f = getattr(cfg, "__file__", None)
    if f:
        return Path(f).parent
    from armbridge.resources import firmware_dir
    return firmware_dir() / "esp32"


def rig_plant(cfg: Any, params: ServoParams | None, q0, seed: int) -> PositionalPlant:
    """The rig's plant from the firmware config: one DS3235-class servo per joint,
    mounted as SERVO_CAL says (the config's calibration is exact), and the pen
    servo when PEN_CHANNEL is set. Keeps `cfg` as the rig's wiring."""
    if params is not None and not isinstance(params, ServoParams):
        raise ArmbridgeError(f"the pca9685 rig's plant takes ServoParams, not {type(params).__name__}")
    lo, hi = joint_limits_rad(cfg)
    mapping = [(c[0], c[1] / 1000.0, c[2], c[3] / 1000.0) for c in cfg.SERVO_CAL]
    pen = None
    if getattr(cfg, "PEN_CHANNEL", None) is not None:
        contact = params.pen_contact_us if params is not None else PEN_CONTACT_US  # a drawn rig's own
        pen = PenServo(up_us=float(cfg.PEN_UP_US), down_us=float(cfg.PEN_DOWN_US), contact_us=contact)
    plant = PositionalPlant(lo, hi, mapping, params, q0=q0, seed=seed, pen=pen)
    plant.cfg = cfg
    return plant


class PcaSimHal(SimHal):
    """The positional rig's HAL (see the module docstring). cfg: the firmware
    config (default: the one the plant was built from); the other keywords are
    SimHal's."""

    POSITIONAL = True

    def __init__(self, clock, plant: PositionalPlant, uart, persist=None, *, cfg: Any = None, **kw: Any) -> None:
        super().__init__(clock, cast(Any, plant), uart, persist, **kw)
        self.rig = plant
        cfg = cfg if cfg is not None else plant.cfg
        if cfg is None:
            raise ArmbridgeError("PcaSimHal needs the firmware config (cfg=, or a plant from rig_plant)")
        from armbridge.emulator.runner import load_firmware

        fw = load_firmware([_firmware_dir(cfg)], ("pca9685", "servos"))
        self.firmware = fw
        self.pca = Pca9685Model(now=lambda: self.clock.t)
        self.bus = SimI2C(cfg.I2C_FREQ, before=self._sync, after=self._pulses_changed)
        self.bus.attach(cfg.PCA9685_ADDR, self.pca)
        chans = [int(c) for c in cfg.SERVO_CHANNELS]
        if plant.pen is not None:
            chans.append(int(cfg.PEN_CHANNEL))
        self._channels = chans
        max_log = int(kw.get("max_log", 200_000))
        self.positions: deque[tuple[float, tuple[float, ...]]] = deque(maxlen=max_log)
        self.calibrations: list[tuple[float, int, int, int, int, int]] = []
        self.pen_widths_log: list[tuple[float, int, int]] = []
        self.driver = fw["pca9685"].Pca9685(self.bus, cfg.PCA9685_ADDR, cfg.SERVO_FREQ_HZ,
                                            sleep_us=self._busy_wait)
        self.servos = fw["servos"].ServoBank(self.driver, cfg)
        self.has_pen = bool(self.servos.has_pen)

    # the bus -------------------------------------------------------------
    def _busy_wait(self, us: int) -> None:
        self.clock.advance_us(int(us))

    def _pulses_changed(self) -> None:
        t = self.clock.t
        self.rig.set_pulses(self.pca.pulses_us(self._channels), self.pca.next_frame(t))

    @property
    def pen_changes(self) -> list[tuple[float, bool]]:
        return self.rig.pen_changes

    def pen_down_at(self, t: float) -> bool:
        """Whether the pen touched the paper at time t (s): the pen servo's position."""
        self._sync()
        return bool(self.pen_touching([t])[0])

    def pen_touching(self, ts) -> np.ndarray:
        """pen_down_at for many times (s), as far as the plant has run (no sync: callable
        from another thread)."""
        changes = list(self.rig.pen_changes)
        at = np.array([c[0] for c in changes], float)
        down = np.array([c[1] for c in changes], bool)
        i = np.searchsorted(at, np.asarray(ts, float), side="right") - 1
        return np.where(i >= 0, down[np.maximum(i, 0)] if len(down) else False, False)

    # the HAL -------------------------------------------------------------
    def write_positions(self, q) -> None:
        self.servos.write(q)
        self.bridged_positions(q)

    def write_outputs(self, efforts) -> None:
        raise ArmbridgeError("the pca9685 rig has positional servos: the board must call "
                             "write_positions (hal.POSITIONAL), not write_outputs")

    def outputs_off(self) -> None:
        self.servos.off()
        self.bridged_off()

    def set_calibration(self, j0: int, us_a: int, mrad_a: int, us_b: int, mrad_b: int) -> None:
        self.servos.set_calibration(j0, us_a, mrad_a, us_b, mrad_b)
        self.bridged_calibration(j0, us_a, mrad_a, us_b, mrad_b)

    def set_lead(self, j0: int, mrad: int) -> None:
        self.servos.set_lead(j0, mrad)

    def write_pen(self, down: bool) -> None:
        self.servos.pen(down)
        self.bridged_pen(down)

    def set_pen_widths(self, up_us: int, down_us: int) -> None:
        self.servos.set_pen_widths(up_us, down_us)
        self.bridged_pen_widths(up_us, down_us)

    # the firmware's own driver under MicroPython (emulator/micropython.py) ------------
    # There the firmware's pca9685.py and servos.py run in the interpreter: their I2C
    # transfers and busy-waits come here in order, the HAL-level calls only as records.
    def bridged_write(self, addr: int, reg: int, data: bytes) -> None:
        self.bus.writeto_mem(addr, reg, data)

    def bridged_read(self, addr: int, reg: int, n: int) -> bytes:
        return self.bus.readfrom_mem(addr, reg, n)

    def bridged_sleep_us(self, us: int) -> None:
        self._busy_wait(us)

    def bridged_positions(self, q) -> None:
        t = self.clock.t
        if not self.outputs_enabled:
            self.outputs_on_at.append(t)
        self.outputs_enabled = True
        self.positions.append((t, tuple(float(x) for x in q)))

    def bridged_off(self) -> None:
        if self.outputs_enabled:
            self.outputs_off_at.append(self.clock.t)
        self.outputs_enabled = False

    def bridged_calibration(self, j0: int, us_a: int, mrad_a: int, us_b: int, mrad_b: int) -> None:
        self.calibrations.append((self.clock.t, int(j0), int(us_a), int(mrad_a), int(us_b), int(mrad_b)))

    def bridged_pen(self, down: bool) -> None:
        SimHal.write_pen(self, down)

    def bridged_pen_widths(self, up_us: int, down_us: int) -> None:
        self.pen_widths_log.append((self.clock.t, int(up_us), int(down_us)))
