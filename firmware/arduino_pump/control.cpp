/* The proportional controller with dead band, saturation and asymmetry (control.h). */
#include "control.h"

#include "config.h"

int16_t p_control(const PGain &g, int32_t e) {
    int32_t mag = e < 0 ? -e : e;
    if (mag <= g.dband || g.kp <= 0) return 0;
    if (mag > 100000L) mag = 100000L;                  /* keeps the product in 32 bits below */
    int32_t kp = g.kp;
    int32_t cap = DUTY_MAX_DEFLATE;
    if (e > 0) {
        kp = (int32_t)((int64_t)kp * KP_INFLATE_PERMILLE / 1000);
        cap = DUTY_MAX_INFLATE;
    }
    int64_t u = (int64_t)kp * mag / 1000;              /* kp thousandths x mrad -> per-mille */
    if (u > cap) u = cap;
    if (u < DUTY_MIN) u = DUTY_MIN;
    return (int16_t)(e > 0 ? u : -u);
}
