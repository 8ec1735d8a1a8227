/* The pump's joint controller: E = K (theta_r - theta_c) (the paper's eq. 24), one
 * per joint, with the dead band, output saturation and the inflation/deflation
 * asymmetry (p_control: pure integer-in, integer-out), and the settle around it
 * (seek_control, below: a fine band with hysteresis and a ramp).
 *
 * The asymmetry (paper Fig. 9a: the elastomer inflates abruptly once the pressure
 * passes a threshold and deflates smoothly): a positive error (more bend wanted:
 * inflate) is driven with a lower gain, KP * KP_INFLATE_PERMILLE / 1000, and a lower
 * ceiling, DUTY_MAX_INFLATE, so that the abrupt part of the inflation is entered
 * slowly enough to stop inside the dead band; a negative error (deflate, smooth)
 * gets the full gain and the full range. Outside the dead band the drive is at least
 * DUTY_MIN either way (the motor's break-away), inside it the pump is off: the
 * closed syringe holds the air, so holding costs no drive.
 */
#ifndef PUMP_CONTROL_H
#define PUMP_CONTROL_H

#include <stdint.h>

struct PGain {
    int32_t kp;              /* thousandths of duty per-mille per mrad */
    int32_t dband;           /* mrad */
};

/* Duty in per-mille (+ inflates) for error = set point - angle (mrad). */
int16_t p_control(const PGain &g, int32_t error_mrad);

/* The settle (seek_control): the P law above, without its dead band, drives a joint
 * until it is within SETTLE_FINE_MRAD of its set point (or the error changes sign:
 * it passed the set point); then the joint is settled and its pump off (the closed
 * syringe holds the air) until the error grows past SETTLE_RESEEK_MRAD (hysteresis:
 * the sensor's noise, a leak's sag). Inside the dead band, where the P law alone
 * crawls at the motor's break-away (or stalls under a motor that needs more), a ramp
 * (the I term: the integral of the error's sign) adds SEEK_RAMP_PERMILLE per control
 * period, up to SEEK_RAMP_MAX; it is reset at every settle, so it cannot wind up.
 * Both bands are at most the joint's dead band (DBAND): 0 holds to the count.
 * Outside the dead band the drive is the P law's: the planner times moves with it. */
struct Seek {
    uint8_t seeking;         /* 1: driving to the set point; 0: settled, pump off */
    int8_t dir;              /* +1 / -1: the error's sign when the seek began */
    int16_t ramp;            /* per-mille added to the drive (the I term) */
};

void seek_reset(Seek &s);
int16_t seek_control(Seek &s, const PGain &g, int32_t error_mrad);

#endif
