"""Configuration of the MASR mobile actuator (MA) on the 5R arm (ESP32).
Board(hal, cfg) (ma.py) takes this module, or any object with the same names.

Units follow the protocol: angles in mrad, the MA position d in mm, speeds in
mrad/s and mm/s, times in ms. The board has N_JOINTS = 6 coordinates as the
link counts them: theta_1..theta_5, then d (masr paper, eq. (1)).
The HAL speaks counts and efforts in [-1, 1].
"""

FW_NAME = "masr_ma"
FW_VERSION = "0.1.0"

N_JOINTS = 6                         # coordinates: 5 joint angles + d
LINK_LENGTHS_MM = (200, 200, 200, 100, 100)   # l_1..l_5; joint j at r_j = sum_{i<j} l_i

# Hard limits (min, max) per coordinate, mrad for the joints (+-50 deg), mm for d
# (0..l); SETLIM may only narrow them.
LIMITS = ((-873, 873), (-873, 873), (-873, 873), (-873, 873), (-873, 873), (0, 800))
VMAX = (280, 280, 280, 280, 280, 100)   # mrad/s per joint (0.28 rad/s), mm/s for d

PERIOD_MS = 10                       # control period (100 Hz)
QSIZE = 16                           # action queue slots
TELEMETRY_HZ = 25                    # default telemetry rate (RATE changes it)
WDOG_MS = 1000                       # default watchdog timeout (WDOG changes it)
PERSIST_MS = 50                      # while moving, the position is persisted this often

# ---------------------------------------------------------------- sensors
WHEEL_MM_PER_COUNT = 0.05            # wheel encoder: MA travel per count (4x quadrature)
GEAR_MRAD_PER_COUNT = 0.1            # joint mrad per gear-encoder count, through the worm
HALL_WINDOW_MM = 1.5                 # the hall sensor fires within +-this of a magnet
SLIP_MAX = 0.01                      # |wheel slip| <= 1 % of the wheel's travel (rubber on the link)
BACKLASH_MRAD = 3.0                  # play of the worm drive, joint side
SPEED_TICKS = 2                      # MA speed: encoder counts over this many periods (20 ms)

# ---------------------------------------------------------------- locomotion
# Speed loop: effort per mm/s of speed error; kff = 1 / (speed at full effort).
LOCO_KP = 0.006                      # 1/(mm/s)
LOCO_KI = 0.06                       # 1/mm
LOCO_KD = 0.0
LOCO_KFF = 0.0085                    # s/mm (about 118 mm/s at full effort)
LOCO_KPOS = 6.0                      # 1/s: speed added per mm the MA lags its reference
LOCO_KAFF = 0.04                     # s: the reference's acceleration fed forward (the drive's lag)
LOCO_ACCEL_MM_S2 = 800               # ramp of the speed reference, start and stop (80 % of the traction limit;
                                     # the step kff kaff a it feeds forward stays within the drive)
LOCO_CREEP_MM_S = 15                 # lowest approach speed (HOME onto the base)
MAG_MM_S = 40                        # approach speed over the last w + 0.5 mm onto a magnet (ROT, MV onto a joint):
                                     # braked from there the MA stays inside the hall window
STOP_TOL_MM = 0.5                    # MV is done within this of d (and settled)
SETTLE_MM_S = 3                      # ... at a speed below this ...
SETTLE_MS = 20                       # ... for this long (MV, the stop on a magnet, ROT's turn: the angle unchanged)
HOME_MM_S = 40                       # HOME speed while the board does not know d
HOME_EFFORT = 0.5                    # effort cap while homing (pushing on the base stop)
HOME_STOP_MS = 150                   # no wheel progress this long at the base magnet: homed
END_APPROACH_MM = 10                 # END: ramp to this short of l, then push on the far stop at creep

# ---------------------------------------------------------------- joint rotation
# Joint loop: effort per rad of angle error; kff = 1 / (joint rate at full effort).
ROT_KP = 60.0                        # 1/rad (3 mrad short: 0.18 effort, the play crossed in ~50 ms)
ROT_KI = 1.0                         # 1/(rad s)
ROT_KD = 0.0                         # s/rad
ROT_KFF = 2.9                        # s/rad (about 0.35 rad/s at full effort)
ROT_KAFF = 0.05                      # s: the reference's acceleration fed forward (the drive's lag 0.03 s
                                     # + half a period + the gear count's delay)
ROT_ACCEL_MRAD_S2 = 3000             # ramp of the angle reference (kff kaff a: a step the drive's 5 rad/s^2 can take)
ROT_TOL_MRAD = 1.0                   # ROT is done within this of the angle (the drive off, the angle still)
ROT_CONTACT_LOAD = 0.010             # current sense above this (effort): the worm drives the gear, the play taken up
PLAY_MAX_MRAD = 40                   # the worm turned this far in the play without meeting the gear: FAULT MESH:j

# ---------------------------------------------------------------- faults
STALL_U = 0.25                       # an effort at least this with no encoder count ...
STALL_MS = 400                       # ... this long: FAULT STALL:LOCO / STALL:j
FOLLOW_ERR_MM = 30                   # |d reference - d| above this ...
FOLLOW_ERR_MRAD = 80                 # |theta reference - theta| above this ...
FOLLOW_ERR_MS = 500                  # ... this long: FAULT FOLLOW:j

# ---------------------------------------------------------------- gripper
GRIP_MS = 300                        # servo travel time: GRIP completes after it
GRIP_OPEN_US = 2000
GRIP_CLOSED_US = 1000
SERVO_FREQ_HZ = 50

# ---------------------------------------------------------------- pins (ESP32)
LOCO_PWM_PIN = 25                    # locomotion motor driver (e.g. DRV8871 / TB6612 IN/PWM)
LOCO_DIR_PIN = 26
ROT_PWM_PIN = 27                     # joint-rotation motor driver (DRV8874: PH/EN, with IPROPI below)
ROT_DIR_PIN = 14
ROT_ISENSE_PIN = 36                  # its current sense (IPROPI through a resistor into ADC1); None: no
                                     # sense, the joint estimated through the config's BACKLASH_MRAD
ROT_ISENSE_FULL = 1.0                # the load (effort, stall current = 1) at the ADC's full scale
MOTOR_PWM_HZ = 20000                 # above hearing
WHEEL_ENC_A = 32                     # wheel encoder, quadrature (PCNT unit WHEEL_PCNT)
WHEEL_ENC_B = 33
WHEEL_PCNT = 0
GEAR_ENC_A = 34                      # gear encoder of the rotation drive (PCNT unit GEAR_PCNT)
GEAR_ENC_B = 35
GEAR_PCNT = 1
ENC_FILTER_NS = 1000                 # PCNT glitch filter
HALL_PIN = 4                         # hall switch, open drain, active low (pulled up)
HALL_ACTIVE_LOW = True
HALL_RING = 16                       # wheel counts latched by the hall IRQ between two reads
GRIP_PIN = 13                        # gripper servo

UART_ID = 1                          # 0: the USB bridge (REPL pins), 1: GPIO TX/RX below
UART_TX = 17
UART_RX = 16
UART_BAUD = 115200
UART_RXBUF = 1024
