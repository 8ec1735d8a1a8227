/* The proportional controller with dead band, saturation and asymmetry, and the settle
 * around it (control.h). */
#include "control.h"

#include "config.h"

/* No 64-bit division (the AVR has no divider: one costs thousands of cycles): kp <= 1e6
 * (GAIN's range), so kp x 600 fits 32 bits; u = kp x mag / 1000 saturates at cap exactly
 * when kp x mag >= cap x 1000 (a multiply), below which kp x mag < 1e6 fits 32 bits. */
int16_t p_control(const PGain &g, int32_t e) {
    int32_t mag = e < 0 ? -e : e;
    if (mag <= g.dband || g.kp <= 0) return 0;
    int32_t kp = g.kp;
    int32_t cap = DUTY_MAX_DEFLATE;
    if (e > 0) {
        kp = kp * KP_INFLATE_PERMILLE / 1000;
        cap = DUTY_MAX_INFLATE;
        if (kp <= 0) return DUTY_MIN;
    }
    /* saturated iff kp x mag >= cap x 1000: a 32x32->64 multiply, no division */
    int32_t u = (int64_t)kp * mag >= (int64_t)cap * 1000 ? cap : kp * mag / 1000;   /* thousandths x mrad -> per-mille */
    if (u < DUTY_MIN) u = DUTY_MIN;
    return (int16_t)(e > 0 ? u : -u);
}

void seek_reset(Seek &s) {
    s.seeking = 0;
    s.dir = 0;
    s.ramp = 0;
}

int16_t seek_control(Seek &s, const PGain &g, int32_t e) {
    int32_t mag = e < 0 ? -e : e;
    int32_t band = g.dband < 0 ? 0 : g.dband;
    int32_t fine = band < SETTLE_FINE_MRAD ? band : SETTLE_FINE_MRAD;
    int32_t reseek = band < SETTLE_RESEEK_MRAD ? band : SETTLE_RESEEK_MRAD;
    if (g.kp <= 0) {
        seek_reset(s);
        return 0;
    }
    if (!s.seeking) {
        if (mag <= reseek) return 0;
        s.seeking = 1;
        s.ramp = 0;
        s.dir = e > 0 ? 1 : -1;
    } else if (mag <= fine || (e > 0) != (s.dir > 0)) {
        seek_reset(s);                       /* settled (or past the set point): pump off */
        return 0;
    }
    PGain p = g;
    p.dband = 0;
    int32_t u = p_control(p, e);
    if (u < 0) u = -u;
    if (mag <= band) {
        s.ramp = (int16_t)(s.ramp + SEEK_RAMP_PERMILLE);
        if (s.ramp > SEEK_RAMP_MAX) s.ramp = SEEK_RAMP_MAX;
    }
    int32_t cap = e > 0 ? DUTY_MAX_INFLATE : DUTY_MAX_DEFLATE;
    u += s.ramp;
    if (u > cap) u = cap;
    return (int16_t)(e > 0 ? u : -u);
}
