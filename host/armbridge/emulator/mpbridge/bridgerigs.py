"""The bridge HALs of the rigs besides the arm's effort rig (MicroPython; also
imports under CPython for fwcost.py). Importing it adds them to bridgehal.RIGS
(and their answer fields to bridgehal.FIELDS), where make_hal picks one by the
rig name the emulator announces (`H` request, caps "rig").

"ma", the MASR actuator (firmware/masr_ma, the MA HAL of docs/architecture.md):
the sensors arrive with every request (`S ms us RX wheel gear level edges
load`, edges the wheel counts the emulator's hall sensor latched since the last
request, comma-separated, "-" for none, load the rotation driver's current
sense) and are what wheel_count, gear_count, hall_level, hall_edges and
rot_load answer during that pass, as the chip's pulse
counters and hall interrupt ring (hal_ma.py) would at that instant: the
emulator's clock stands still during a pass. Edges the firmware has not taken
yet stay queued here, in order. loco, rot and grip go into the log (`L<u>`,
`R<u>`, `G1`/`G0`) and are replayed on the emulator's MaSimHal.

"pca", the paper's servo rig (firmware/esp32 with SERVOS = "pca9685"): the
firmware's own PCA9685 driver and servo bank (pca9685.py, servos.py) run here,
wired as hal_pca9685.Pca9685Hal wires them, over `BridgeI2C`: every register
write goes into the log in order (`I<addr>,<reg>,<hex>`), the driver's
busy-waits too (`Z<us>`, which also move this HAL's clock), and a register
read is asked of the emulator's bus at once (`BridgeHal.ask`: the log so far
is replayed there first, so the simulated chip answers in the state those
writes left it in). The HAL-level calls go into the log as well, for the
emulator's records: `Q<q1>,..` write_positions, `X` outputs off, `C<j0>,..`
a calibration, `N1`/`N0` the pen, `Y<up>,<down>` its widths (their I2C transfers are the `I` fields).
"""

try:
    import bridgehal  # type: ignore[import-not-found]
except ImportError:  # CPython (fwcost.py's comparison run): the package's module
    from armbridge.emulator.mpbridge import bridgehal

LOCO = 10
ROT = 11
GRIP = 12
I2C_W = 13
SLEEP = 14
POS = 15
CAL = 16


class MaBridgeHal(bridgehal.BridgeHal):
    """The MA's HAL over the bridge (see the module docstring)."""

    def __init__(self, n, persist=b"", has_pen=False, uid="0"):
        bridgehal.BridgeHal.__init__(self, n, persist, False, uid)
        self.wheel = 0
        self.gear = 0
        self.level = 0
        self.edges = []
        self.load = 0.0

    def sense(self, fields):
        self.wheel = int(fields[0])
        self.gear = int(fields[1])
        self.level = int(fields[2])
        if len(fields) > 3 and fields[3] != "-":
            for x in fields[3].split(","):
                self.edges.append(int(x))
        if len(fields) > 4:
            self.load = float(fields[4])

    def wheel_count(self):
        return self.wheel

    def gear_count(self):
        return self.gear

    def hall_level(self):
        return self.level

    def hall_edges(self):
        out = self.edges
        self.edges = []
        return out

    def rot_load(self):
        return self.load

    def loco(self, u):
        self.ops.append((LOCO, float(u)))

    def rot(self, u):
        self.ops.append((ROT, float(u)))

    def grip(self, open_):
        self.ops.append((GRIP, bool(open_)))


class BridgeI2C:
    """machine.I2C's memory API over the bridge: writes logged, reads asked."""

    def __init__(self, hal):
        self.hal = hal

    def writeto_mem(self, addr, memaddr, buf, addrsize=8):
        self.hal.ops.append((I2C_W, (addr, memaddr, bytes(buf))))

    def readfrom_mem(self, addr, memaddr, nbytes, addrsize=8):
        return self.hal.ask("r%d,%d,%d" % (addr, memaddr, nbytes))

    def readfrom_mem_into(self, addr, memaddr, buf, addrsize=8):
        buf[:] = self.readfrom_mem(addr, memaddr, len(buf), addrsize)


class PcaBridgeHal(bridgehal.BridgeHal):
    """The PCA9685 rig's HAL over the bridge (see the module docstring)."""

    POSITIONAL = True
    firmware = None   # {"pca9685": module, "servos": module} where they are not importable (CPython's bench)

    def __init__(self, n, persist=b"", has_pen=False, uid="0"):
        bridgehal.BridgeHal.__init__(self, n, persist, False, uid)
        self.i2c = BridgeI2C(self)
        self.servos = None

    def start(self, cfg):
        """The firmware's driver and servo bank on the bridged bus, as the chip's HAL builds them."""
        if self.firmware is not None:
            Pca9685 = self.firmware["pca9685"].Pca9685
            ServoBank = self.firmware["servos"].ServoBank
        else:
            from pca9685 import Pca9685  # type: ignore[import-not-found]
            from servos import ServoBank  # type: ignore[import-not-found]

        pca = Pca9685(self.i2c, cfg.PCA9685_ADDR, cfg.SERVO_FREQ_HZ, sleep_us=self.sleep_us)
        self.servos = ServoBank(pca, cfg)
        self.has_pen = self.servos.has_pen

    def sleep_us(self, us):
        """A busy-wait: the clock moves on here, and the emulator's with the replay."""
        us = int(us)
        self.ops.append((SLEEP, us))
        self.ms = bridgehal._ticks_add(self.ms, (self.us % 1000 + us) // 1000)
        self.us = bridgehal._ticks_add(self.us, us)

    def write_positions(self, q):
        self.servos.write(q)
        self.ops.append((POS, tuple(q)))

    def write_outputs(self, efforts):
        raise RuntimeError("the pca9685 rig has positional servos: write_positions, not write_outputs")

    def outputs_off(self):
        self.servos.off()
        self.ops.append((bridgehal.OFF, None))

    def set_calibration(self, j0, us_a, mrad_a, us_b, mrad_b):
        self.servos.set_calibration(j0, us_a, mrad_a, us_b, mrad_b)
        self.ops.append((CAL, (j0, us_a, mrad_a, us_b, mrad_b)))

    def set_lead(self, j0, mrad):
        self.servos.set_lead(j0, mrad)

    def write_pen(self, down):
        self.servos.pen(down)
        self.ops.append((bridgehal.PEN, bool(down)))

    def set_pen_widths(self, up_us, down_us):
        self.servos.set_pen_widths(up_us, down_us)
        self.ops.append((bridgehal.PENW, (int(up_us), int(down_us))))


class RegisterFile:
    """For fwcost.py's bench, which has no emulator to ask: a bus on which every
    device keeps the bytes written to it (auto-incrementing, as the PCA9685 with
    MODE1.AI) and reads them back. `ask` is a BridgeHal.asker."""

    def __init__(self):
        self.regs = {}

    def ask(self, line):
        fields = line[1:].split("\t")
        for f in fields[:-1]:
            if f[:1] == "I":
                addr, reg, data = f[1:].split(",")
                mem = self._mem(int(addr))
                reg = int(reg)
                for b in bridgehal.binascii.unhexlify(data):
                    mem[reg & 0xFF] = b
                    reg += 1
        q = fields[-1]
        if q[:1] != "r":
            raise ValueError("the bench's bus cannot answer %r" % q)
        addr, reg, n = [int(x) for x in q[1:].split(",")]
        mem = self._mem(addr)
        return bridgehal._hex(bytes([mem[(reg + k) & 0xFF] for k in range(n)]))

    def _mem(self, addr):
        if addr not in self.regs:
            self.regs[addr] = bytearray(256)
        return self.regs[addr]


bridgehal.RIGS["ma"] = MaBridgeHal
bridgehal.RIGS["pca"] = PcaBridgeHal
bridgehal.FIELDS.update({
    LOCO: lambda v: "L" + repr(v),
    ROT: lambda v: "R" + repr(v),
    GRIP: lambda v: "G1" if v else "G0",
    I2C_W: lambda v: "I%d,%d,%s" % (v[0], v[1], bridgehal._hex(v[2])),
    SLEEP: lambda v: "Z%d" % v,
    POS: lambda v: "Q" + ",".join([repr(float(x)) for x in v]),
    CAL: lambda v: "C" + ",".join([str(int(x)) for x in v]),
})
