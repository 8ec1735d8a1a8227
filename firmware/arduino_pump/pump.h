/* The syringe-pump board (the soft arm of the WJRRT paper, section V-B/C): its verbs
 * (W, GAIN, SETLIM, DBAND, BEND, MODBUS, IDENT, CALID), its control period (bend sensors ->
 * angles, the trajectory, one proportional controller per joint, end stops, the
 * syringe travel estimate, the following-error check) and its telemetry columns.
 * The protocol is link.cpp's; the chip is behind hal.h. Portable: the native tests
 * and the fuzzer run it over a fake HAL.
 *
 * Telemetry after `ms state done free`: q1..q3 (mrad), set points (mrad), duties
 * (per-mille, + inflates), syringe positions (per-mille of travel), end-stop bits
 * (bit 2k: pump k retracted, 2k+1: extended).
 *
 * The control period (control(), advance(), relay_step(), check_following()) runs in
 * the timer's interrupt on the Mega: the discipline of what it shares with the main
 * loop is listed in link.h. In short: q u syr_ stops seek fe_ms_ blocked_ and the
 * trajectory's consumer side are the period's (the main loop reads them under CtlLock
 * and resets them only in halt()/hold_here() under it); gain cal lim relay[] (its
 * start) and the trajectory's ranges are the main loop's (written under CtlLock).
 */
#ifndef PUMP_PUMP_H
#define PUMP_PUMP_H

#include <stdint.h>

#include "config.h"
#include "control.h"
#include "hal.h"
#include "link.h"
#include "traj.h"

struct RelayRun {             /* RELAY on one joint (firmware/common/relay.py in integers) */
    uint8_t on;
    int8_t out;               /* +1 / -1: the sign of the drive */
    uint8_t cycles, ups;      /* cycles to count; switches to + seen */
    int16_t amp;              /* per-mille */
    int32_t hyst;             /* mrad */
    uint32_t last_switch, first_up;   /* ms */
    int32_t hi, lo, sum_pp;   /* this cycle's extremes; peak-to-peak summed over counted cycles */
};

struct BendCal {              /* 12 bytes on the AVR and natively (EEPROM layout) */
    int32_t a;
    int32_t b;
    uint16_t adc_a;
    uint16_t adc_b;
};

class PumpBoard : public BoardIf {
public:
    void begin(Hal *hal);
    void poll() { link.poll(); }

    /* ---- BoardIf */
    uint8_t n_joints() { return N_JOINTS; }
    uint8_t qsize() { return QSIZE; }
    uint8_t free_slots() { return traj.free(); }
    bool busy();
    void halt();
    void hold_here();
    void set_hold(bool on) { traj.hold = on; }
    void control(uint8_t mode);
    void limits(uint8_t j, int32_t *m);
    int command(int verb, const int32_t *v, Payload *out, AbError *err);
    bool motion_verb(int verb);
    void telemetry(LineWriter *w);

    /* ---- shared with the Modbus accessors (pump_modbus.cpp) */
    int queue(uint16_t id, uint16_t dur, const int32_t *q, AbError *err);
    int setlim(uint8_t j, int32_t lo, int32_t hi, int32_t vmax);
    int set_bend(uint8_t j, const BendCal &c);
    void save_settings();
    void save_calibration(uint32_t id);   /* CALID: gains, bands and bends under id */
    int32_t syringe_permille(uint8_t j) const { return syr_[j] / 1000; }
    int32_t syringe_raw(uint8_t j) const { return syr_[j]; }   /* 1/1000 per-mille */
    Hal *hal() { return hal_; }

    Link link;
    Traj traj;
    PGain gain[N_JOINTS];
    Seek seek[N_JOINTS];                  /* each joint's settle (control.h) */
    RelayRun relay[N_JOINTS];             /* RELAY: the joint's drive while on */
    int32_t ki[N_JOINTS], kd[N_JOINTS];   /* accepted by GAIN and read back; not used */
    int32_t hard[N_JOINTS][3];            /* min max vmax: the firmware's own */
    int32_t lim[N_JOINTS][3];             /* now in force (SETLIM narrows) */
    BendCal cal[N_JOINTS];
    int32_t q[N_JOINTS];                  /* measured angles, mrad */
    int16_t u[N_JOINTS];                  /* duties, per-mille */
    uint8_t stops;                        /* end-stop bits */
    uint8_t modbus_addr;                  /* 0: line protocol */
    uint32_t cal_id;                      /* the calibration held (CALID; 0: none saved) */
    uint32_t serial;                      /* IDENT's uid: EEPROM, made once when erased */
    Waypoint last_wp;                     /* the newest queued waypoint (Modbus window reads) */
    /* Test hook: called with every completed waypoint (events coalesce them). */
    void (*on_done)(int32_t id);

private:
    void read_sensors();
    void halt_();
    void advance();
    void check_following();
    int16_t relay_step(uint8_t j, uint32_t now);
    void load_settings();
    void load_calibration();
    void load_serial();
    Hal *hal_;
    int32_t syr_[N_JOINTS];               /* syringe estimate, 1/1000 per-mille */
    uint8_t blocked_;                     /* bit k: pump k held at an end stop */
    uint16_t fe_ms_[N_JOINTS];
};

extern PumpBoard *g_pump;                 /* the board the Modbus accessors serve */

#endif
