/* The control period against the main loop (link.h, "The period and the main loop"):
 * on the Mega the period is a timer interrupt that can come between any two of the main
 * loop's steps. Here it is called directly (Link::period()) where the interrupt could
 * come, and the main loop's side (Link::sync(), a command) after it: events reach the
 * host in order and only through the main loop, a DONE of a period before the main
 * loop's halt is dropped, a full event ring keeps the newest DONE, a watchdog the period
 * raises drives nothing until the main loop has latched it. */
#include <string.h>

#include "check.h"
#include "rig.h"

static uint8_t EE[EE_SIZE];

static void events_only_through_sync() {
    memset(EE, 0xFF, sizeof EE);
    Rig r(EE);
    r.hello(1);
    CHECK(r.cmd("W 0 20 10 10 10") == "OK 31");
    r.forget();
    for (int i = 0; i < 4; i++) r.board.link.period();   /* the timer, the main loop elsewhere */
    CHECK(r.board.link.done == -1 && !r.seen("EV DONE") && !r.seen("EV START"));
    r.board.link.sync();
    CHECK(r.board.link.done == 0 && r.seen("EV START 0") && r.seen("EV DONE 0 32"));
    /* START before DONE, as the period raised them */
    size_t s = 0, d = 0;
    for (size_t i = 0; i < r.log.size(); i++) {
        if (r.log[i].find(" START 0") != std::string::npos) s = i + 1;
        if (r.log[i].find(" DONE 0 ") != std::string::npos) d = i + 1;
    }
    CHECK(s && d && s < d);

    /* a period completes waypoint 1, then the main loop halts (a new session's hold)
       before its sync: that DONE is stale, never sent, and done stays */
    CHECK(r.cmd("W 1 20 10 10 10") == "OK 31");
    r.forget();
    for (int i = 0; i < 4; i++) r.board.link.period();
    r.board.hold_here();
    r.board.link.sync();
    CHECK(r.board.link.done == 0 && !r.seen("EV DONE 1"));
    CHECK(r.bad_lines == 0);
}

static void a_full_ring_keeps_the_newest_done() {
    memset(EE, 0xFF, sizeof EE);
    Rig r(EE);
    r.hello(1);
    for (int i = 0; i < 24; i++) CHECK(r.cmd("W " + std::to_string(100 + i) + " 10 10 10 10").compare(0, 3, "OK ") == 0);
    r.forget();
    for (int i = 0; i < 30; i++) r.board.link.period();   /* a DONE a period: more than the ring */
    r.board.link.sync();
    CHECK(r.board.link.done == 123 && r.seen("EV DONE 123 32"));
    CHECK(r.board.link.state == ST_IDLE);
}

static void a_watchdog_from_the_period() {
    memset(EE, 0xFF, sizeof EE);
    Rig r(EE);
    r.hello(1);
    CHECK(r.cmd("WDOG 500") == "OK 32");
    CHECK(r.cmd("W 0 5000 400 800 900") == "OK 31");
    r.run_live(1000);
    CHECK_MSG(r.board.link.state == ST_RUN && (r.hal.duty[0] || r.hal.duty[1] || r.hal.duty[2]), "state %d duty %d %d %d",
              r.board.link.state, r.hal.duty[0], r.hal.duty[1], r.hal.duty[2]);
    r.hal.t_us += 600000;                                /* the host went quiet */
    r.board.link.period();                               /* the period trips it ... */
    CHECK(r.hal.duty[0] == 0 && r.hal.duty[1] == 0 && r.hal.duty[2] == 0);
    CHECK_MSG(r.board.link.state == ST_RUN && EE[EE_LATCH] != 0xC4, "state %d cell %x", r.board.link.state,
              EE[EE_LATCH]);   /* ... the main loop latches */
    r.board.link.period();                               /* and drives nothing meanwhile */
    CHECK(r.hal.duty[0] == 0 && r.hal.duty[1] == 0 && r.hal.duty[2] == 0 && !r.board.busy());
    CHECK(r.cmd("W 1 100 0 0 0").find(" 9 LATCHED") != std::string::npos);
    CHECK(r.board.link.state == ST_WDOG && r.seen("EV WDOG") && EE[EE_LATCH] == 0xC4);
    CHECK(r.cmd("CLR") == "OK 32" && r.board.link.state == ST_IDLE);
}

void run_period() {
    events_only_through_sync();
    a_full_ring_keeps_the_newest_done();
    a_watchdog_from_the_period();
}
