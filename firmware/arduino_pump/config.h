/* The syringe-pump board's configuration: pins (Arduino Mega 2560) and defaults.
 *
 * Units as every armbridge board: angles in mrad, speeds in mrad/s, times in ms,
 * duties in per-mille (signed: + inflates, the syringe pushes air into the joint).
 * Joint ranges are the soft3 robot's (host/armbridge/robots/catalog.py): 0..30,
 * 0..55, 0..60 deg (the paper's section V-B/C). Portable: no Arduino header.
 */
#ifndef PUMP_CONFIG_H
#define PUMP_CONFIG_H

#include <stdint.h>

#define FW_NAME "arduino_pump"
#define FW_VERSION "0.1.0"
#define FW_VERSION_MAJOR 0
#define FW_VERSION_MINOR 1
#define FW_VERSION_PATCH 0

#define N_JOINTS 3
#define QSIZE 32               /* waypoint queue slots */
#define PERIOD_MS 10           /* control period: a Timer5 interrupt (hal_avr.cpp), not loop speed */
#define TELEMETRY_HZ 25        /* default telemetry rate (RATE changes it) */
#define WDOG_MS 1000           /* default watchdog (WDOG changes it) */
#define UART_BAUD 115200UL

/* Hard limits per joint (min, max in mrad; vmax in mrad/s). SETLIM only narrows. */
#define LIM_MIN_MRAD {0, 0, 0}
#define LIM_MAX_MRAD {524, 960, 1047}
#define VMAX_MRAD_S {500, 500, 500}

/* The proportional controller E = K (theta_r - theta_c) (paper eq. 24), per joint.
 * KP in thousandths of duty per-mille per mrad (GAIN j kp ki kd; ki and kd are
 * accepted, kept for reading back, and not used: the paper's controller is P only).
 * The asymmetry (inflation abrupt after a threshold, deflation smooth, Fig. 9a):
 * inflating uses KP * KP_INFLATE_PERMILLE / 1000 and saturates at DUTY_MAX_INFLATE,
 * deflating uses KP and saturates at DUTY_MAX_DEFLATE; outside the dead band the
 * drive is at least DUTY_MIN (the motor's break-away). */
#define KP_DEFAULT 4000                  /* 4 per-mille of duty per mrad */
#define KP_INFLATE_PERMILLE 600          /* inflation gain = 0.6 x KP */
#define DUTY_MAX_INFLATE 700
#define DUTY_MAX_DEFLATE 1000
#define DUTY_MIN 120
#define DBAND_DEFAULT_MRAD 70            /* 4 deg, the paper's band for three joints */

/* The settle inside the dead band (control.h seek_control): a joint seeks its set point
 * until within SETTLE_FINE_MRAD, then rests with the pump off until its error exceeds
 * SETTLE_RESEEK_MRAD (hysteresis); inside the dead band a ramp adds SEEK_RAMP_PERMILLE
 * of duty per control period (2 per 10 ms: 200 per-mille/s) up to SEEK_RAMP_MAX, reset
 * at every settle. The paper's P controller stopped at the edge of its 4 deg band. */
#define SETTLE_FINE_MRAD 3               /* 0.17 deg: 1.5 counts of the bend sensor */
#define SETTLE_RESEEK_MRAD 8             /* 0.46 deg: 4 counts, above its noise (docs/pump.md) */
#define SEEK_RAMP_PERMILLE 2
#define SEEK_RAMP_MAX 400

/* RELAY j amp hyst cycles (Astrom-Hagglund relay feedback, firmware/common/relay.py): a
 * relay that has not switched for RELAY_TIMEOUT_MS gives up (EV RELAY j 0 0). With a
 * hysteresis the joint cannot cross, it is an open-loop push at a known duty until the
 * end stop (the calibration's drive, docs/pump.md "Calibration"). */
#define RELAY_TIMEOUT_MS 20000

/* Following error |set point - angle| above FOLLOW_ERR_MRAD for FOLLOW_ERR_MS -> FAULT. */
#define FOLLOW_ERR_MRAD 300
#define FOLLOW_ERR_MS 2000

/* Syringe travel estimate: a full stroke at full duty takes SYRINGE_STROKE_MS; the
 * estimate integrates the duty and is re-zeroed at the end stops (0 retracted,
 * 1000 extended). It starts at 0 after a reset (syringes rest retracted). */
#define SYRINGE_STROKE_MS 5000

/* Bend-sensor calibration defaults (BEND j adc_a a adc_b b; kept in EEPROM):
 * ADC count adc_a at angle a, adc_b at b, linear between. A flex sensor in a
 * divider: about 1.0 V (205 counts) straight, about 3.5 V (716) at 60 deg. */
#define BEND_DEFAULT {{205, 0, 716, 1047}, {205, 0, 716, 1047}, {205, 0, 716, 1047}}

/* ------------------------------------------------------------------ pins (Mega 2560)
 * Motor k (k = 0, 1, 2) on an L298: EN (PWM) on PIN_EN[k], IN1/IN2 on PIN_IN1[k]/PIN_IN2[k].
 * IN1 high, IN2 low: forward (inflate); IN1 low, IN2 high: backward (deflate);
 * both low with EN 0: off. EN pins are timer PWM pins simavr's model exposes
 * (9 = OC2B, 10 = OC2A, 11 = OC1A; not 2/3: external-interrupt pins).
 * Bend sensor k on A0+k. End stops (INPUT_PULLUP, LOW = at the stop): retracted on
 * PIN_STOP_RET[k], extended on PIN_STOP_EXT[k]. */
#define PIN_EN {9, 10, 11}
#define PIN_IN1 {22, 24, 26}
#define PIN_IN2 {23, 25, 27}
#define PIN_BEND {0, 1, 2}           /* analog channels A0..A2 (Arduino pins 54..56) */
#define PIN_STOP_RET {30, 32, 34}
#define PIN_STOP_EXT {31, 33, 35}

/* EEPROM layout (docs/pump.md): two slots of the link record, the settings, and the
 * latch cell: one byte written at once when the state latches or CLR releases it (a
 * byte programs in 3.4 ms; the 32-byte record behind it takes ~110 ms), so a reset
 * right after an e-stop still boots latched. */
#define EE_LINK_A 0                  /* 32 bytes: link record, slot A */
#define EE_LINK_B 32                 /* 32 bytes: link record, slot B */
#define EE_SETTINGS 64               /* 44 bytes: bend calibration, Modbus mode and address */
#define EE_LATCH 108                 /* 1 byte: 0xC0 | latch state (0xC0: released) */
#define EE_CALIB 112                 /* 92 bytes: the calibration record (CALID: id, gains, bands, bends) */
#define EE_SERIAL 204                /* 4 bytes: the board's serial (IDENT's uid), made once when erased */
#define KEEP_SIZE 36                 /* bytes of .noinit SRAM: magic and the link record */
#define EE_SIZE 208                  /* bytes of EEPROM the board uses (the HAL's shadow) */

#endif
