/* Trajectory (traj.h): firmware/common/traj.py step for step. */
#include "traj.h"

static_assert(QSIZE <= 128 && (256 % QSIZE) == 0, "free-running byte indices");

static void add(TrajEvent *ev, uint8_t *ne, uint8_t kind, int32_t a, int32_t b) {
    if (*ne < TRAJ_MAX_EVENTS) {
        ev[*ne].kind = kind;
        ev[*ne].a = a;
        ev[*ne].b = b;
        (*ne)++;
    } else if (kind == TE_DONE) {   /* keep the newest DONE: those before it are done too */
        ev[TRAJ_MAX_EVENTS - 1].kind = kind;
        ev[TRAJ_MAX_EVENTS - 1].a = a;
        ev[TRAJ_MAX_EVENTS - 1].b = b;
    }
}

void Traj::init(const int32_t *vmax_) {
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        vmax[j] = vmax_[j];
        lo[j] = -(1L << 30);
        hi[j] = 1L << 30;
        ramping_[j] = false;
        sp[j] = 0.0f;
        vel[j] = 0.0f;
    }
    hold = false;
    head_ = tail_ = 0;
    active_id = -1;
    dur_ = t_ = 0;
    scale_ = 1.0f;
}

bool Traj::push(uint16_t id, uint16_t dur, const int32_t *q) {
    uint8_t t = tail_;
    if ((uint8_t)(t - head_) >= QSIZE) return false;
    Waypoint &w = queue_[t % QSIZE];
    w.id = id;
    w.dur = dur;
    for (uint8_t j = 0; j < N_JOINTS; j++) w.q[j] = q[j];
    tail_ = (uint8_t)(t + 1);   /* volatile, after the entry: the period takes it whole */
    return true;
}

void Traj::set_range(uint8_t j, int32_t lo_, int32_t hi_, int32_t vmax_) {
    bool slower = vmax_ < vmax[j];
    lo[j] = lo_;
    hi[j] = hi_;
    vmax[j] = vmax_;
    if (slower && active_id >= 0) {   /* re-plan from where the set point is */
        for (uint8_t k = 0; k < N_JOINTS; k++) start_[k] = sp[k];
        plan(dur_ - t_);
        for (uint8_t k = 0; k < N_JOINTS; k++) vel[k] = (end_[k] - start_[k]) * scale_;
    }
}

bool Traj::excludes(uint8_t j, int32_t lo_, int32_t hi_) const {
    for (uint8_t i = 0, n = count(); i < n; i++) {
        int32_t x = queue_[(uint8_t)(head_ + i) % QSIZE].q[j];
        if (x < lo_ || x > hi_) return true;
    }
    return active_id >= 0 && (targets_[j] < lo_ || targets_[j] > hi_);
}

void Traj::flush() {
    head_ = tail_;
    active_id = -1;
    for (uint8_t j = 0; j < N_JOINTS; j++) vel[j] = 0.0f;
}

void Traj::set_point(const float *q) {
    flush();
    for (uint8_t j = 0; j < N_JOINTS; j++) sp[j] = q[j];
}

void Traj::last_target(float *q) const {
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        if (count()) q[j] = (float)queue_[(uint8_t)(tail_ - 1) % QSIZE].q[j];
        else if (active_id >= 0) q[j] = end_[j];
        else q[j] = sp[j];
    }
}

uint8_t Traj::step(uint16_t dt_ms, TrajEvent *ev) {
    uint8_t ne = 0;
    if (hold) {
        for (uint8_t j = 0; j < N_JOINTS; j++) vel[j] = 0.0f;
        return 0;
    }
    if (active_id < 0 && count() == 0) {
        ramp(dt_ms, ev, &ne);
        return ne;
    }
    uint32_t left = active_id < 0 ? 0 : dt_ms;
    for (;;) {
        if (active_id < 0) {
            if (count() == 0) {
                for (uint8_t j = 0; j < N_JOINTS; j++) vel[j] = 0.0f;
                break;
            }
            begin(ev, &ne);
        }
        t_ += left;
        if (t_ < dur_) {
            interpolate();
            break;
        }
        left = t_ - dur_;
        for (uint8_t j = 0; j < N_JOINTS; j++) {
            sp[j] = end_[j];
            vel[j] = 0.0f;
        }
        add(ev, &ne, TE_DONE, active_id, 0);
        active_id = -1;
        if (left == 0 && count() == 0) break;
    }
    return ne;
}

void Traj::ramp(uint16_t dt_ms, TrajEvent *ev, uint8_t *ne) {
    if (dt_ms == 0) return;
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        float x = sp[j];
        if (x >= (float)lo[j] && x <= (float)hi[j]) {
            ramping_[j] = false;
            vel[j] = 0.0f;
            continue;
        }
        if (!ramping_[j]) {
            ramping_[j] = true;
            add(ev, ne, TE_LIMIT, j + 1, 0);
        }
        float reach = (float)vmax[j] * dt_ms / 1000.0f;
        float y;
        if (x < (float)lo[j]) y = (float)lo[j] - x <= reach ? (float)lo[j] : x + reach;
        else y = x - (float)hi[j] <= reach ? (float)hi[j] : x - reach;
        vel[j] = (y - x) * 1000.0f / dt_ms;
        sp[j] = y;
    }
}

void Traj::begin(TrajEvent *ev, uint8_t *ne) {
    const Waypoint &w = queue_[head_ % QSIZE];
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        ramping_[j] = false;
        start_[j] = sp[j];
        end_[j] = (float)w.q[j];
        targets_[j] = w.q[j];
    }
    active_id = w.id;
    uint16_t dur = w.dur;
    head_ = (uint8_t)(head_ + 1);   /* after the entry is read: the slot is the producer's again */
    add(ev, ne, TE_START, active_id, 0);
    int worst = plan(dur);
    if (worst >= 0) add(ev, ne, TE_SLOW, w.id, worst + 1);
}

/* The time a move of a mrad needs at vmax, ceil(a * 1000 / vmax) in float, when it is
 * longer than dur ms, else 0. The float formula costs a division (and conversions) per
 * joint; where a is a whole number below 8388 (a * 1000 < 2^23, exact in float) and
 * 0 < vmax < 2^24 its result is ceil(N / vmax) of the integers N = a * 1000 and vmax
 * exactly (a quotient k + r/vmax, r > 0, lies more than an ulp of it above k), so "not
 * longer" is the integer test N <= dur * vmax, one 32-bit multiply (a product that wraps
 * is smaller than the true one: it can only send a move to the float formula). The rest
 * (a move from a set point between whole mrad: a re-plan, a move from rest; a move longer
 * than dur) takes the float formula itself. */
static uint32_t need_ms(float a, int32_t vmax, uint32_t dur) {
    if (a < 8388.0f && vmax > 0 && vmax < (1L << 24)) {
        uint16_t ai = (uint16_t)a;
        if ((float)ai == a && dur * (uint32_t)vmax >= (uint32_t)ai * 1000u) return 0;
    }
    float need = a * 1000.0f / (float)vmax;
    /* beyond 2^32 ms (a tiny vmax) the conversion is undefined: saturate (largest float below 2^32) */
    uint32_t ms = need < 4294967040.0f ? (uint32_t)need : 4294967040UL;
    if ((float)ms < need) ms++;
    return ms > dur ? ms : 0;
}

/* Sets dur_ (stretched to the joints' vmax), scale_ = 1000 / dur_ and t_ = 0. Not vel:
 * step() sets it after begin() (interpolate() or DONE), set_range() after its re-plan. */
int Traj::plan(uint32_t dur) {
    int worst = -1;
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        float d = end_[j] - start_[j];
        uint32_t need = need_ms(d < 0 ? -d : d, vmax[j], dur);
        if (need) {
            dur = need;
            worst = j;
        }
    }
    if (dur < 1) dur = 1;
    if (dur != dur_) scale_ = 1000.0f / (float)dur;   /* else scale_ = 1000 / dur_ from the last plan */
    dur_ = dur;
    t_ = 0;
    return worst;
}

void Traj::interpolate() {
    float f = (float)t_ / (float)dur_;
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        float a = start_[j];
        sp[j] = a + (end_[j] - a) * f;
        vel[j] = (end_[j] - a) * scale_;
    }
}
