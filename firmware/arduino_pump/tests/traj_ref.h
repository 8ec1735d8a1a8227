/* The trajectory generator as it was before Traj::plan lost its per-joint float division
 * (traj.cpp at c7769fd, renamed RefTraj, header-only): tests/test_board.cpp runs it beside
 * Traj on the same random inputs and requires the same set points, velocities and events,
 * bit for bit. Do not "fix" it: it is the reference. */
#ifndef PUMP_TEST_TRAJ_REF_H
#define PUMP_TEST_TRAJ_REF_H

#include "traj.h"

class RefTraj {
public:
    void init(const int32_t *vmax);
    bool push(uint16_t id, uint16_t dur, const int32_t *q);
    void set_range(uint8_t j, int32_t lo, int32_t hi, int32_t vmax);
    void flush();
    void set_point(const float *q);
    uint8_t step(uint16_t dt_ms, TrajEvent *ev);

    float sp[N_JOINTS];
    float vel[N_JOINTS];
    bool hold;
    int32_t active_id;
    int32_t lo[N_JOINTS], hi[N_JOINTS], vmax[N_JOINTS];

private:
    void begin(TrajEvent *ev, uint8_t *ne);
    int plan(uint32_t dur);
    void interpolate();
    void ramp(uint16_t dt_ms, TrajEvent *ev, uint8_t *ne);
    Waypoint queue_[QSIZE];
    uint8_t head_, count_;
    bool ramping_[N_JOINTS];
    int32_t targets_[N_JOINTS];
    float start_[N_JOINTS], end_[N_JOINTS];
    uint32_t dur_, t_;
    float scale_;
};

static inline void ref_add(TrajEvent *ev, uint8_t *ne, uint8_t kind, int32_t a, int32_t b) {
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

inline void RefTraj::init(const int32_t *vmax_) {
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        vmax[j] = vmax_[j];
        lo[j] = -(1L << 30);
        hi[j] = 1L << 30;
        ramping_[j] = false;
        sp[j] = 0.0f;
        vel[j] = 0.0f;
    }
    hold = false;
    head_ = count_ = 0;
    active_id = -1;
    dur_ = t_ = 0;
    scale_ = 1.0f;
}

inline bool RefTraj::push(uint16_t id, uint16_t dur, const int32_t *q) {
    if (count_ >= QSIZE) return false;
    Waypoint &w = queue_[(head_ + count_) % QSIZE];
    w.id = id;
    w.dur = dur;
    for (uint8_t j = 0; j < N_JOINTS; j++) w.q[j] = q[j];
    count_++;
    return true;
}

inline void RefTraj::set_range(uint8_t j, int32_t lo_, int32_t hi_, int32_t vmax_) {
    bool slower = vmax_ < vmax[j];
    lo[j] = lo_;
    hi[j] = hi_;
    vmax[j] = vmax_;
    if (slower && active_id >= 0) {   /* re-plan from where the set point is */
        for (uint8_t k = 0; k < N_JOINTS; k++) start_[k] = sp[k];
        plan(dur_ - t_);
    }
}

inline void RefTraj::flush() {
    count_ = 0;
    active_id = -1;
    for (uint8_t j = 0; j < N_JOINTS; j++) vel[j] = 0.0f;
}

inline void RefTraj::set_point(const float *q) {
    flush();
    for (uint8_t j = 0; j < N_JOINTS; j++) sp[j] = q[j];
}

inline uint8_t RefTraj::step(uint16_t dt_ms, TrajEvent *ev) {
    uint8_t ne = 0;
    if (hold) {
        for (uint8_t j = 0; j < N_JOINTS; j++) vel[j] = 0.0f;
        return 0;
    }
    if (active_id < 0 && count_ == 0) {
        ramp(dt_ms, ev, &ne);
        return ne;
    }
    uint32_t left = active_id < 0 ? 0 : dt_ms;
    for (;;) {
        if (active_id < 0) {
            if (count_ == 0) {
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
        ref_add(ev, &ne, TE_DONE, active_id, 0);
        active_id = -1;
        if (left == 0 && count_ == 0) break;
    }
    return ne;
}

inline void RefTraj::ramp(uint16_t dt_ms, TrajEvent *ev, uint8_t *ne) {
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
            ref_add(ev, ne, TE_LIMIT, j + 1, 0);
        }
        float reach = (float)vmax[j] * dt_ms / 1000.0f;
        float y;
        if (x < (float)lo[j]) y = (float)lo[j] - x <= reach ? (float)lo[j] : x + reach;
        else y = x - (float)hi[j] <= reach ? (float)hi[j] : x - reach;
        vel[j] = (y - x) * 1000.0f / dt_ms;
        sp[j] = y;
    }
}

inline void RefTraj::begin(TrajEvent *ev, uint8_t *ne) {
    const Waypoint &w = queue_[head_];
    head_ = (uint8_t)((head_ + 1) % QSIZE);
    count_--;
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        ramping_[j] = false;
        start_[j] = sp[j];
        end_[j] = (float)w.q[j];
        targets_[j] = w.q[j];
    }
    active_id = w.id;
    ref_add(ev, ne, TE_START, w.id, 0);
    int worst = plan(w.dur);
    if (worst >= 0) ref_add(ev, ne, TE_SLOW, w.id, worst + 1);
}

inline int RefTraj::plan(uint32_t dur) {
    int worst = -1;
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        float d = end_[j] - start_[j];
        if (d < 0) d = -d;
        float need = d * 1000.0f / (float)vmax[j];
        uint32_t need_ms = need < 4294967040.0f ? (uint32_t)need : 4294967040UL;   /* as traj.cpp: no UB */
        if ((float)need_ms < need) need_ms++;
        if (need_ms > dur) {
            dur = need_ms;
            worst = j;
        }
    }
    if (dur < 1) dur = 1;
    dur_ = dur;
    t_ = 0;
    scale_ = 1000.0f / (float)dur;
    for (uint8_t j = 0; j < N_JOINTS; j++) vel[j] = (end_[j] - start_[j]) * scale_;
    return worst;
}

inline void RefTraj::interpolate() {
    float f = (float)t_ / (float)dur_;
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        float a = start_[j];
        sp[j] = a + (end_[j] - a) * f;
        vel[j] = (end_[j] - a) * scale_;
    }
}

#endif
