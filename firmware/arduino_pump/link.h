/* The link layer of the pump board: firmware/common/link.py in C++.
 *
 * What every armbridge board does for the protocol, whatever it drives: the line
 * reader and the e-stop byte, decode with the link epoch, the session rules, the
 * common verbs (HELLO LIM HOLD RESUME CLR RATE WDOG STAT PING), the states and
 * their latches persisted in EEPROM (two slots with a CRC), the watchdog fed only
 * by lines answered OK, telemetry pacing, events sent after the reply of the command
 * that caused them, the control period (period(): a Timer5 interrupt on the Mega,
 * scheduled from us() in poll() over the native tests' fake HAL), and the switch to
 * Modbus RTU (after the OK of MODBUS, and back on the Modbus command register).
 *
 * The period and the main loop (docs/pump.md, "The control period on a timer"). The
 * period preempts the main loop at any instruction (never the reverse: the main loop
 * runs only when no period is on the stack), so:
 *   - what the period writes and the main loop reads as more than one byte is read
 *     under CtlLock (hal.h: masks the period's interrupt only): PumpBoard q u syr_
 *     stops traj.sp/vel/active_id (busy(), telemetry, Modbus inputs, RELAY), period_ms_;
 *   - what the main loop writes and the period reads as more than one byte is written
 *     under CtlLock: last_ok_, wdog_ms, PumpBoard gain cal (GAIN DBAND BEND, Modbus),
 *     traj ranges (SETLIM), relay[] (RELAY), and everything halt()/hold_here() reset;
 *   - single bytes the main loop alone writes: state, outputs_allowed, traj.hold;
 *   - the waypoint queue is a single-producer (the main loop: push, tail) single-
 *     consumer (the period: step, head) ring; flush() and set_point() under CtlLock;
 *   - what the period raises (events, DONE, a WDOG or FAULT latch) goes through the
 *     event ring below (producer: the period, head; consumer: sync() in the main
 *     loop, tail), in order; a latch the period raises is also held in pend_latch_
 *     (the period drives nothing while it is set) until sync() latches it in the
 *     main loop (EEPROM, record, EV), under CtlLock with the state;
 *   - events of a period that ran before the main loop's halt() (a latch, CLR, a new
 *     session) are dropped (their generation is older), latches never.
 * The period never touches the UART, the line writer, the session or the EEPROM.
 *
 * Rules kept here:
 *   after any boot the outputs stay off until a HELLO is accepted, and while a
 *   latch the board booted with holds, until CLR; ESTOP, WDOG and FAULT latch,
 *   survive a reset and refuse motion; only CLR releases them, never a HELLO; the
 *   watchdog (RUN/HOLD only) is fed only by lines answered OK.
 */
#ifndef PUMP_LINK_H
#define PUMP_LINK_H

#include <stdint.h>

#include "hal.h"
#include "proto.h"
#include "session.h"

enum { ST_IDLE = 0, ST_RUN, ST_HOLD, ST_ESTOP, ST_WDOG, ST_FAULT };
enum { CTL_OFF = 0, CTL_ZERO, CTL_DRIVE };   /* BoardIf::control(mode) */

extern const char *const STATE_NAMES[6];
extern const char K_DONE[], K_LATCH[];   /* the event ring's own kinds (link_period.cpp) */

/* A short text the board's verbs answer after `OK seq free` (LIM's payload). */
class Payload {
public:
    Payload() : len(0) { buf[0] = 0; }
    void str(const char *s);
    void num(int32_t v);
    char buf[64];
    uint8_t len;
};

/* What the link needs from the board it serves (pump.cpp). */
class BoardIf {
public:
    virtual uint8_t n_joints() = 0;
    virtual uint8_t qsize() = 0;
    virtual uint8_t free_slots() = 0;
    virtual bool busy() = 0;
    virtual void halt() = 0;                 /* drop all motion; the set point stays */
    virtual void hold_here() = 0;            /* halt, set point := measured, loops reset */
    virtual void set_hold(bool on) = 0;
    virtual void control(uint8_t mode) = 0;  /* one period: CTL_OFF / CTL_ZERO / CTL_DRIVE */
    virtual void limits(uint8_t j, int32_t *min_max_vmax) = 0;   /* j 1-based */
    /* The board's own verb (index in AB_COMMANDS, arguments checked): -> 0 (OK),
     * an error code (err->detail set), or AB_ERR_VERB when it has no such verb. */
    virtual int command(int verb, const int32_t *v, Payload *out, AbError *err) = 0;
    virtual bool motion_verb(int verb) = 0;  /* refused LATCHED while latched */
    virtual void telemetry(LineWriter *w) = 0;   /* the 3n columns, then its own */
};

#define LINK_MAX_EVENTS 12   /* a command's or a control period's: START SLOW DONE, LIMIT and ENDSTOP per joint */
#define LINK_REASON_MAX 9
#define LINK_RING 16         /* events raised by the control periods not yet sent (power of 2) */

class Link {
public:
    void begin(Hal *hal, BoardIf *board, uint8_t modbus_addr);   /* 0: line protocol */
    void poll();                             /* one pass of the main loop */
    void period();                           /* one control period (the timer's interrupt) */
    void sync();                             /* main loop: what the periods raised */
    void estop();
    bool in_period() const { return in_tick_; }
    void halted() { hgen_++; }               /* main loop, under CtlLock: older events are stale */

    /* ---- board callbacks */
    uint32_t board_ms();
    void event(const char *kind, uint8_t nargs, int32_t a = 0, int32_t b = 0, int32_t c = 0);
    void completed(int32_t wid);
    void fault(int32_t j, int32_t detail, const char *reason);
    void save();
    /* ---- Modbus (pump_modbus.cpp) */
    void switch_to_modbus(uint8_t addr);    /* after the current reply is sent */
    void switch_to_line();                  /* after the current Modbus reply */
    bool modbus() const { return modbus_; }
    void latch_estop_cmd() { estop(); }
    void set_wdog(int32_t ms);
    void hold_cmd(bool on);
    void feed();                             /* a line or frame answered OK: the watchdog */
    void clear_cmd();

    uint8_t state;
    int32_t done;            /* id of the last completed waypoint, -1 none */
    int32_t queued;          /* id of the last accepted move, -1 none */
    int32_t rate;
    int32_t wdog_ms;
    bool outputs_allowed;
    char reason[LINK_REASON_MAX];
    Session sess;

private:
    void on_line(const uint8_t *raw, size_t n, bool tail);   /* tail: see next_byte() */
    int next_byte();
    uint8_t execute(uint16_t seq, int verb, const AbLine &l, Payload *p, AbError *err);
    uint8_t hello(uint16_t seq, const AbLine &l, Payload *p, AbError *err);
    void reply(uint16_t seq, uint8_t code, uint8_t free, const char *detail, const Payload *p);
    void send_er(int32_t seq, uint8_t code, const char *detail);
    void latch(uint8_t st, const char *why);
    void telemetry(uint32_t now, uint8_t periods);
    struct CtlEvent { const char *kind; uint8_t nargs, gen; int32_t a, b, c; };
    void push(const char *kind, uint8_t nargs, int32_t a, int32_t b, int32_t c);
    void take(const CtlEvent &e);
    void take_latch();
    static void period_cb(void *self);
    void send(LineWriter *w);
    void flush_events();
    void load();
    void load_latch_cell();
    void modbus_pass();

    Hal *hal_;
    BoardIf *board_;
    LineReader reader_;
    LineWriter w_;
    uint32_t last_ok_;
    uint32_t next_tick_us_;  /* without a timer (the fake HAL): the next period's us() */
    int32_t telem_acc_;
    bool in_command_;
    volatile bool in_tick_;  /* inside period(): events go to the ring */
    bool timer_;             /* the HAL's timer runs period() */
    /* period -> main loop (see the top of this file) */
    CtlEvent ring_[LINK_RING];
    volatile uint8_t ring_head_, ring_tail_, ring_lost_;
    volatile uint8_t periods_;              /* periods run (wraps; a byte: read without a lock) */
    uint8_t periods_seen_;
    uint32_t period_ms_;     /* ms() at the newest period (under CtlLock) */
    volatile uint8_t hgen_;
    volatile uint8_t pend_latch_;            /* ST_WDOG / ST_FAULT raised by the period, 0 none */
    int32_t pend_j_, pend_detail_;
    char pend_why_[LINK_REASON_MAX];
    volatile uint8_t done_ovf_;              /* a DONE the full ring could not take */
    int32_t done_ovf_id_, done_ovf_free_;
    uint8_t n_events_;
    struct { const char *kind; uint8_t nargs; int32_t a, b, c; } events_[LINK_MAX_EVENTS];
    uint8_t gen_;            /* persist slot generation */
    bool modbus_;
    int16_t pending_mode_;   /* -1 none, 0 line, 1..247 Modbus address */
    uint32_t mb_frames_, mb_exceptions_;
    /* The first line since boot (link.cpp, next_byte()): its first byte not yet come,
     * come by JOIN_US after begin() (the line may be a tail), or neither. */
    enum { JOIN_WAIT, JOIN_TAIL, JOIN_DONE };
    uint8_t join_;
    uint32_t boot_us_;
};

#endif
