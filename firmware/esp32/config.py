"""Configuration of the 3R planar servo arm (ESP32). Board(hal, cfg) takes this
module, or any object with the same attribute names.

Units follow the protocol: positions in mrad, speeds in mrad/s, times in ms.
The HAL speaks SI units (rad) and efforts in [-1, 1].
"""

FW_NAME = "arm3r"
FW_VERSION = "0.1.0"

N_JOINTS = 3
JOINT_NAMES = ("shoulder", "elbow", "wrist")
LINK_LENGTHS_M = (0.19, 0.12, 0.07)

# Hard joint limits (min, max) in mrad; SETLIM may only narrow them.
LIMITS_MRAD = ((0, 3142), (-3142, 0), (-1571, 1571))
VMAX_MRAD_S = (3000, 3000, 3000)   # speed limit per joint

PERIOD_MS = 10                      # control period (100 Hz)
QSIZE = 32                          # waypoint queue slots
TELEMETRY_HZ = 25                   # default telemetry rate (RATE changes it)
WDOG_MS = 1000                      # default watchdog timeout (WDOG changes it)

# PID per joint, effort in [-1, 1] per rad of error. Tuned against the servo
# plant: joint velocity = effort * 5.0 rad/s behind a 30 ms first-order lag.
# kff = 1 / 5.0 makes the feed-forward alone produce the planned velocity.
PID_KP = (8.0, 8.0, 8.0)            # 1/rad
PID_KI = (2.0, 2.0, 2.0)            # 1/(rad s)
PID_KD = (0.15, 0.15, 0.15)         # s/rad (on the measurement)
PID_KFF = (0.2, 0.2, 0.2)           # s/rad (on the set-point velocity)

# Speed cap on the PID's output (arm.SpeedCap), so that a joint catching up
# with a set point at vmax does not pass vmax: at most the feed-forward's
# effort at vmax, (kff + trim) * vmax (never below SPEED_UMIN), less SPEED_KV
# per rad/s of measured speed over vmax; the trim (within +-SPEED_TRIM * kff)
# learns, at SPEED_KI, the effort that holds vmax while the output sits at the cap.
SPEED_KV = 0.5                      # effort per rad/s over vmax
SPEED_KI = 2.0                      # 1/s: the trim's learning rate (relative to kff, per relative speed error)
SPEED_TRIM = 0.5                    # the trim's bound, a fraction of kff
SPEED_UMIN = 0.1                    # the cap is never below this effort (a slow vmax still moves and holds)

# Following error |set point - measured| above this for this long -> FAULT.
FOLLOW_ERR_MRAD = 350
FOLLOW_ERR_MS = 300

# ---------------------------------------------------------------- pins (ESP32)
PWM_PINS = (25, 26, 27)
PWM_FREQ_HZ = 50
PULSE_MIN_US = 1000                 # effort -1
PULSE_NEUTRAL_US = 1500             # effort 0
PULSE_MAX_US = 2000                 # effort +1

# Feedback potentiometers, linear calibration per joint:
# rad = ADC_RAD_AT_CENTER + ADC_RAD_PER_V * (volts - ADC_CENTER_V)
ADC_PINS = (32, 33, 34)
ADC_CENTER_UV = (1650000, 1650000, 1650000)
ADC_RAD_AT_CENTER = (1.5708, -1.5708, 0.0)
ADC_RAD_PER_V = (1.5, 1.5, 1.5)     # 270 deg pot over ~3.14 V

UART_ID = 1                         # 0: the USB bridge (REPL pins), 1: GPIO TX/RX below
UART_TX = 17
UART_RX = 16
UART_BAUD = 115200
UART_RXBUF = 1024

# ---------------------------------------------------------------- the rig
# "effort": continuous-rotation servos driven by effort with potentiometer
# feedback (hal_esp32.Esp32Hal). "pca9685": the paper's rig (section 4.1,
# Table 1): positional hobby servos behind a PCA9685 I2C servo controller
# (hal_pca9685.Pca9685Hal), feedback pots on the ADC pins above.
SERVOS = "effort"
I2C_ID = 0
I2C_SCL = 22
I2C_SDA = 21
I2C_FREQ = 400000
PCA9685_ADDR = 0x40
# The PWM frame (Hz) of every PCA9685 channel. One count is a 4096th of the
# frame: at 50 Hz 4.88 us, 11.5 mrad of a 270 deg servo (about 2 mm at the pen);
# at 200 Hz 1.22 us (2.9 mrad). 50 is the default because every hobby servo,
# the analog SG90-class pen lift included, takes it; a rig whose servos are all
# digital (the DS3235 takes up to 333 Hz) should use 200: finer steps and a
# shorter frame; the drawn "ARM" then keeps within 1.5 mm of its strokes on
# every drawn board, which 50 Hz's counts alone cannot (docs/calibration.md).
SERVO_FREQ_HZ = 50
# The positional servos trail their pulse by their own loop's lag (about 40 ms,
# first order: v * tau along a ramp); the board sends each set point this far
# ahead along its velocity (0: none). Only while the set point moves; a servo
# with a DBAND (its hysteresis, which servos.py leads by half) is led here only
# by what this adds beyond half its DBAND width (arm.py _led).
SERVO_LEAD_MS = 40
SERVO_CHANNELS = (0, 1, 2)          # PCA9685 channel of each joint
# Per joint: pulse us_a (us) at angle a (mrad) and us_b at b; linear between.
# A 270 deg servo (500..2500 us) mounted with its centre at the middle of the
# joint's range. CAL changes them at run time (RAM only).
SERVO_CAL = ((500, -785, 2500, 3927), (500, -3927, 2500, 785), (500, -2356, 2500, 2356))

# ---------------------------------------------------------------- pen lift
# An optional fourth servo lifts the pen (as BrachioGraph's): PCA9685 channel
# PEN_CHANNEL on the pca9685 rig, PWM pin PEN_PIN on the effort rig (None: no
# pen servo, and the PEN verb is refused VERB).
PEN_CHANNEL = 3
PEN_PIN = 14
# The next three are defaults: PENPOS sets them (arm_pen.py) and CALID keeps them.
PEN_UP_US = 1200
PEN_DOWN_US = 1700
PEN_SETTLE_MS = 150                 # a pen change waits this long before the next move

# ---------------------------------------------------------------- board IK
# Cartesian waypoints (X, XY) are solved on the board by the int8 net
# (ik3r.py, mlp.py) plus a fixed number of FABRIK passes. The weights are a
# file on the board's filesystem (models/onnx/arm3r-ik/int8.bin, flashed as
# IK_WEIGHTS); without it X and XY are refused VERB.
IK_WEIGHTS = "arm3r_ik.bin"
IK_THETA_MRAD = 0                   # the pen angle XY uses (host: ik.region.pen_angle)
IK_REGION_UM = (76000, 190000, 114853)   # safe disc (cx, cy, r): host ik.region.safe_region, r rounded up + 1 um (X rounds x, y to um)
IK_FABRIK_PASSES = 128              # fixed passes: every disc target at IK_THETA within IK_TOL (100,000 of 100,000, max 40 um)
IK_TOL_UM = 100                     # a solve that ends farther than this from the target: REACH
