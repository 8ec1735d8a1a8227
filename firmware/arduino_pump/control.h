/* The pump's joint controller: E = K (theta_r - theta_c) (the paper's eq. 24), one
 * per joint, with the dead band, output saturation and the inflation/deflation
 * asymmetry. Pure integer-in, integer-out; no state, so no windup to reset.
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

#endif
