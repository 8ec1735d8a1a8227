"""The armbridge line protocol, version 2, declared once (spec: docs/protocol.md).

Why this file exists: two hand-written command tables (host and firmware) drifted
apart in names and in one rule, and a third board (the AVR pump, in C) is on its
way. So the protocol's facts live here, as pure data, and nowhere else: Klipper
declares each command once and the host learns the dictionary from it; MAVLink
generates every language's codec from one message definition. The host codec
(link/protocol.py) reads this module directly; `python -m armbridge.link.codegen`
renders it as `firmware/common/protodef.py` (MicroPython, const()) and
`firmware/arduino_pump/protodef.h` (C), and a test checks that the committed
renderings are current. Change the protocol here, regenerate, and every codec
follows; the shared vectors (tests/vectors/) then say whether they still agree.

Only ints, strings and tuples/dicts of them: the generator writes them out as
literals, so nothing here may be computed from code.
"""

PROTOCOL_VERSION = 2

# Lengths in bytes, LF included.
MAX_HOST_LINE = 96  # host -> board: fits the smallest board's line buffer
MAX_BOARD_LINE = 192  # board -> host

ESTOP_BYTE = 0x98  # out of band: latches ESTOP the moment it arrives
CRC_DIGITS = 8  # CRC-32/ISO-HDLC as 8 upper-case hex digits
HELLO_EPOCH = 0  # the CRC seed of every HELLO and of every board -> host line

SEQ_MOD = 65536  # sequence numbers are 0..65535
RING = 32  # replay window: answers kept for the last RING executed seqs
MAX_EPOCH_COMMANDS = 32768  # a host opens a new epoch before issuing this many in one
EPOCH_MAX = 1073741823  # 2**30 - 1: the largest MicroPython small int
SESSION_MAX = 65535
TICKS_PERIOD = 1073741824  # 2**30: board time MS wraps (MicroPython ticks_ms period)
JOINT_ABS_MAX = 1000000  # every joint value, in milli-units, is within +-JOINT_ABS_MAX

# Error codes (docs/protocol.md section 5). Codes 1..3 are framing errors,
# answered with "-" as seq.
PARSE = 1
CRC = 2
LONG = 3
VERB = 4
ARGS = 5
RANGE = 6
SEQ = 7
FULL = 8
LATCHED = 9
NOSESSION = 10
STALE = 11
PROTO = 12
REACH = 13  # a Cartesian target outside the board's safe region, or one its IK did not reach
UNHOMED = 14  # the MASR actuator does not know where it is (a reset mid-move, a localisation fault): HOME

ERROR_NAMES = {
    1: "PARSE", 2: "CRC", 3: "LONG", 4: "VERB", 5: "ARGS", 6: "RANGE",
    7: "SEQ", 8: "FULL", 9: "LATCHED", 10: "NOSESSION", 11: "STALE", 12: "PROTO",
    13: "REACH", 14: "UNHOMED",
}

# Host -> board commands: verb -> argument specs (name, lo, hi), in order.
# Two names are kinds, not plain integers:
#   "joint" is a joint index 1..n of the board (lo 1, hi written 0: "n");
#   "q" stands for n joint values, each within [lo, hi]; it is always last.
# Every other argument is a decimal integer within [lo, hi].
COMMANDS = {
    "HELLO": (("proto", 1, 65535), ("session", 1, 65535), ("epoch", 1, 1073741823)),
    "LIM": (("joint", 1, 0),),
    "W": (("id", 0, 65535), ("dur", 1, 60000), ("q", -1000000, 1000000)),
    "HOLD": (),
    "RESUME": (),
    "CLR": (),
    "RATE": (("hz", 0, 100),),
    "GAIN": (("joint", 1, 0), ("kp", 0, 1000000), ("ki", 0, 1000000), ("kd", 0, 1000000)),
    "SETLIM": (("joint", 1, 0), ("min", -1000000, 1000000), ("max", -1000000, 1000000),
               ("vmax", 1, 1000000)),
    "WDOG": (("ms", 50, 10000),),
    "STAT": (),
    "PING": (),
    # The 3R drawing arm's capabilities; a board without one answers VERB.
    # X: a Cartesian waypoint, x y in micrometres, theta (q1+q2+q3, unwrapped) in
    # mrad, solved by the board's own IK. XY: the same at the board's pen angle.
    "X": (("id", 0, 65535), ("dur", 1, 60000), ("x", -1000000, 1000000), ("y", -1000000, 1000000),
          ("theta", -10000, 10000)),
    "XY": (("id", 0, 65535), ("dur", 1, 60000), ("x", -1000000, 1000000), ("y", -1000000, 1000000)),
    # PEN: modal pen-lift state (0 up, 1 down) of the waypoints queued after it.
    "PEN": (("down", 0, 1),),
    # PENPOS: the pen-lift servo's pulse widths for up and down (us) and the dwell after a
    # pen change (ms, the pen's settle); a pen at rest moves to its state's new width. Refused
    # RANGE while waypoints are queued; saved by CALID.
    "PENPOS": (("up_us", 500, 2500), ("down_us", 500, 2500), ("settle_ms", 0, 2000)),
    # CAL: a positional servo's calibration, pulse us_a (us) at angle a, us_b at b (mrad).
    "CAL": (("joint", 1, 0), ("us_a", 500, 2500), ("a", -1000000, 1000000), ("us_b", 500, 2500),
            ("b", -1000000, 1000000)),
    # The MASR mobile actuator's actions, queued like waypoints (credits, DONE id).
    # Its coordinates are joints 1..n-1 (mrad) and d (the last, in mm) along the arm.
    # MV: drive the MA to d. ROT: turn joint j to angle (the MA drives onto joint j's
    # magnet first). GRIP: the gripper (0 closed, 1 open). HOME: drive to the base, zero d.
    # END: drive onto the far end stop (d = l) as HOME onto the base, report EV ENDSTOP n
    # count (the wheel's count from home there; calibration's second reference), d unchanged.
    "MV": (("id", 0, 65535), ("d", 0, 1000000)),
    "ROT": (("id", 0, 65535), ("joint", 1, 0), ("angle", -1000000, 1000000)),
    "GRIP": (("id", 0, 65535), ("open", 0, 1)),
    "HOME": (("id", 0, 65535),),
    "END": (("id", 0, 65535),),
    # The syringe-pump board (the soft arm, firmware/arduino_pump). DBAND: joint j's
    # dead band (mrad) of its proportional controller. BEND: joint j's bend-sensor
    # calibration, ADC count adc_a at angle a, adc_b at b (mrad), kept in EEPROM.
    # MODBUS: after the OK, the UART speaks Modbus RTU as device addr (kept in EEPROM).
    "DBAND": (("joint", 1, 0), ("mrad", 0, 1000)),
    "BEND": (("joint", 1, 0), ("adc_a", 0, 1023), ("a", -1000000, 1000000), ("adc_b", 0, 1023),
             ("b", -1000000, 1000000)),
    "MODBUS": (("addr", 1, 247),),
    # Calibration (docs/calibration.md), every board. IDENT: the board's unique id and
    # the id of the calibration it holds (0: none). CALID: persist every setting the
    # calibration covers (gains, servo, bend, dead band, magnets, wheel) under `id`;
    # a boot loads it back. RELAY: relay auto-tune (Astrom-Hagglund) of joint j's loop:
    # effort +-amp (per mille) about the set point, switching at +-hyst (mrad); after
    # `cycles` whole cycles the board reports `EV RELAY j period_ms amp_mrad` and holds.
    "IDENT": (),
    "CALID": (("id", 1, 1073741823),),
    "RELAY": (("joint", 1, 0), ("amp", 1, 1000), ("hyst", 0, 1000), ("cycles", 1, 50)),
    # The MASR actuator's localisation. MAG: joint j's magnet centre (um from home, in
    # the wheel's frame) and its hall window's half width (um). WHEEL: travel per
    # wheel encoder count (nm).
    "MAG": (("joint", 1, 0), ("pos", 0, 1000000), ("win", 0, 10000)),
    "WHEEL": (("nm", 1, 1000000),),
}

# Verbs that change nothing: a retransmitted copy is answered afresh, not replayed.
READ_ONLY = ("STAT", "LIM", "PING", "IDENT")

# Cross-argument rules, checked after every argument's own range: verb ->
# ((a, b), ...) meaning value a <= value b, else RANGE. (min == max is allowed:
# a locked joint.)
ORDERED = {
    "SETLIM": (("min", "max"),),
    "CAL": (("us_a", "us_b"),),
    "BEND": (("adc_a", "adc_b"),),
}

# OK payloads of the commands that have one (names, in order).
REPLIES = {
    "HELLO": ("fw", "fwver", "proto", "n", "qsize", "rate", "wdog_ms", "done", "queued", "state"),
    "LIM": ("joint", "min", "max", "vmax"),
    "STAT": ("state", "done", "queued", "ms"),
    "PING": ("ms",),
    "IDENT": ("uid", "cal"),
}

# Board -> host line kinds: verb -> the fields after the board's seq ("..." = a
# variable tail: payload, detail, joint columns or event args).
BOARD_LINES = {
    "OK": ("seq", "free", "..."),
    "ER": ("seq", "code", "name", "..."),
    "T": ("ms", "state", "done", "free", "..."),
    "EV": ("ms", "kind", "..."),
    "BOOT": ("fw", "fwver", "proto", "state"),
}

STATES = ("IDLE", "RUN", "HOLD", "ESTOP", "WDOG", "FAULT")
LATCHED_STATES = ("ESTOP", "WDOG", "FAULT")  # released only by CLR, never by HELLO or a reset

EVENTS = ("START", "DONE", "SLOW", "LIMIT", "ESTOP", "WDOG", "FAULT", "HOLD", "RESUME", "CLEAR", "PEN", "MAGNET", "ENDSTOP", "RELAY")

# A latch's reason (STAT's fifth field; the board's kind adds its own, docs/protocol.md
# §3.2, §9) -> (what happened, what EV FAULT's value `v` is: "error" in the joint's
# milli-unit, "effort" in per-mille of full drive, "magnet" a magnet's joint number).
# The reason's part after ":" names a joint (or LOCO, MISSED, SPURIOUS). Host-side words
# for summaries, recordings and `armbridge board state` (executor/faults.py); the boards
# send the tokens only.
FAULT_REASONS = {
    "FOLLOW": ("following error", "error"),
    "STALL": ("drive stalled", "effort"),
    "MAGNET": ("localisation lost", "magnet"),
    "WDOG": ("watchdog (no valid line in time)", None),
}
