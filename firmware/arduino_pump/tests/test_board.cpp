/* The board's logic natively over the fake HAL: boot and HELLO, waypoints to DONE,
 * the e-stop within one period, the watchdog, latches and settings across a reset
 * through the fake EEPROM, bad commands answered while the board keeps answering,
 * end stops, the dead band and the asymmetry, retransmits, SETLIM, FAULT, Modbus. */
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "control.h"
#include "modbus.h"
#include "rig.h"
#include "traj_ref.h"

static uint8_t EE[EE_SIZE];

static void fresh_eeprom() { memset(EE, 0xFF, sizeof EE); }

static bool within(int32_t a, int32_t b, int32_t tol) { return a - b <= tol && b - a <= tol; }

static void boot_and_hello() {
    fresh_eeprom();
    Rig r(EE);
    CHECK(r.hal.tx.compare(0, strlen("\n"), "\n") == 0);
    CHECK(r.seen("BOOT arduino_pump 0.1.0 2 IDLE"));
    CHECK(r.cmd("PING").compare(0, strlen("OK "), "OK ") == 0);             /* read-only: no session needed */
    CHECK(r.cmd("W 0 100 0 0 0") == "ER 10 NOSESSION");
    r.seq = 1;
    CHECK(r.hello(1) == "OK 32 arduino_pump 0.1.0 2 3 32 25 1000 - - IDLE");
    CHECK(r.cmd("LIM 1") == "OK 32 1 0 524 500");
    CHECK(r.cmd("LIM 3") == "OK 32 3 0 1047 500");
    CHECK(r.cmd("LIM 4") == "ER 6 RANGE joint");
    CHECK(r.hal.off_calls >= 1 && r.bad_lines == 0);
}

static std::vector<int32_t> done_ids;
static void on_done(int32_t id) { done_ids.push_back(id); }

static void waypoints_to_done() {
    fresh_eeprom();
    Rig r(EE);
    r.board.on_done = on_done;
    done_ids.clear();
    r.hello(1);
    CHECK(r.cmd("W 0 1500 300 500 600") == "OK 31");
    CHECK(r.cmd("W 1 1500 150 300 400") == "OK 30");
    r.run(200);
    CHECK(r.seen("EV START 0") && r.board.link.state == ST_RUN);
    r.run_live(5000);
    CHECK(r.seen("EV DONE 1 32") && r.board.link.done == 1 && done_ids.size() == 2 && done_ids[1] == 1);
    /* settled: every joint inside its dead band of the last target */
    int32_t want[3] = {150, 300, 400};
    for (int j = 0; j < 3; j++)
        CHECK_MSG(within(r.board.q[j], want[j], DBAND_DEFAULT_MRAD), "joint %d at %d", j + 1, r.board.q[j]);
    CHECK(r.board.link.state == ST_IDLE);
    CHECK(r.cmd("STAT").compare(0, strlen("OK 32 IDLE 1 1"), "OK 32 IDLE 1 1") == 0);
    /* a waypoint outside the limits, and a full queue */
    CHECK(r.cmd("W 2 100 600 0 0") == "ER 6 RANGE 1");
    CHECK(r.cmd("HOLD") == "OK 32");
    for (int i = 0; i < 32; i++) r.cmd("W " + std::to_string(10 + i) + " 100 100 100 100");
    CHECK(r.cmd("W 99 100 100 100 100") == "ER 8 FULL");
    CHECK(r.bad_lines == 0);
}

static void estop_within_one_period() {
    fresh_eeprom();
    Rig r(EE);
    r.hello(1);
    r.cmd("W 0 3000 500 900 1000");
    r.run(300);
    CHECK(r.hal.duty[0] != 0 || r.hal.duty[1] != 0);
    r.forget();
    r.hal.push("\x98");
    /* the receive path: motors off before the board's next pass */
    CHECK(r.hal.duty[0] == 0 && r.hal.duty[1] == 0 && r.hal.duty[2] == 0);
    r.run(PERIOD_MS);   /* within one control period: latched and reported */
    CHECK(r.board.link.state == ST_ESTOP && r.seen("EV ESTOP"));
    r.run(100);
    CHECK(r.hal.duty[0] == 0 && r.hal.duty[1] == 0 && r.hal.duty[2] == 0);
    CHECK(r.cmd("W 1 100 0 0 0") == "ER 9 LATCHED");
    CHECK(r.cmd("STAT").compare(0, strlen("OK 32 ESTOP"), "OK 32 ESTOP") == 0);
    CHECK(r.cmd("CLR") == "OK 32" && r.board.link.state == ST_IDLE && r.seen("EV CLEAR"));
    /* mid-line: the rest of that line is dropped silently, the next one runs */
    r.hal.push("6 PI\x98NG*00000000\n");
    r.run(5);
    CHECK(r.board.link.state == ST_ESTOP);
    CHECK(r.cmd("CLR") == "OK 32");
}

static void watchdog() {
    fresh_eeprom();
    Rig r(EE);
    r.hello(1);
    CHECK(r.cmd("WDOG 200") == "OK 32");
    r.cmd("W 0 5000 300 300 300");
    for (int i = 0; i < 10; i++) {   /* PINGs (answered OK) keep it fed */
        r.run(100);
        r.cmd("PING");
    }
    CHECK(r.board.link.state == ST_RUN);
    for (int i = 0; i < 5; i++) {    /* lines answered ER never feed it */
        r.hal.push("99 PING*00000000\n");
        r.run(60);
    }
    CHECK(r.board.link.state == ST_WDOG && r.seen("EV WDOG"));
    CHECK(r.hal.duty[0] == 0 && r.hal.duty[1] == 0 && r.hal.duty[2] == 0);
    CHECK(r.cmd("W 1 100 0 0 0").find(" 9 LATCHED") != std::string::npos);
}

static void latches_across_reset() {
    fresh_eeprom();
    {
        Rig r(EE);
        r.hello(1, 77);
        r.cmd("W 5 500 100 100 100");
        r.run_live(3000);
        CHECK(r.board.link.done == 5);
        r.hal.push("\x98");
        r.run(10);
        CHECK(r.board.link.state == ST_ESTOP);
        CHECK(r.cmd("BEND 2 100 -50 900 1500") == "OK 32");
    }
    Rig r(EE);   /* the reset: a new board over the same EEPROM */
    CHECK(r.seen("BOOT arduino_pump 0.1.0 2 ESTOP"));
    CHECK(r.board.cal[1].adc_a == 100 && r.board.cal[1].a == -50 && r.board.cal[1].b == 1500);
    r.run(1);   /* a line that starts a while after the boot is no tail (link.cpp next_byte) */
    CHECK(r.cmd("W 6 100 0 0 0") == "" && r.seen("ER - 2 CRC"));   /* checked with the persisted epoch */
    r.epoch = 1;
    CHECK(r.cmd("W 6 100 0 0 0") == "ER 10 NOSESSION");
    r.seq = 9;
    CHECK(r.hello(1, 77) == "ER 11 STALE 1");      /* the epoch survived */
    CHECK(r.hello(2, 77) == "OK 32 arduino_pump 0.1.0 2 3 32 25 1000 5 - ESTOP");   /* done and latch too */
    r.run(100);
    CHECK(r.hal.duty[0] == 0 && !r.board.link.outputs_allowed);
    CHECK(r.cmd("CLR") == "OK 32" && r.board.link.outputs_allowed);
    /* a torn record falls back to the other slot; both torn reads as power on */
    EE[EE_LINK_A + 5] ^= 0xFF;
    EE[EE_LINK_B + 5] ^= 0xFF;
    Rig p(EE);
    CHECK(p.seen("BOOT arduino_pump 0.1.0 2 IDLE") && p.board.link.sess.epoch == 0);
}

/* A reset before the latch record is programmed (on the Mega the 32-byte record takes
 * ~110 ms behind the loop, the latch cell 3.4 ms, written at once): the record slots
 * still hold the state from before the e-stop, the cell says ESTOP: the board boots
 * ESTOP. A CLR writes the cell released first; a reset before its record still boots
 * latched (only CLR releases, and CLR again is safe). */
static void latch_cell_wins_over_an_older_record() {
    fresh_eeprom();
    uint8_t before[EE_SIZE];
    {
        Rig r(EE);
        r.hello(1, 77);
        r.cmd("W 5 5000 100 100 100");
        r.run_live(200);
        memcpy(before, EE, sizeof before);
        r.hal.push("\x98");
        r.run(10);
        CHECK(r.board.link.state == ST_ESTOP && EE[EE_LATCH] == 0xC3);
    }
    memcpy(EE, before, EE_LATCH);   /* the record slots (and settings) as before the e-stop */
    {
        Rig r(EE);
        CHECK(r.seen("BOOT arduino_pump 0.1.0 2 ESTOP") && r.board.link.state == ST_ESTOP);
        r.seq = 9;
        std::string ok = r.hello(2, 77);
        CHECK_MSG(ok.size() > 5 && ok.compare(ok.size() - 5, 5, "ESTOP") == 0, "%s", ok.c_str());
        CHECK(r.cmd("W 6 100 0 0 0") == "ER 9 LATCHED");
        memcpy(before, EE, sizeof before);
        CHECK(r.cmd("CLR") == "OK 32" && EE[EE_LATCH] == 0xC0);
    }
    memcpy(EE, before, EE_LATCH);   /* CLR's record lost: the old one says ESTOP */
    Rig r(EE);
    CHECK(r.seen("BOOT arduino_pump 0.1.0 2 ESTOP"));
}

/* The live link record sits in .noinit SRAM, written at once; the EEPROM copy lags
 * behind (a byte per pass on the Mega: under a stream of DONEs a slot never
 * finishes). A reset keeps SRAM: HELLO's done is the last DONE reported. A power
 * cycle clears it (noise): the EEPROM copy is read. */
static void done_across_reset_from_noinit() {
    fresh_eeprom();
    uint8_t ram[KEEP_SIZE];
    memset(ram, 0, sizeof ram);
    uint8_t before[EE_SIZE];
    {
        Rig r(EE, ram);
        r.hello(1, 77);
        r.run_live(50);
        memcpy(before, EE, sizeof before);   /* the EEPROM as of the HELLO: done none */
        for (int i = 5; i < 9; i++) r.cmd("W " + std::to_string(i) + " 40 100 100 100");
        r.run_live(1000);
        CHECK(r.board.link.done == 8 && r.seen("EV DONE 8"));
    }
    memcpy(EE, before, sizeof EE);   /* no EEPROM slot finished since the HELLO */
    {
        Rig r(EE, ram);   /* the reset: SRAM kept */
        r.seq = 20;
        std::string ok = r.hello(2, 77);
        CHECK_MSG(ok.find(" 1000 8 - IDLE") != std::string::npos, "%s", ok.c_str());
    }
    memcpy(EE, before, sizeof EE);
    Rig p(EE);   /* a power cycle: .noinit is noise, the EEPROM copy wins */
    p.seq = 20;
    std::string ok = p.hello(2, 77);
    CHECK_MSG(ok.find(" 1000 - - IDLE") != std::string::npos, "%s", ok.c_str());
}

/* The receiver comes up while a HELLO is on the wire (the host never waits for BOOT):
 * the board gets its tail at once and drops it silently; a whole line that arrives at
 * once runs; a damaged first line that starts later is answered ER as every line. */
static void a_tail_at_boot_is_dropped_silently() {
    fresh_eeprom();
    {
        Rig r(EE);
        std::string hello = r.frame("1 HELLO 2 4242 1", 0);
        r.hal.push(hello.substr(9));
        r.run(5);
        CHECK(r.lines().size() == 1 && !r.seen("ER"));   /* BOOT, and no answer */
        r.seq = 1;
        CHECK(r.hello(1) == "OK 32 arduino_pump 0.1.0 2 3 32 25 1000 - - IDLE");
        CHECK(r.cmd("PING").compare(0, strlen("OK 32"), "OK 32") == 0 && !r.seen("ER") && r.bad_lines == 0);
    }
    fresh_eeprom();
    {
        Rig r(EE);   /* a whole line at once is no tail: it runs */
        CHECK(r.hello(1) == "OK 32 arduino_pump 0.1.0 2 3 32 25 1000 - - IDLE");
    }
    fresh_eeprom();
    {
        Rig r(EE);   /* only the first line: a bad second line is answered */
        r.hal.push("LLO 2 1 1*00000000\n");
        r.hal.push("garbage\n");
        r.run(5);
        CHECK(r.seen("ER - 1 PARSE") && !r.seen("ER - 2 CRC"));
    }
    fresh_eeprom();
    {
        Rig r(EE);   /* a damaged line that starts after two byte times: answered */
        r.run(1);
        r.hal.push("LLO 2 1 1*00000000\n");
        r.run(5);
        CHECK(r.seen("ER - 2 CRC"));
    }
}

static void bad_commands_keep_answering() {
    fresh_eeprom();
    Rig r(EE);
    r.hello(1);
    r.forget();
    r.hal.push("garbage\n");
    r.hal.push(std::string(200, 'x') + "\n");
    r.hal.push("\n");
    r.hal.push(r.frame("2 PING", 7));   /* another epoch: CRC */
    r.run(5);
    CHECK(r.seen("ER - 1 PARSE") && r.seen("ER - 3 LONG") && r.seen("ER - 2 CRC"));
    CHECK(r.cmd("JUMP 1") == "ER 4 VERB");
    CHECK(r.cmd("X 1 100 0 0 0") == "ER 4 VERB");          /* the arm's verb: not this board's */
    CHECK(r.cmd("RATE 01") == "ER 5 ARGS");
    CHECK(r.cmd("RATE 101") == "ER 6 RANGE hz");
    CHECK(r.cmd("SETLIM 1 0 600 500") == "ER 6 RANGE 1");   /* past the hard limit */
    CHECK(r.cmd("BEND 1 100 5 100 9") == "ER 6 RANGE 1");   /* adc_a == adc_b */
    CHECK(r.cmd("HELLO 3 1 1") == "ER 12 PROTO 2");   /* a HELLO is not recorded: expect stays 8 */
    r.seq = 20;
    CHECK(r.cmd("PING") == "ER 7 SEQ 8");
    r.seq = 8;
    CHECK(r.cmd("PING").compare(0, strlen("OK 32 "), "OK 32 ") == 0 && r.bad_lines == 0);
}

static void replay_executes_once() {
    fresh_eeprom();
    Rig r(EE);
    r.hello(1);
    std::string w = r.frame("2 W 0 2000 100 100 100", 1);
    r.hal.push(w);
    r.run(3);
    r.hal.push(w);   /* the retransmit */
    r.run(3);
    r.seq = 3;
    r.lines();
    CHECK(r.board.traj.queued() + (r.board.traj.active_id >= 0) == 1);
    int oks = 0;
    for (size_t i = 0; i < r.log.size(); i++) oks += r.log[i].find(" OK 2 31") != std::string::npos;
    CHECK(oks == 2);
}

static void end_stop_stops_that_pump() {
    fresh_eeprom();
    Rig r(EE);
    r.hello(1);
    r.hal.force_stop[0] = 2;   /* pump 1 at its extended stop */
    r.cmd("W 0 1000 400 400 400");
    r.run(500);
    CHECK(r.hal.duty[0] == 0 && r.seen("EV ENDSTOP 1"));
    CHECK(r.hal.duty[1] > 0 && r.hal.duty[2] > 0);       /* the others pump on */
    CHECK(r.board.stops & 2);
    r.run_live(3000);   /* joint 1 cannot follow: following error latches FAULT */
    CHECK(r.board.link.state == ST_FAULT && r.seen("EV FAULT 1"));
    CHECK(r.cmd("STAT").find("FAULT") != std::string::npos && r.cmd("STAT").find("FOLLOW:1") != std::string::npos);
}

static void dead_band_and_asymmetry() {
    PGain g;
    g.kp = 4000;
    g.dband = 70;
    CHECK(p_control(g, 0) == 0 && p_control(g, 70) == 0 && p_control(g, -70) == 0);
    CHECK(p_control(g, 71) >= DUTY_MIN && p_control(g, -71) <= -DUTY_MIN);
    CHECK(p_control(g, 200) == 480 && p_control(g, -200) == -800);    /* inflation at 0.6 x kp */
    CHECK(p_control(g, 100000) == DUTY_MAX_INFLATE && p_control(g, -100000) == -DUTY_MAX_DEFLATE);
    /* the 32-bit arithmetic is the 64-bit reference's, over GAIN's whole kp range */
    static const int32_t kps[] = {1, 2, 7, 999, 4000, 33333, 250000, 999999, 1000000};
    int bad = 0;
    for (size_t i = 0; i < sizeof kps / sizeof kps[0]; i++) {
        g.kp = kps[i];
        for (int32_t e = -2100000; e <= 2100000; e += (e > -3000 && e < 3000) ? 1 : 997) {
            int32_t mag = e < 0 ? -e : e, kp = e > 0 ? (int32_t)((int64_t)g.kp * KP_INFLATE_PERMILLE / 1000) : g.kp;
            int64_t u = (int64_t)kp * mag / 1000, cap = e > 0 ? DUTY_MAX_INFLATE : DUTY_MAX_DEFLATE;
            if (u > cap) u = cap;
            if (u < DUTY_MIN) u = DUTY_MIN;
            int32_t want = mag <= g.dband ? 0 : (int32_t)(e > 0 ? u : -u);
            if (p_control(g, e) != want && bad++ < 5) fprintf(stderr, "kp %d e %d: %d, want %d\n", kps[i], e, p_control(g, e), want);
        }
    }
    CHECK(bad == 0);
    g.kp = 0;
    CHECK(p_control(g, 500) == 0);
    /* on the board: settled (within the fine band, then the re-seek band) the pumps are off
     * (this rig's plant is slow: 0.24 rad/s at full duty, so the P law's approach takes
     * seconds; the pneumatic plant's is about twice as fast) */
    fresh_eeprom();
    Rig r(EE);
    r.hello(1);
    r.cmd("W 0 1000 300 300 300");
    r.run_live(6000);
    for (int j = 0; j < 3; j++)
        CHECK(r.hal.duty[j] == 0 && !r.board.seek[j].seeking && within(r.board.q[j], 300, SETTLE_RESEEK_MRAD));
    CHECK(r.cmd("DBAND 2 10") == "OK 32");
    r.run_live(2000);
    CHECK(within(r.board.q[1], 300, 10));
    CHECK(r.cmd("GAIN 1 0 0 0") == "OK 32");
    r.cmd("W 1 500 500 300 300");
    r.run(500);
    CHECK(r.hal.duty[0] == 0);   /* kp 0: joint 1 undriven */
}

/* The settle (control.h seek_control): hysteresis between the fine and the re-seek band,
 * the ramp inside the dead band and its reset, a sign change ends a seek, DBAND caps both. */
static void settle_with_hysteresis_and_ramp() {
    PGain g;
    g.kp = 4000;
    g.dband = 70;
    Seek s;
    seek_reset(s);
    CHECK(seek_control(s, g, SETTLE_RESEEK_MRAD) == 0 && !s.seeking);        /* resting: the re-seek band */
    CHECK(seek_control(s, g, -SETTLE_RESEEK_MRAD) == 0 && !s.seeking);
    int16_t u0 = seek_control(s, g, SETTLE_RESEEK_MRAD + 1);                 /* past it: seeks, inflating */
    CHECK(s.seeking && s.dir == 1 && u0 >= DUTY_MIN);
    int16_t u1 = seek_control(s, g, SETTLE_RESEEK_MRAD);                     /* seeking: on inside the re-seek band */
    CHECK(u1 > 0 && s.ramp == 2 * SEEK_RAMP_PERMILLE);
    for (int i = 0; i < 1000; i++) seek_control(s, g, SETTLE_FINE_MRAD + 1);
    CHECK(s.ramp == SEEK_RAMP_MAX && seek_control(s, g, SETTLE_FINE_MRAD + 1) == DUTY_MIN + SEEK_RAMP_MAX);
    CHECK(seek_control(s, g, SETTLE_FINE_MRAD) == 0 && !s.seeking && s.ramp == 0);   /* settled: off, reset */
    CHECK(seek_control(s, g, -SETTLE_RESEEK_MRAD - 1) <= -DUTY_MIN && s.dir == -1);  /* deflating */
    CHECK(seek_control(s, g, 3) == 0 && !s.seeking);                         /* past the set point: stop */
    /* outside the dead band: the P law, no ramp; the ramp never passes the ceiling */
    seek_reset(s);
    CHECK(seek_control(s, g, 200) == p_control(g, 200) && s.ramp == 0);
    seek_reset(s);
    CHECK(seek_control(s, g, -100000) == -DUTY_MAX_DEFLATE);
    seek_reset(s);
    for (int i = 0; i < 1000; i++) seek_control(s, g, 60);
    CHECK(seek_control(s, g, 60) <= DUTY_MAX_INFLATE);
    /* DBAND caps both bands: 5 (under SETTLE_RESEEK_MRAD) re-seeks past 5; 0 holds to the count */
    g.dband = 5;
    seek_reset(s);
    CHECK(seek_control(s, g, 5) == 0 && seek_control(s, g, 6) > 0);
    g.dband = 0;
    seek_reset(s);
    CHECK(seek_control(s, g, 1) > 0 && seek_control(s, g, 0) == 0 && !s.seeking);
    g.kp = 0;
    CHECK(seek_control(s, g, 500) == 0 && !s.seeking);
}

static void setlim_ramps() {
    fresh_eeprom();
    Rig r(EE);
    r.hello(1);
    r.cmd("W 0 1000 400 400 400");
    r.run_live(3000);
    CHECK(r.cmd("SETLIM 1 0 200 100") == "OK 32");
    r.run(20);
    CHECK(r.seen("EV LIMIT 1"));
    float last = r.board.traj.sp[0];
    for (int i = 0; i < 100; i++) {   /* never faster than the new vmax: 1 mrad per 10 ms */
        r.run(PERIOD_MS);
        CHECK(last - r.board.traj.sp[0] <= 1.001f && last >= r.board.traj.sp[0]);
        last = r.board.traj.sp[0];
    }
    CHECK(r.cmd("W 1 100 300 0 0") == "ER 6 RANGE 1");
    CHECK(r.cmd("LIM 1") == "OK 32 1 0 200 100");
}

/* A straight joint reads a count below its calibration (sensor noise: -2 mrad, under
 * the limit 0): the set point HELLO takes from it is the limit, not a point outside
 * the range to ramp in from (no EV LIMIT); a real SETLIM narrowing still ramps. */
static void hello_on_a_straight_arm_is_no_limit() {
    fresh_eeprom();
    Rig r(EE);
    for (int k = 0; k < N_JOINTS; k++) r.hal.adc_bias[k] = -1;
    r.hello(1);
    r.run_live(500);
    CHECK(!r.seen("EV LIMIT"));
    for (int j = 0; j < N_JOINTS; j++) CHECK_MSG(r.board.traj.sp[j] == 0.0f, "joint %d set point %g", j + 1,
                                                  (double)r.board.traj.sp[j]);
    CHECK(r.board.q[0] == -2);
}

static std::string mb_frame(std::vector<uint8_t> f) {
    uint16_t crc = mb_crc16(f.data(), (uint16_t)f.size());
    f.push_back((uint8_t)(crc & 0xFF));
    f.push_back((uint8_t)(crc >> 8));
    return std::string(f.begin(), f.end());
}

static void modbus_switch() {
    fresh_eeprom();
    {
        Rig r(EE);
        r.hello(1);
        CHECK(r.cmd("MODBUS 5") == "OK 32");
        CHECK(r.board.link.modbus());
        size_t before = r.hal.tx.size();
        r.hal.push(mb_frame({5, 4, 0, 44, 0, 1}));   /* FC4: input register 44, n */
        r.run(5);
        std::string reply = r.hal.tx.substr(before);
        CHECK(reply.size() == 7 && (uint8_t)reply[1] == 4 && (uint8_t)reply[4] == 3);
    }
    Rig r(EE);   /* kept across a reset: boots speaking Modbus, no text banner */
    CHECK(r.board.link.modbus() && r.hal.tx.empty());
    r.hal.push(mb_frame({5, 6, 0, MB_HR_COMMAND, 0, MB_CMD_LINE}));
    r.run(5);
    CHECK(r.hal.tx.size() == 8 && !r.board.link.modbus());
    r.rd = r.hal.tx.size();
    r.seq = 1;
    CHECK(r.hello(2).compare(0, strlen("OK"), "OK") == 0);
}

/* A frame whose bytes arrive while the loop is busy (a long pass): they wait in the
 * receive ring. Each keeps the time of its receive interrupt, so the frame is not
 * split at the stall (before: the second half was stamped when the loop took it,
 * 3 ms after the first, a gap above t3.5 that split the frame and failed its CRC). */
static void modbus_frame_across_a_stall() {
    fresh_eeprom();
    Rig r(EE);
    r.hello(1);
    CHECK(r.cmd("MODBUS 5") == "OK 32");
    std::string f = mb_frame({5, 16, 0, 0, 0, 3, 6, 0, 100, 0, 100, 0, 100});
    size_t before = r.hal.tx.size();
    for (size_t i = 0; i < f.size(); i++) {   /* a byte per 87 us, as the wire at 115200 */
        r.hal.push(f.substr(i, 1));
        r.hal.step_plant(87);
        if (i == 4) r.board.poll();           /* the loop takes the first bytes ... */
    }
    r.hal.step_plant(3000);                   /* ... then is busy for 3 ms */
    r.run(5);
    std::string reply = r.hal.tx.substr(before);
    CHECK_MSG(reply.size() == 8 && (uint8_t)reply[1] == 16, "reply of %zu bytes", reply.size());
    CHECK(mb_stats()->frames == 1 && mb_stats()->crc_errors == 0);
}

/* Traj against RefTraj (tests/traj_ref.h: the generator before plan() lost its float
 * divisions) on the same random calls: waypoints from whole-mrad set points (plan's
 * integer path) with steps at and one mrad past what the duration allows at vmax (N ==
 * dur * vmax, the ceiling's edge), long and huge moves, durations 0..65535, vmax from 1
 * to 2^25, re-plans from a set point between whole mrad (SETLIM slower), set points,
 * ranges that ramp, hold. Tolerance: none; after every call the set points, velocities,
 * active id and events must be the same bit for bit. */
static uint32_t rng_state = 12345u;
static uint32_t rnd() {   /* xorshift32 */
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 17;
    rng_state ^= rng_state << 5;
    return rng_state;
}
static int32_t rnd_in(int32_t lo, int32_t hi) { return lo + (int32_t)(rnd() % (uint32_t)(hi - lo + 1)); }

static bool same_traj(const Traj &a, const RefTraj &b) {
    return memcmp(a.sp, b.sp, sizeof a.sp) == 0 && memcmp(a.vel, b.vel, sizeof a.vel) == 0 &&
           a.active_id == b.active_id;
}

static int32_t rnd_vmax() {
    switch (rnd() % 6) {
        case 0: return 500;
        case 1: return rnd_in(1, 20);
        case 2: return rnd_in(1, 2000);
        case 3: return (int32_t)(1000 * rnd_in(1, 9));
        case 4: return rnd_in((1L << 24) - 2, (1L << 24) + 2);
        default: return rnd_in(1, 1L << 25);
    }
}

static void traj_matches_the_float_formula() {
    const int trials = 400, calls = 600;
    long steps = 0, edge = 0, near = 0, slow = 0, mismatches = 0;
    for (int trial = 0; trial < trials && mismatches == 0; trial++) {
        int32_t vmax[N_JOINTS];
        for (int j = 0; j < N_JOINTS; j++) vmax[j] = rnd_vmax();
        Traj t;
        RefTraj r;
        t.init(vmax);
        r.init(vmax);
        int32_t last[N_JOINTS] = {0, 0, 0};
        uint16_t id = 0;
        for (int c = 0; c < calls && mismatches == 0; c++) {
            TrajEvent ea[TRAJ_MAX_EVENTS], eb[TRAJ_MAX_EVENTS];
            uint32_t op = rnd() % 100;
            if (op < 45) {                       /* a waypoint */
                uint16_t dur;
                switch (rnd() % 5) {
                    case 0: dur = 2; break;
                    case 1: dur = (uint16_t)rnd_in(0, 3); break;
                    case 2: dur = (uint16_t)rnd_in(0, 300); break;
                    case 3: dur = (uint16_t)rnd_in(250, 260); break;
                    default: dur = (uint16_t)rnd_in(0, 65535); break;
                }
                int32_t q[N_JOINTS], prev0 = last[0];
                bool at_edge = false;
                for (int j = 0; j < N_JOINTS; j++) {
                    int32_t d;
                    uint32_t kind = rnd() % 8;
                    int64_t allow = (int64_t)dur * r.vmax[j];   /* N allowed: dur * vmax */
                    if (kind < 3 && allow % 1000 == 0 && allow / 1000 < 9000) {
                        d = (int32_t)(allow / 1000) + (int32_t)(kind == 2);   /* at the edge, one past */
                        at_edge = at_edge || kind < 2;
                    } else if (kind < 5) {
                        d = rnd_in(0, 12);
                    } else if (kind < 7) {
                        d = rnd_in(0, 9000);
                    } else {
                        d = rnd_in(0, 1L << 22);
                    }
                    if (rnd() & 1) d = -d;
                    q[j] = last[j] + d;
                    if (q[j] > (1L << 23) || q[j] < -(1L << 23)) q[j] = last[j] - d;
                    last[j] = q[j];
                }
                if (rnd() % 3 == 0) {            /* dur at joint 1's need, or 1 ms short of it */
                    int64_t n = (int64_t)(q[0] > prev0 ? q[0] - prev0 : prev0 - q[0]) * 1000, v = r.vmax[0];
                    int64_t need = (n + v - 1) / v - (int64_t)(rnd() & 1);
                    if (need >= 0 && need <= 65535) { dur = (uint16_t)need; near++; }
                }
                if (at_edge) edge++;
                bool pa = t.push(id, dur, q), pb = r.push(id, dur, q);
                CHECK(pa == pb);
                id++;
            } else if (op < 88) {                /* a control period (or a few ms of one) */
                uint16_t dt = (rnd() & 1) ? (uint16_t)PERIOD_MS : (uint16_t)rnd_in(0, 30);
                uint8_t na = t.step(dt, ea), nb = r.step(dt, eb);
                steps++;
                CHECK(na == nb);
                bool ev_same = na == nb;
                for (uint8_t i = 0; ev_same && i < na; i++) {
                    ev_same = ea[i].kind == eb[i].kind && ea[i].a == eb[i].a && ea[i].b == eb[i].b;
                    if (eb[i].kind == TE_SLOW) slow++;
                }
                CHECK(ev_same);
                if (!ev_same) mismatches++;
            } else if (op < 93) {                /* SETLIM: a slower vmax re-plans from the set point */
                uint8_t j = (uint8_t)(rnd() % N_JOINTS);
                int32_t lo = rnd_in(-(1L << 23), 0), hi = rnd_in(0, 1L << 23);
                if (rnd() % 4 == 0) { lo = rnd_in(-3000, 3000); hi = lo + rnd_in(0, 3000); }
                int32_t v = (rnd() & 1) ? r.vmax[j] / rnd_in(1, 5) + (int32_t)(r.vmax[j] < 5) : rnd_vmax();
                t.set_range(j, lo, hi, v);
                r.set_range(j, lo, hi, v);
            } else if (op < 96) {                /* a set point, whole mrad or between */
                float q[N_JOINTS];
                for (int j = 0; j < N_JOINTS; j++) {
                    q[j] = (float)rnd_in(-5000, 5000);
                    if (rnd() & 1) q[j] += (float)rnd_in(1, 999) / 1000.0f;
                    last[j] = (int32_t)q[j];
                }
                t.set_point(q);
                r.set_point(q);
            } else if (op < 98) {
                t.hold = r.hold = !r.hold;
            } else {
                t.flush();
                r.flush();
            }
            bool same = same_traj(t, r);
            CHECK_MSG(same, "trial %d call %d: sp %.9g/%.9g vel %.9g/%.9g id %ld/%ld", trial, c,
                      (double)t.sp[0], (double)r.sp[0], (double)t.vel[0], (double)r.vel[0],
                      (long)t.active_id, (long)r.active_id);
            if (!same) mismatches++;
        }
    }
    /* the cases that matter occurred, many times */
    CHECK_MSG(steps > 50000 && edge > 5000 && near > 5000 && slow > 5000, "steps %ld edge %ld near %ld slow %ld",
              steps, edge, near, slow);
    printf("traj vs reference: %ld steps, %ld waypoints at the vmax edge, %ld at joint 1's need, %ld SLOW\n",
           steps, edge, near, slow);
}

/* IDENT and CALID: the serial made once in an erased EEPROM and kept; CALID persists the
 * gains, dead bands and bends under its id, a reset boots with them and IDENT reports the
 * id; a torn calibration record boots the defaults with cal 0; CALID 0 refused. RELAY: a
 * push the joint cannot switch runs to the end stop and gives up (EV RELAY j 0 0). */
static void ident_calid_relay() {
    fresh_eeprom();
    std::string uid;
    {
        Rig r(EE);
        r.hello(1, 77);
        std::string id = r.cmd("IDENT");
        CHECK_MSG(id.size() == strlen("OK 32 ") + 8 + 2 && id.compare(id.size() - 2, 2, " 0") == 0, "%s", id.c_str());
        uid = id.substr(strlen("OK 32 "), 8);
        CHECK(uid != "ffffffff" && uid != "00000000");
        CHECK(r.cmd("CALID 0") == "ER 6 RANGE id");
        CHECK(r.cmd("GAIN 2 3100 5 7") == "OK 32");
        CHECK(r.cmd("DBAND 3 45") == "OK 32");
        CHECK(r.cmd("BEND 1 0 -400 1023 1700") == "OK 32");
        CHECK(r.cmd("CALID 4242") == "OK 32");
        CHECK(r.cmd("IDENT") == "OK 32 " + uid + " 4242");
        CHECK(r.cmd("GAIN 2 9000 0 0") == "OK 32");       /* RAM only: the boot loads the calibration's */
        /* a relay whose switch the reading cannot reach (a BEND that reads 3 rad low): a push to
         * the stop (a BEND after CALID persists, but the boot loads the calibration's) */
        CHECK(r.cmd("BEND 1 205 -3000 716 -1953") == "OK 32");
        CHECK(r.cmd("RELAY 1 1000 1000 1") == "OK 32");
        r.run_live(RELAY_TIMEOUT_MS + 500);
        CHECK(r.seen("EV ENDSTOP 1") && r.seen("EV RELAY 1 0 0"));
        CHECK(!r.board.relay[0].on && r.board.link.state != ST_FAULT);
        CHECK(r.cmd("W 9 2000 0 0 0") == "OK 31");
        CHECK(r.cmd("RELAY 1 500 0 1") == "ER 6 RANGE");   /* motion queued */
    }
    {
        Rig r(EE);   /* the reset */
        r.hello(2, 77);
        CHECK(r.cmd("IDENT") == "OK 32 " + uid + " 4242");
        CHECK(r.board.gain[1].kp == 3100 && r.board.ki[1] == 5 && r.board.kd[1] == 7);
        CHECK(r.board.gain[2].dband == 45 && r.board.gain[0].dband == DBAND_DEFAULT_MRAD);
        CHECK(r.board.cal[0].adc_a == 0 && r.board.cal[0].a == -400 && r.board.cal[0].b == 1700);
    }
    EE[EE_CALIB + 20] ^= 0x01;   /* torn: the CRC fails */
    Rig r(EE);
    r.hello(3, 77);
    CHECK(r.cmd("IDENT") == "OK 32 " + uid + " 0");
    CHECK(r.board.gain[1].kp == KP_DEFAULT && r.board.gain[2].dband == DBAND_DEFAULT_MRAD);
}

void run_board() {
    boot_and_hello();
    waypoints_to_done();
    estop_within_one_period();
    watchdog();
    latches_across_reset();
    latch_cell_wins_over_an_older_record();
    done_across_reset_from_noinit();
    a_tail_at_boot_is_dropped_silently();
    bad_commands_keep_answering();
    replay_executes_once();
    end_stop_stops_that_pump();
    dead_band_and_asymmetry();
    settle_with_hysteresis_and_ramp();
    setlim_ramps();
    modbus_switch();
    modbus_frame_across_a_stall();
    hello_on_a_straight_arm_is_no_limit();
    traj_matches_the_float_formula();
    ident_calid_relay();
}
