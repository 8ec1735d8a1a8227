"""The chip HALs the emulator's bridge stands in for, under the real
MicroPython interpreter: the MASR actuator's (firmware/masr_ma/hal_ma.py) and
the PCA9685 rig's (firmware/esp32/hal_pca9685.py).

The emulator's bridge hands the MA firmware its sensors at the HAL's level
(wheel and gear counts, the hall edges: emulator/mpbridge/bridgerigs.py), so
hal_ma.py itself, the layer over `machine`, does not run there. Here it does,
in the MicroPython WebAssembly interpreter, over a `machine` module written
for this test with the ESP32 port's names (Pin with irq, PWM, Encoder, UART,
RTC): the hall interrupt's ring of latched wheel counts (in order, the oldest
dropped on an overrun, and no allocation in the handler: a hard IRQ on the
chip may not allocate), the encoders, the motor drivers' duty and direction,
the gripper's pulse and outputs_off. And the PCA9685 rig's HAL, on an I2C bus
of that module that keeps what is written, sends the chip the same transfers as
the bridge's PcaBridgeHal (bridgerigs.py) for the same calls: the bridge wires
the firmware's driver and servo bank as the chip's HAL does. Without Node or
the package these skip, or fail under ARMBRIDGE_REQUIRE_HIL=1.
"""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

from require import missing

ROOT = Path(__file__).resolve().parents[1]

MACHINE = '''
# the ESP32 port's names, recording what the HAL asks of them
class Pin:
    IN = 1
    OUT = 3
    PULL_UP = 2
    IRQ_RISING = 1
    IRQ_FALLING = 2
    pins = {}

    def __init__(self, n, mode=-1, pull=-1, value=None):
        self.n = n
        self.v = 1 if value is None else value
        self.handler = None
        self.trigger = None
        self.hard = None
        Pin.pins[n] = self

    def value(self, v=None):
        if v is None:
            return self.v
        self.v = v

    def irq(self, handler=None, trigger=None, hard=False):
        self.handler = handler
        self.trigger = trigger
        self.hard = hard


class PWM:
    def __init__(self, pin, freq=0, duty_u16=None, duty_ns=None):
        self.pin = pin
        self.freq = freq
        self.u16 = duty_u16
        self.ns = duty_ns

    def duty_u16(self, v):
        self.u16 = v

    def duty_ns(self, v):
        self.ns = v


class Encoder:
    def __init__(self, unit, a, b, phases=1, filter_ns=0):
        self.unit = unit
        self.phases = phases
        self.count = 0

    def value(self):
        return self.count


class UART:
    def __init__(self, *a, **kw):
        pass


class ADC:
    ATTN_11DB = 3

    def __init__(self, pin, atten=0):
        self.pin = pin

    def read_uv(self):
        return 1650000


class I2C:
    """Every device keeps the bytes written to it (auto-increment) and reads them back."""
    log = []

    def __init__(self, bus, scl=None, sda=None, freq=0):
        self.regs = {}

    def _mem(self, addr):
        if addr not in self.regs:
            self.regs[addr] = bytearray(256)
        return self.regs[addr]

    def writeto_mem(self, addr, reg, buf, addrsize=8):
        I2C.log.append([addr, reg, bytes(buf).hex()])
        mem = self._mem(addr)
        for k in range(len(buf)):
            mem[(reg + k) & 0xFF] = buf[k]

    def readfrom_mem(self, addr, reg, n, addrsize=8):
        mem = self._mem(addr)
        return bytes([mem[(reg + k) & 0xFF] for k in range(n)])


class RTC:
    def memory(self, data=None):
        return b""


def unique_id():
    return b"\\x01\\x02"
'''

SCENARIO = '''
import sys, gc, json
with open("/io/machine.py", "w") as f:
    f.write(MACHINE)
sys.path[:0] = ["/io", "/fwma", "/fwc"]
import config as cfg
import machine
from hal_ma import MaHal

hal = MaHal(cfg)
out = {}
wheel = hal._wheel
hall = machine.Pin.pins[cfg.HALL_PIN]
out["irq"] = [hall.trigger == machine.Pin.IRQ_FALLING, hall.hard]
# three magnets: the IRQ latches the wheel count at each
for c in (120, 4000, 8001):
    wheel.count = c
    hall.handler(hall)
wheel.count = 9000
out["edges"] = hal.hall_edges()
out["again"] = hal.hall_edges()
out["counts"] = [hal.wheel_count(), hal.gear_count()]
# an overrun: 20 edges into a ring of HALL_RING
for c in range(20):
    wheel.count = c
    hall.handler(hall)
out["overrun"] = hal.hall_edges()
# the handler allocates nothing
gc.collect()
a0 = gc.mem_alloc()
for c in range(50):
    hall.handler(hall)
a1 = gc.mem_alloc()
out["irq_alloc"] = a1 - a0
hal.hall_edges()
hall.v = 0
out["level_on"] = hal.hall_level()
hall.v = 1
out["level_off"] = hal.hall_level()
loco = hal._loco
rot = hal._rot
hal.loco(0.5)
hal.rot(-1.5)
out["drive"] = [loco.u16, hal._loco_dir.v, rot.u16, hal._rot_dir.v]
hal.grip(True)
out["grip"] = [hal._grip.ns, hal._grip.freq]
hal.outputs_off()
out["off"] = [loco.u16, rot.u16, hal._grip.ns]
with open("/io/out.json", "w") as f:
    json.dump(out, f)
'''


PCA = '''
import sys, json
with open("/io/machine.py", "w") as f:
    f.write(MACHINE)
sys.path[:0] = ["/io", "/fw", "/fwc", "/bridge"]
import config as cfg
import machine
import bridgehal, bridgerigs
from hal_pca9685 import Pca9685Hal


def calls(hal):
    hal.write_positions([1.5, -1.5, 0.1])
    hal.write_positions([1.5, -1.5, 0.1])      # unchanged: no transfer
    hal.set_calibration(1, 600, -3927, 2400, 785)
    hal.write_positions([1.6, -1.4, 0.0])
    hal.write_pen(True)
    hal.outputs_off()
    hal.write_positions([1.6, -1.4, 0.0])


chip = Pca9685Hal(cfg)
calls(chip)
bridge = bridgerigs.PcaBridgeHal(cfg.N_JOINTS)
regs = bridgerigs.RegisterFile()
sent = []


def ask(line):
    # a read's question carries the log before it (the emulator replays it first)
    for f in line[1:].split("\\t")[:-1]:
        if f[0] == "I":
            a, r, d = f[1:].split(",")
            sent.append([int(a), int(r), d])
    return regs.ask(line)


bridge.asker = ask
bridge.start(cfg)
calls(bridge)
sent += [[v[0], v[1], bridgehal._hex(v[2])] for k, v in bridge.ops if k == bridgerigs.I2C_W]
with open("/io/out.json", "w") as f:
    json.dump({"chip": machine.I2C.log, "bridge": sent, "pen": [chip.has_pen, bridge.has_pen],
               "waits": [v for k, v in bridge.ops if k == bridgerigs.SLEEP]}, f)
'''


def run_script(scenario: str) -> dict:
    pkg = ROOT / "node_modules" / "@micropython" / "micropython-webassembly-pyscript" / "micropython.mjs"
    node = shutil.which("node")
    if node is None or not pkg.is_file():
        missing("node and the npm package @micropython/micropython-webassembly-pyscript (make setup)")
    script = "MACHINE = " + repr(MACHINE) + "\n" + scenario
    proc = subprocess.run([node, str(ROOT / "tests" / "mpy" / "run_script.mjs"), str(ROOT)], input=script,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout)


def test_the_pca9685_rigs_chip_hal_and_the_bridges_send_the_same_transfers():
    got = run_script(PCA)
    assert got["pen"] == [True, True] and got["waits"] == [500]   # the oscillator's wake-up, as a busy-wait
    assert len(got["chip"]) > 10
    assert got["bridge"] == got["chip"]


def test_the_mas_chip_hal_under_micropython():
    got = run_script(SCENARIO)
    assert got["irq"] == [True, True]                     # active low: the falling edge, a hard IRQ
    assert got["edges"] == [120, 4000, 8001] and got["again"] == []
    assert got["counts"] == [9000, 0]
    assert got["overrun"] == list(range(4, 20))           # HALL_RING = 16: the 4 oldest dropped
    assert got["irq_alloc"] == 0
    assert (got["level_on"], got["level_off"]) == (1, 0)
    assert got["drive"] == [32767, 0, 65535, 1]           # |u| as duty, direction low for +; clipped at 1
    assert got["grip"] == [2000 * 1000, 50]               # GRIP_OPEN_US, SERVO_FREQ_HZ
    assert got["off"] == [0, 0, 2000 * 1000]              # the motors stop, the gripper holds
