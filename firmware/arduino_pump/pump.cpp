/* The syringe-pump board (pump.h). */
#include "pump.h"

#include <string.h>

PumpBoard *g_pump = 0;

static int32_t round_mrad(float x) { return (int32_t)(x < 0 ? x - 0.5f : x + 0.5f); }

static int32_t bend_mrad(const BendCal &c, int32_t adc);

static void detail_joint(AbError *err, uint8_t j) {
    err->detail[0] = (char)('0' + j);
    err->detail[1] = 0;
}

/* ------------------------------------------------------------------ settings (EEPROM)
 * tag 'S', version 1, Modbus address (0: line protocol), pad; the bend calibration
 * of each joint (adc_a, a, adc_b, b); CRC-32 of the bytes before it. */
struct SettingsRec {
    uint8_t tag, ver, modbus, pad;
    BendCal cal[N_JOINTS];
    uint32_t crc;
};
static_assert(sizeof(SettingsRec) == 44 && sizeof(SettingsRec) <= EE_SIZE - EE_SETTINGS, "settings layout");

void PumpBoard::load_settings() {
    static const int32_t defaults[N_JOINTS][4] = BEND_DEFAULT;
    SettingsRec r;
    hal_->ee_read(EE_SETTINGS, &r, sizeof r);
    bool ok = r.tag == 'S' && r.ver == 1 && ab_crc32((const uint8_t *)&r, sizeof r - 4, 0) == r.crc;
    for (uint8_t j = 0; ok && j < N_JOINTS; j++)
        ok = r.cal[j].adc_a < r.cal[j].adc_b && r.cal[j].adc_b <= 1023 && r.cal[j].a != r.cal[j].b;
    if (ok && r.modbus > 247) ok = false;
    if (ok) {
        memcpy(cal, r.cal, sizeof cal);
        modbus_addr = r.modbus;
        return;
    }
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        cal[j].adc_a = (uint16_t)defaults[j][0];
        cal[j].a = defaults[j][1];
        cal[j].adc_b = (uint16_t)defaults[j][2];
        cal[j].b = defaults[j][3];
    }
    modbus_addr = 0;
}

void PumpBoard::save_settings() {
    SettingsRec r;
    memset(&r, 0, sizeof r);
    r.tag = 'S';
    r.ver = 1;
    r.modbus = modbus_addr;
    memcpy(r.cal, cal, sizeof cal);
    r.crc = ab_crc32((const uint8_t *)&r, sizeof r - 4, 0);
    hal_->ee_write(EE_SETTINGS, &r, sizeof r);
}

/* ------------------------------------------------------------------ calibration (CALID, IDENT)
 * tag 'C', version 1, pad; the calibration id; per joint kp, ki, kd (GAIN), the dead
 * band (DBAND) and the bend calibration (BEND); CRC-32 of the bytes before it. A boot
 * loads a whole record (every value in its verb's range) or none: then the defaults
 * and the settings record's bends stay, and IDENT reports cal 0. */
struct CalRec {
    uint8_t tag, ver, pad0, pad1;
    uint32_t id;
    int32_t kp[N_JOINTS], ki[N_JOINTS], kd[N_JOINTS];
    int16_t dband[N_JOINTS];
    int16_t pad2;
    BendCal cal[N_JOINTS];
    uint32_t crc;
};
static_assert(sizeof(CalRec) == 92 && EE_CALIB + sizeof(CalRec) <= EE_SERIAL, "calibration layout");
static_assert(EE_SERIAL + 4 <= EE_SIZE, "serial layout");

#define CAL_ID_MAX 1073741823L
#define GAIN_MAX 1000000L
#define DBAND_MAX 1000

static bool in(int32_t v, int32_t lo, int32_t hi) { return v >= lo && v <= hi; }

void PumpBoard::load_calibration() {
    CalRec r;
    cal_id = 0;
    hal_->ee_read(EE_CALIB, &r, sizeof r);
    bool ok = r.tag == 'C' && r.ver == 1 && in((int32_t)r.id, 1, CAL_ID_MAX) &&
              ab_crc32((const uint8_t *)&r, sizeof r - 4, 0) == r.crc;
    for (uint8_t j = 0; ok && j < N_JOINTS; j++)
        ok = in(r.kp[j], 0, GAIN_MAX) && in(r.ki[j], 0, GAIN_MAX) && in(r.kd[j], 0, GAIN_MAX) &&
             in(r.dband[j], 0, DBAND_MAX) && r.cal[j].adc_a < r.cal[j].adc_b && r.cal[j].adc_b <= 1023 &&
             r.cal[j].a != r.cal[j].b;
    if (!ok) return;
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        gain[j].kp = r.kp[j];
        ki[j] = r.ki[j];
        kd[j] = r.kd[j];
        gain[j].dband = r.dband[j];
        cal[j] = r.cal[j];
    }
    cal_id = r.id;
}

void PumpBoard::save_calibration(uint32_t id) {
    CalRec r;
    memset(&r, 0, sizeof r);
    r.tag = 'C';
    r.ver = 1;
    r.id = id;
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        r.kp[j] = gain[j].kp;
        r.ki[j] = ki[j];
        r.kd[j] = kd[j];
        r.dband[j] = (int16_t)gain[j].dband;
        r.cal[j] = cal[j];
    }
    r.crc = ab_crc32((const uint8_t *)&r, sizeof r - 4, 0);
    hal_->ee_write(EE_CALIB, &r, sizeof r);
    save_settings();          /* the bends in the settings record too: the same values */
    cal_id = id;
}

/* The Mega has no unique id: a 32-bit serial in EEPROM, made once when the EEPROM is
 * erased (0xFFFFFFFF) or zero, from the bend sensors' noise and the clock; kept from
 * then on. (The emulator writes one per emulated board into a fresh EEPROM.) */
void PumpBoard::load_serial() {
    hal_->ee_read(EE_SERIAL, &serial, sizeof serial);
    if (serial != 0xFFFFFFFFUL && serial != 0) return;
    uint32_t x = 0x9E3779B9UL ^ hal_->us();
    for (uint8_t i = 0; i < 32; i++) {
        x ^= (uint32_t)hal_->read_adc((uint8_t)(i % N_JOINTS)) << (i % 23);
        x ^= hal_->us();
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
    }
    if (x == 0xFFFFFFFFUL || x == 0) x = 0x5EED0001UL;
    serial = x;
    hal_->ee_write(EE_SERIAL, &serial, sizeof serial);
}

/* ------------------------------------------------------------------ boot */

void PumpBoard::begin(Hal *hal) {
    static const int32_t lmin[N_JOINTS] = LIM_MIN_MRAD, lmax[N_JOINTS] = LIM_MAX_MRAD;
    static const int32_t vmax[N_JOINTS] = VMAX_MRAD_S;
    hal_ = hal;
    g_pump = this;
    on_done = 0;
    traj.init(vmax);
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        hard[j][0] = lim[j][0] = lmin[j];
        hard[j][1] = lim[j][1] = lmax[j];
        hard[j][2] = lim[j][2] = vmax[j];
        traj.set_range(j, lmin[j], lmax[j], vmax[j]);
        gain[j].kp = KP_DEFAULT;
        gain[j].dband = DBAND_DEFAULT_MRAD;
        ki[j] = kd[j] = 0;
        seek_reset(seek[j]);
        relay[j].on = 0;
        u[j] = 0;
        syr_[j] = 0;
        fe_ms_[j] = 0;
    }
    blocked_ = 0;
    stops = 0;
    memset(&last_wp, 0, sizeof last_wp);
    load_settings();
    load_calibration();       /* a saved calibration's gains, bands and bends win */
    load_serial();
    link.begin(hal, this, modbus_addr);   /* last: it calls hold_here() and sends BOOT */
}

/* ------------------------------------------------------------------ BoardIf */

/* From the main loop with the period locked out (and the events of periods before it
 * made stale: link.h); from the period itself (a watchdog, a fault) as it is. */
void PumpBoard::halt() {
    if (link.in_period()) {
        halt_();
        return;
    }
    CtlLock l(hal_);
    halt_();
    link.halted();
}

bool PumpBoard::busy() {
    CtlLock l(hal_);
    return traj.busy();
}

void PumpBoard::halt_() {
    traj.flush();
    traj.hold = false;
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        u[j] = 0;
        seek_reset(seek[j]);
        relay[j].on = 0;      /* CLR, a latch, a new session end a relay */
    }
}

/* The set point becomes the measured angle. A joint at rest on a limit reads a
 * little past it (sensor noise: a straight joint reads -2..+2 mrad): an angle outside
 * the range by no more than the joint's dead band is taken as the limit itself, so
 * HELLO or CLR on a straight arm starts no ramp into range and sends no EV LIMIT
 * (the controller would not move the joint for that error anyway). Farther out (a
 * SETLIM narrowed below where the joint is) the set point ramps in, with EV LIMIT. */
void PumpBoard::hold_here() {
    int32_t m[N_JOINTS];      /* the sensors read outside the lock (the divisions) */
    float f[N_JOINTS];
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        m[j] = bend_mrad(cal[j], hal_->read_adc(j));
        int32_t x = m[j], lo = lim[j][0], hi = lim[j][1], band = gain[j].dband;
        if (x < lo && lo - x <= band) x = lo;
        if (x > hi && x - hi <= band) x = hi;
        f[j] = (float)x;
    }
    uint8_t st = hal_->endstops();
    CtlLock l(hal_);
    halt_();
    link.halted();
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        q[j] = m[j];
        fe_ms_[j] = 0;
    }
    stops = st;
    traj.set_point(f);
}

void PumpBoard::limits(uint8_t j, int32_t *m) {
    for (uint8_t i = 0; i < 3; i++) m[i] = lim[j - 1][i];
}

bool PumpBoard::motion_verb(int verb) { return verb == AB_VERB_W || verb == AB_VERB_RELAY; }

int PumpBoard::queue(uint16_t id, uint16_t dur, const int32_t *t, AbError *err) {
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        if (t[j] < lim[j][0] || t[j] > lim[j][1]) {
            detail_joint(err, (uint8_t)(j + 1));
            return AB_ERR_RANGE;
        }
    }
    if (!traj.push(id, dur, t)) return AB_ERR_FULL;
    link.queued = id;
    last_wp.id = id;
    last_wp.dur = dur;
    for (uint8_t j = 0; j < N_JOINTS; j++) last_wp.q[j] = t[j];
    return 0;
}

int PumpBoard::setlim(uint8_t j, int32_t lo, int32_t hi, int32_t vmax) {
    const int32_t *h = hard[j - 1];
    CtlLock l(hal_);          /* excludes() reads the queue, set_range() may re-plan */
    if (lo > hi || lo < h[0] || hi > h[1] || vmax < 1 || vmax > h[2] || traj.excludes((uint8_t)(j - 1), lo, hi))
        return AB_ERR_RANGE;
    lim[j - 1][0] = lo;
    lim[j - 1][1] = hi;
    lim[j - 1][2] = vmax;
    traj.set_range((uint8_t)(j - 1), lo, hi, vmax);
    return 0;
}

int PumpBoard::set_bend(uint8_t j, const BendCal &c) {
    if (c.adc_a >= c.adc_b || c.adc_b > 1023 || c.a == c.b) return AB_ERR_RANGE;
    {
        CtlLock l(hal_);
        cal[j - 1] = c;
    }
    save_settings();
    return 0;
}

int PumpBoard::command(int verb, const int32_t *v, Payload *out, AbError *err) {
    uint8_t j = (uint8_t)v[0];
    switch (verb) {
        case AB_VERB_W:
            return queue((uint16_t)v[0], (uint16_t)v[1], v + 2, err);
        case AB_VERB_GAIN: {
            CtlLock l(hal_);
            gain[j - 1].kp = v[1];
            ki[j - 1] = v[2];
            kd[j - 1] = v[3];
            return 0;
        }
        case AB_VERB_SETLIM:
            if (setlim(j, v[1], v[2], v[3])) {
                detail_joint(err, j);
                return AB_ERR_RANGE;
            }
            return 0;
        case AB_VERB_DBAND: {
            CtlLock l(hal_);
            gain[j - 1].dband = v[1];
            return 0;
        }
        case AB_VERB_BEND: {
            BendCal c;
            c.adc_a = (uint16_t)v[1];
            c.a = v[2];
            c.adc_b = (uint16_t)v[3];
            c.b = v[4];
            if (set_bend(j, c)) {
                detail_joint(err, j);
                return AB_ERR_RANGE;
            }
            return 0;
        }
        case AB_VERB_IDENT: {
            static const char hex[] = "0123456789abcdef";
            char u[9];
            for (uint8_t i = 0; i < 8; i++) u[i] = hex[(serial >> (28 - 4 * i)) & 0xF];
            u[8] = 0;
            out->str(u);
            out->num((int32_t)cal_id);
            return 0;
        }
        case AB_VERB_CALID:
            save_calibration((uint32_t)v[0]);
            return 0;
        case AB_VERB_RELAY: {
            CtlLock l(hal_);
            if (traj.busy()) return AB_ERR_RANGE;
            RelayRun &r = relay[j - 1];
            memset(&r, 0, sizeof r);
            r.on = 1;
            r.out = 1;                /* starts pushing up (inflating) */
            r.amp = (int16_t)v[1];
            r.hyst = v[2];
            r.cycles = (uint8_t)v[3];
            r.last_switch = hal_->ms();
            r.hi = r.lo = q[j - 1];
            seek_reset(seek[j - 1]);
            return 0;
        }
        case AB_VERB_MODBUS:
            modbus_addr = (uint8_t)v[0];
            save_settings();
            link.switch_to_modbus(modbus_addr);
            return 0;
        default:
            return AB_ERR_VERB;
    }
}

/* A snapshot of the period's values under the lock (a copy: a few us), formatted after. */
void PumpBoard::telemetry(LineWriter *w) {
    int32_t qq[N_JOINTS], syr[N_JOINTS];
    float sp[N_JOINTS];
    int16_t uu[N_JOINTS];
    uint8_t st;
    {
        CtlLock l(hal_);
        for (uint8_t j = 0; j < N_JOINTS; j++) {
            qq[j] = q[j];
            sp[j] = traj.sp[j];
            uu[j] = u[j];
            syr[j] = syr_[j];
        }
        st = stops;
    }
    for (uint8_t j = 0; j < N_JOINTS; j++) w->num(qq[j]);
    for (uint8_t j = 0; j < N_JOINTS; j++) w->num(round_mrad(sp[j]));
    for (uint8_t j = 0; j < N_JOINTS; j++) w->num(uu[j]);
    for (uint8_t j = 0; j < N_JOINTS; j++) w->num(syr[j] / 1000);
    w->num(st);
}

/* ------------------------------------------------------------------ control */

/* The calibration line in integers, rounded to the nearest mrad (half away from zero):
 * |adc - adc_a| <= 1023 and |b - a| <= 2e6 keep the product in 32 bits; adc_b > adc_a
 * (BEND checks it). One 32-bit division per joint: no float on a chip without an FPU. */
static int32_t bend_mrad(const BendCal &c, int32_t adc) {
    int32_t num = (adc - (int32_t)c.adc_a) * (c.b - c.a), den = (int32_t)c.adc_b - (int32_t)c.adc_a;
    int32_t f = num >= 0 ? (num + den / 2) / den : -((-num + den / 2) / den);
    return c.a + f;
}

void PumpBoard::read_sensors() {
    for (uint8_t j = 0; j < N_JOINTS; j++) q[j] = bend_mrad(cal[j], hal_->read_adc(j));
    stops = hal_->endstops();
}

void PumpBoard::control(uint8_t mode) {
    /* the travel estimate integrates the duty of the period that just ended */
    for (uint8_t j = 0; j < N_JOINTS; j++) {
#if (PERIOD_MS * 1000L) % SYRINGE_STROKE_MS == 0   /* a multiply, no division */
        syr_[j] += (int32_t)u[j] * (PERIOD_MS * 1000L / SYRINGE_STROKE_MS);   /* full = 1e6 */
#else
        syr_[j] += (int32_t)u[j] * PERIOD_MS * 1000L / SYRINGE_STROKE_MS;
#endif
        if (syr_[j] < 0) syr_[j] = 0;
        if (syr_[j] > 1000000L) syr_[j] = 1000000L;
    }
    read_sensors();
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        if (stops & (1u << (2 * j))) syr_[j] = 0;
        if (stops & (2u << (2 * j))) syr_[j] = 1000000L;
    }
    if (mode != CTL_DRIVE) {
        for (uint8_t j = 0; j < N_JOINTS; j++) {
            u[j] = 0;
            seek_reset(seek[j]);
            relay[j].on = 0;
        }
        blocked_ = 0;
        if (mode == CTL_ZERO)
            for (uint8_t j = 0; j < N_JOINTS; j++) hal_->write_duty(j, 0);
        return;
    }
    advance();
    uint32_t now = hal_->ms();
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        int16_t d = relay[j].on ? relay_step(j, now) : seek_control(seek[j], gain[j], round_mrad(traj.sp[j]) - q[j]);
        bool at_ext = (stops >> (2 * j + 1)) & 1, at_ret = (stops >> (2 * j)) & 1;
        uint8_t bit = (uint8_t)(1u << j);
        if ((d > 0 && at_ext) || (d < 0 && at_ret)) {   /* an end stop stops that pump */
            d = 0;
            if (!(blocked_ & bit)) {
                blocked_ |= bit;
                link.event("ENDSTOP", 1, j + 1);
            }
        } else if (d != 0) {
            blocked_ &= (uint8_t)~bit;
        }
        u[j] = d;
        hal_->write_duty(j, d);
    }
    check_following();
}

/* One tick of the trajectory. Its events are coalesced, as the arm's, so that short
 * waypoints cannot flood the return lane: one DONE for the last waypoint completed
 * in the tick, START only for a waypoint that starts from rest. */
void PumpBoard::advance() {
    TrajEvent ev[TRAJ_MAX_EVENTS];
    uint8_t n = traj.step(PERIOD_MS, ev);
    int32_t last_done = -1;
    for (uint8_t i = 0; i < n; i++) {
        switch (ev[i].kind) {
            case TE_DONE:
                last_done = ev[i].a;
                if (on_done) on_done(ev[i].a);
                break;
            case TE_START:
                if (last_done < 0) link.event("START", 1, ev[i].a);
                break;
            case TE_SLOW: link.event("SLOW", 2, ev[i].a, ev[i].b); break;
            case TE_LIMIT: link.event("LIMIT", 1, ev[i].a); break;
            default: break;
        }
    }
    if (last_done >= 0) link.completed(last_done);
}

/* One period of joint j's relay: +-amp about the set point, switching when the error
 * crosses +-hyst; after `cycles` whole cycles past the first (settling) one, EV RELAY j
 * period_ms amp_mrad (the mean period, the mean half peak-to-peak); without a switch
 * for RELAY_TIMEOUT_MS, EV RELAY j 0 0. Either way the loop then holds the set point. */
int16_t PumpBoard::relay_step(uint8_t j, uint32_t now) {
    RelayRun &r = relay[j];
    int32_t m = q[j], e = round_mrad(traj.sp[j]) - m;
    if ((uint32_t)(now - r.last_switch) > RELAY_TIMEOUT_MS) {
        r.on = 0;
        seek_reset(seek[j]);
        link.event("RELAY", 3, j + 1, 0, 0);
        return 0;
    }
    if (m > r.hi) r.hi = m;
    if (m < r.lo) r.lo = m;
    if (r.out > 0 && e < -r.hyst) {
        r.out = -1;
        r.last_switch = now;
    } else if (r.out < 0 && e > r.hyst) {
        r.out = 1;
        r.last_switch = now;
        r.ups++;
        if (r.ups == 2) r.first_up = now;
        if (r.ups >= 3) r.sum_pp += r.hi - r.lo;    /* a counted whole cycle */
        r.hi = r.lo = m;
        if (r.ups >= r.cycles + 2) {
            r.on = 0;
            seek_reset(seek[j]);
            int32_t period = (int32_t)((now - r.first_up) / r.cycles);
            link.event("RELAY", 3, j + 1, period, r.sum_pp / (2 * (int32_t)r.cycles));
            return 0;
        }
    }
    return (int16_t)(r.out > 0 ? r.amp : -r.amp);
}

void PumpBoard::check_following() {
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        if (relay[j].on) {    /* the relay drives the joint away from its set point on purpose */
            fe_ms_[j] = 0;
            continue;
        }
        int32_t err = round_mrad(traj.sp[j]) - q[j];
        if (err > FOLLOW_ERR_MRAD || err < -FOLLOW_ERR_MRAD) {
            fe_ms_[j] = (uint16_t)(fe_ms_[j] + PERIOD_MS);
            if (fe_ms_[j] >= FOLLOW_ERR_MS) {
                char why[LINK_REASON_MAX] = "FOLLOW:0";
                why[7] = (char)('1' + j);
                link.fault(j + 1, err, why);
                return;
            }
        } else {
            fe_ms_[j] = 0;
        }
    }
}
