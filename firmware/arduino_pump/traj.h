/* Waypoint queue and set-point generator, as firmware/common/traj.py (without its
 * pen dwell/aux): each waypoint is a straight segment from where the previous one
 * ended (or from the set point at rest) to its targets, stretched in time when a
 * joint would exceed its vmax (event SLOW): the set point never jumps. step(dt)
 * advances segment time; a segment that ends mid-step hands its leftover to the
 * next. A segment taken up from rest starts at the step that takes it up. While
 * `hold` is set time is frozen. At rest a set point outside its joint's range moves
 * into it at vmax (event LIMIT when that starts). Positions in mrad (float: the
 * AVR's 32-bit float, as ESP32 MicroPython's), durations in ms.
 */
#ifndef PUMP_TRAJ_H
#define PUMP_TRAJ_H

#include <stdint.h>

#include "config.h"

enum { TE_START = 1, TE_SLOW, TE_DONE, TE_LIMIT };

struct TrajEvent {
    uint8_t kind;            /* TE_* */
    int32_t a;               /* START/SLOW/DONE: waypoint id; LIMIT: joint (1-based) */
    int32_t b;               /* SLOW: joint (1-based) */
};

#define TRAJ_MAX_EVENTS 8

struct Waypoint {
    uint16_t id;
    uint16_t dur;
    int32_t q[N_JOINTS];
};

class Traj {
public:
    void init(const int32_t *vmax);
    /* The queue is a single-producer single-consumer ring (pump.h): push() (the main
     * loop) alone moves tail_, step() (the control period) alone moves head_, each a
     * free-running byte; flush() and set_point() are called with the period locked out. */
    uint8_t free() const { return (uint8_t)(QSIZE - count()); }
    uint8_t queued() const { return count(); }
    bool busy() const { return active_id >= 0 || count() > 0; }
    bool push(uint16_t id, uint16_t dur, const int32_t *q);
    void set_range(uint8_t j, int32_t lo, int32_t hi, int32_t vmax);
    bool excludes(uint8_t j, int32_t lo, int32_t hi) const;
    void flush();
    void set_point(const float *q);
    /* The end of the last queued segment (or the active one, or the set point). */
    void last_target(float *q) const;
    /* Advances by dt_ms -> number of events written to ev (at most TRAJ_MAX_EVENTS;
     * DONEs beyond that are folded into the last one). */
    uint8_t step(uint16_t dt_ms, TrajEvent *ev);

    float sp[N_JOINTS];      /* set point */
    float vel[N_JOINTS];     /* set-point velocity (mrad/s) */
    bool hold;
    int32_t active_id;       /* -1: none */
    int32_t lo[N_JOINTS], hi[N_JOINTS], vmax[N_JOINTS];

private:
    void begin(TrajEvent *ev, uint8_t *ne);
    int plan(uint32_t dur);
    void interpolate();
    void ramp(uint16_t dt_ms, TrajEvent *ev, uint8_t *ne);
    uint8_t count() const { return (uint8_t)(tail_ - head_); }
    Waypoint queue_[QSIZE];
    volatile uint8_t head_, tail_;
    bool ramping_[N_JOINTS];
    int32_t targets_[N_JOINTS];
    float start_[N_JOINTS], end_[N_JOINTS];
    uint32_t dur_, t_;
    float scale_;
};

#endif
