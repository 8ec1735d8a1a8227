/* The control period and what it shares with the main loop (link.h: the discipline):
 * period() (the timer's interrupt on the Mega), the event ring from it to the main
 * loop, and sync(), the main loop's side. */
#include <string.h>

#include "config.h"
#include "link.h"

static bool latched(uint8_t st) { return st == ST_ESTOP || st == ST_WDOG || st == ST_FAULT; }

void Link::period_cb(void *self) { ((Link *)self)->period(); }

/* One control period: the watchdog, the board's control function (sensors, the
 * trajectory, the controllers, the pins). In the timer's interrupt on the Mega: it
 * reads only what the main loop writes under CtlLock or as single bytes, and raises
 * its events, DONE and latches through the ring (link.h). */
void Link::period() {
    in_tick_ = true;
    uint32_t now = hal_->ms();
    uint8_t st = pend_latch_ ? pend_latch_ : state;
    if ((st == ST_RUN || st == ST_HOLD) && (uint32_t)(now - last_ok_) >= (uint32_t)wdog_ms) {
        board_->halt();                      /* the period's own: no lock */
        pend_latch_ = ST_WDOG;
        pend_j_ = pend_detail_ = 0;
        strcpy(pend_why_, "-");
        push(K_LATCH, 0, 0, 0, 0);
        st = ST_WDOG;
    }
    if (!outputs_allowed || st == ST_ESTOP || st == ST_FAULT) {
        board_->control(CTL_OFF);
    } else if (st == ST_WDOG) {
        board_->control(CTL_ZERO);
    } else {
        board_->control(CTL_DRIVE);
    }
    period_ms_ = now;
    periods_ = (uint8_t)(periods_ + 1);
    in_tick_ = false;
}

/* The period's side of the ring; a full ring drops the event (counted), keeps a DONE
 * aside (the newest: those before it are done too), and a latch stays in pend_latch_. */
void Link::push(const char *kind, uint8_t nargs, int32_t a, int32_t b, int32_t c) {
    uint8_t h = ring_head_;
    if ((uint8_t)(h - ring_tail_) >= LINK_RING) {
        if (kind == K_DONE) {
            done_ovf_id_ = a;
            done_ovf_free_ = b;
            done_ovf_ = hgen_ | 0x80;
        } else if (ring_lost_ != 0xFF) {
            ring_lost_ = (uint8_t)(ring_lost_ + 1);
        }
        return;
    }
    CtlEvent &e = ring_[h & (LINK_RING - 1)];
    e.kind = kind;
    e.nargs = nargs;
    e.gen = hgen_;
    e.a = a;
    e.b = b;
    e.c = c;
    ring_head_ = (uint8_t)(h + 1);           /* volatile: after the entry */
}

/* The main loop's side: the periods' events in order (an event raised by a command
 * in the meantime was already sent after its reply), then the telemetry they pace. */
void Link::sync() {
    uint8_t n = (uint8_t)(periods_ - periods_seen_);   /* bytes: no lock */
    if (!n && ring_tail_ == ring_head_ && !done_ovf_ && !pend_latch_) return;
    periods_seen_ = (uint8_t)(periods_seen_ + n);
    while (ring_tail_ != ring_head_) {
        CtlEvent e = ring_[ring_tail_ & (LINK_RING - 1)];
        ring_tail_ = (uint8_t)(ring_tail_ + 1);   /* the slot is the period's again */
        take(e);
    }
    if (done_ovf_) {
        CtlEvent e;
        {
            CtlLock l(hal_);
            e.kind = K_DONE;
            e.gen = (uint8_t)(done_ovf_ & 0x7F);
            e.a = done_ovf_id_;
            e.b = done_ovf_free_;
            done_ovf_ = 0;
        }
        if ((uint8_t)(e.gen ^ hgen_) & 0x7F) e.gen = (uint8_t)(hgen_ + 1);   /* stale */
        else e.gen = hgen_;
        take(e);
    }
    if (pend_latch_) take_latch();           /* its ring entry was lost */
    if (!n) return;
    if (state == ST_RUN && !board_->busy()) state = ST_IDLE;
    uint32_t now;
    {
        CtlLock l(hal_);
        now = period_ms_;
    }
    telemetry(now, n);
}

void Link::take(const CtlEvent &e) {
    if (e.kind == K_LATCH) {
        take_latch();
        return;
    }
    if (e.gen != hgen_) return;               /* raised before the main loop's halt(): stale */
    if (e.kind == K_DONE) {
        done = e.a;
        save();                               /* before EV DONE goes out (docs/pump.md, EEPROM) */
        event("DONE", 2, e.a, e.b);
        return;
    }
    event(e.kind, e.nargs, e.a, e.b, e.c);
}

/* A latch the period raised (it halted and drives nothing since): the main loop's
 * part, as the period did it before it ran in an interrupt. Over a latch already in
 * force (an e-stop since) it only ends the period's hold: the first cause stays. */
void Link::take_latch() {
    uint8_t st;
    bool over;
    {
        CtlLock l(hal_);
        st = pend_latch_;
        pend_latch_ = 0;
        over = latched(state);
        if (st && !over) state = st;         /* with pend_latch_: the period never sees neither */
    }
    if (!st || over) return;
    board_->halt();
    if (st == ST_WDOG) {
        latch(ST_WDOG, "-");
        event("WDOG", 0);
    } else {
        latch(ST_FAULT, pend_why_);
        event("FAULT", 2, pend_j_, pend_detail_);
    }
}

void Link::feed() {
    uint32_t t = hal_->ms();
    CtlLock l(hal_);
    last_ok_ = t;
}

void Link::set_wdog(int32_t ms) {
    CtlLock l(hal_);
    wdog_ms = ms;
}
