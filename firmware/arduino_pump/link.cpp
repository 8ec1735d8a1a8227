/* The link layer (link.h): firmware/common/link.py in C++. */
#include "link.h"

#include <string.h>

#include "config.h"
#include "modbus.h"

const char *const STATE_NAMES[6] = {"IDLE", "RUN", "HOLD", "ESTOP", "WDOG", "FAULT"};

/* The ring's own kinds (compared by address): a completed waypoint, a latch. */
const char K_DONE[] = "DONE";
const char K_LATCH[] = "LATCH";

static bool latched(uint8_t st) { return st == ST_ESTOP || st == ST_WDOG || st == ST_FAULT; }

#define TICKS_MASK (AB_TICKS_PERIOD - 1)
#define PERIOD_US ((uint32_t)PERIOD_MS * 1000UL)

/* ------------------------------------------------------------------ payload text */

void Payload::str(const char *s) {
    size_t n = strlen(s);
    if (len + n + 2 > sizeof buf) return;
    if (len) buf[len++] = ' ';
    memcpy(buf + len, s, n);
    len = (uint8_t)(len + n);
    buf[len] = 0;
}

void Payload::num(int32_t v) {
    char tmp[12];
    int k = 0;
    uint32_t u = v < 0 ? (uint32_t)(-(int64_t)v) : (uint32_t)v;
    do {
        tmp[10 - k++] = (char)('0' + u % 10);
        u /= 10;
    } while (u);
    if (v < 0) tmp[10 - k++] = '-';
    tmp[11] = 0;
    str(tmp + 11 - k);
}

/* ------------------------------------------------------------------ persistence
 * One slot: tag 'P', version 2, generation, latch; session; epoch; hello_seq; done;
 * reason (8 chars, NUL padded); CRC-32 of the 28 bytes before it. Two slots written
 * in turn: a reset while one is being programmed leaves the other. */
struct PersistRec {
    uint8_t tag, ver, gen, latch;
    uint16_t session, pad;
    uint32_t epoch;
    int32_t hello_seq, done;
    char reason[8];
    uint32_t crc;
};
static_assert(sizeof(PersistRec) == 32 && EE_LINK_A + 32 <= EE_LINK_B && EE_LINK_B + 32 <= EE_SETTINGS, "persist layout");
static_assert(EE_SETTINGS + 44 <= EE_LATCH && EE_LATCH < EE_SIZE, "latch cell layout");

#define LATCH_CELL(st) ((uint8_t)(0xC0 | (st)))   /* 0xC0: released; 0xC3..0xC5: latched */

static bool rec_valid(const PersistRec &r) {
    if (r.tag != 'P' || r.ver != 2) return false;
    if (ab_crc32((const uint8_t *)&r, sizeof r - 4, 0) != r.crc) return false;
    if (r.epoch > (uint32_t)AB_EPOCH_MAX || r.hello_seq < -1 || r.hello_seq > 0xFFFF) return false;
    if (r.done < -1 || r.done > 0xFFFF) return false;
    return r.latch == 0 || latched(r.latch);
}

/* The live copy: the same record behind a magic in .noinit SRAM (hal.h keep_*),
 * written at once on every save. The EEPROM slots are written behind, a byte per
 * main-loop pass (3.4 ms a byte), so while waypoints complete every 20 ms a slot is
 * never finished and EEPROM alone would lose every DONE since the stream began on a
 * reset. SRAM survives a reset (as the ESP32's RTC memory does for the MicroPython
 * boards), not a power cycle: there the EEPROM copy is read. */
#define KEEP_MAGIC 0x4B50554DUL   /* "MUPK" */
struct KeepRec {
    uint32_t magic;
    PersistRec rec;
};
static_assert(sizeof(KeepRec) <= KEEP_SIZE, "keep area");

void Link::load() {
    PersistRec a, b;
    KeepRec k;
    hal_->keep_read(&k, sizeof k);
    hal_->ee_read(EE_LINK_A, &a, sizeof a);
    hal_->ee_read(EE_LINK_B, &b, sizeof b);
    bool va = rec_valid(a), vb = rec_valid(b);
    const PersistRec *r = NULL;
    if (k.magic == KEEP_MAGIC && rec_valid(k.rec)) r = &k.rec;   /* a reset: SRAM is newest */
    else if (va && vb) r = (int8_t)(a.gen - b.gen) >= 0 ? &a : &b;
    else if (va) r = &a;
    else if (vb) r = &b;
    strcpy(reason, "-");
    if (r == NULL) {   /* power on: no session, epoch 0, IDLE */
        sess.init(0, 0, -1);
        done = -1;
        state = ST_IDLE;
        gen_ = 0;
        return;
    }
    sess.init(r->session, r->epoch, r->hello_seq);
    done = r->done;
    state = r->latch ? r->latch : (uint8_t)ST_IDLE;
    memcpy(reason, r->reason, 8);
    reason[8] = 0;
    if (!reason[0]) strcpy(reason, "-");
    gen_ = r->gen;
}

/* The latch cell is written first and at once, the record after it (write-behind):
 * a cell that says latched while the record does not is newer than the record (a reset
 * came before the record was programmed), and wins. A cell that says released while the
 * record says latched leaves the latch: only a CLR releases it, and CLR again is safe. */
void Link::load_latch_cell() {
    uint8_t c;
    hal_->ee_read(EE_LATCH, &c, 1);
    if ((c & 0xF8) == 0xC0 && latched(c & 7) && !latched(state)) {
        state = (uint8_t)(c & 7);
        strcpy(reason, "-");
    }
}

void Link::save() {
    PersistRec r;
    memset(&r, 0, sizeof r);
    r.tag = 'P';
    r.ver = 2;
    r.gen = ++gen_;
    r.latch = latched(state) ? state : 0;
    r.session = sess.session;
    r.epoch = sess.epoch;
    r.hello_seq = sess.hello_seq;
    r.done = done;
    strncpy(r.reason, reason, 8);
    r.crc = ab_crc32((const uint8_t *)&r, sizeof r - 4, 0);
    KeepRec k;
    k.magic = KEEP_MAGIC;
    k.rec = r;
    hal_->keep_write(&k, sizeof k);
    hal_->ee_write((gen_ & 1) ? EE_LINK_B : EE_LINK_A, &r, sizeof r);
}

/* ------------------------------------------------------------------ boot, main loop */

void Link::begin(Hal *hal, BoardIf *board, uint8_t modbus_addr) {
    hal_ = hal;
    board_ = board;
    reader_.reset();
    load();
    load_latch_cell();
    queued = -1;
    rate = TELEMETRY_HZ;
    wdog_ms = WDOG_MS;
    outputs_allowed = false;
    in_command_ = false;
    in_tick_ = false;
    n_events_ = 0;
    ring_head_ = ring_tail_ = ring_lost_ = 0;
    periods_ = periods_seen_ = 0;
    period_ms_ = 0;
    hgen_ = 0;
    pend_latch_ = 0;
    done_ovf_ = 0;
    telem_acc_ = 0;
    pending_mode_ = -1;
    modbus_ = modbus_addr != 0;
    timer_ = false;
    mb_frames_ = mb_exceptions_ = 0;
    last_ok_ = hal->ms();
    next_tick_us_ = hal->us();
    boot_us_ = next_tick_us_;
    join_ = JOIN_WAIT;
    hal->outputs_off();
    hal->set_estop_byte(!modbus_);
    board->hold_here();
    /* last: from here on the period runs on the HAL's timer (or poll() schedules it) */
    timer_ = hal->start_control(&Link::period_cb, this);
    if (modbus_) {
        mb_init(modbus_addr, UART_BAUD);
        return;   /* a Modbus master would read a text banner as a bad frame */
    }
    /* The lone LF ends any line a reset cut short, so BOOT always decodes. */
    hal->uart_write((const uint8_t *)"\n", 1);
    w_.begin(sess.next_bseq());
    w_.str("BOOT");
    w_.str(FW_NAME);
    w_.str(FW_VERSION);
    w_.num(AB_PROTOCOL_VERSION);
    w_.str(STATE_NAMES[state]);
    send(&w_);
}

/* The receiver came up while the board booted, and the host never waits for BOOT
 * (docs/protocol.md §8): a line the host was sending then arrives without its head.
 * The bytes of a line follow each other, so a line in flight when the receiver came
 * up delivers its next byte within a byte time of that; hal.begin() enables the
 * receiver before begin() here. So the first line since boot is a possible tail when
 * its first byte arrived by JOIN_US after begin(), and such a line that fails its
 * framing or CRC is dropped silently (no ER: nothing on the link damaged it), as the
 * host drops the first piece its port delivers. A whole line passes its checks and
 * runs; a first line that starts later is checked as every line is. */
#define JOIN_US (2UL * 10UL * 1000000UL / UART_BAUD)   /* two byte times at 8N1 */

int Link::next_byte() {
    if (join_ != JOIN_WAIT) return hal_->uart_read();
    uint32_t at;
    int c = hal_->uart_read_at(&at);
    if (c >= 0) join_ = (int32_t)(at - boot_us_) <= (int32_t)JOIN_US ? JOIN_TAIL : JOIN_DONE;
    return c;
}

void Link::poll() {
    sync();
    if (modbus_) {
        modbus_pass();
    } else {
        int c;
        while ((c = next_byte()) >= 0) {   /* drain the receive ring every pass */
            int item = reader_.feed((uint8_t)c);
            bool tail = join_ == JOIN_TAIL;   /* the first line since boot may be a tail */
            if (item != AB_ITEM_NONE && join_ == JOIN_TAIL) join_ = JOIN_DONE;
            switch (item) {
                case AB_ITEM_ESTOP: estop(); break;
                case AB_ITEM_ERROR: if (!tail) send_er(-1, reader_.error(), ""); break;
                case AB_ITEM_LINE:
                    sync();                   /* the periods before this line first */
                    on_line(reader_.line(), reader_.length(), tail);
                    break;
                default: break;
            }
            if (modbus_) return;   /* MODBUS answered: the rest is Modbus */
        }
        if (hal_->estop_dropped()) estop();
    }
    if (!timer_) {   /* no timer (the fake HAL): the period is due by us() */
        uint32_t now = hal_->us();
        int32_t late = (int32_t)(now - next_tick_us_);
        if (late >= 0) {
            if ((uint32_t)late >= PERIOD_US) next_tick_us_ = now + PERIOD_US;   /* too late: no burst */
            else next_tick_us_ += PERIOD_US;
            period();
        }
    }
    sync();
}

/* Over a latch the e-stop keeps the first cause as the reason (docs/protocol.md §9):
 * FAULT's reason, or WDOG; ESTOP is the state (outputs off, where WDOG writes zero). */
void Link::estop() {
    sync();                  /* a latch a period raised first: its cause is the first */
    hal_->outputs_off();
    char why[LINK_REASON_MAX] = "-";
    if (latched(state)) strcpy(why, strcmp(reason, "-") || state == ST_ESTOP ? reason : STATE_NAMES[state]);
    state = ST_ESTOP;        /* before the halt: no period drives in between (Modbus has no e-stop flag) */
    board_->halt();
    latch(ST_ESTOP, why);
    hal_->clear_estop();   /* latched now: control(OFF) writes nothing until CLR */
    event("ESTOP", 0);
}

/* ------------------------------------------------------------------ callbacks */

uint32_t Link::board_ms() { return hal_->ms() & TICKS_MASK; }

void Link::event(const char *kind, uint8_t nargs, int32_t a, int32_t b, int32_t c) {
    if (in_tick_) {          /* the period's: through the ring */
        push(kind, nargs, a, b, c);
        return;
    }
    if (in_command_) {
        if (n_events_ < LINK_MAX_EVENTS) {
            events_[n_events_].kind = kind;
            events_[n_events_].nargs = nargs;
            events_[n_events_].a = a;
            events_[n_events_].b = b;
            events_[n_events_].c = c;
            n_events_++;
        }
        return;
    }
    w_.begin(sess.next_bseq());
    w_.str("EV");
    w_.num((int32_t)board_ms());
    w_.str(kind);
    if (nargs > 0) w_.num(a);
    if (nargs > 1) w_.num(b);
    if (nargs > 2) w_.num(c);
    send(&w_);
}

void Link::flush_events() {
    uint8_t n = n_events_;
    n_events_ = 0;
    for (uint8_t i = 0; i < n; i++) event(events_[i].kind, events_[i].nargs, events_[i].a, events_[i].b, events_[i].c);
}

void Link::completed(int32_t wid) {
    if (in_tick_) {
        push(K_DONE, 2, wid, board_->free_slots(), 0);
        return;
    }
    done = wid;
    save();
    event("DONE", 2, wid, board_->free_slots());
}

void Link::fault(int32_t j, int32_t detail, const char *why) {
    hal_->outputs_off();
    board_->halt();
    if (in_tick_) {          /* the period's: latched by the main loop (take_latch) */
        if (!pend_latch_) {
            pend_j_ = j;
            pend_detail_ = detail;
            strncpy(pend_why_, why, LINK_REASON_MAX - 1);
            pend_why_[LINK_REASON_MAX - 1] = 0;
            pend_latch_ = ST_FAULT;
            push(K_LATCH, 0, 0, 0, 0);
        }
        return;
    }
    latch(ST_FAULT, why);
    event("FAULT", 2, j, detail);
}

void Link::latch(uint8_t st, const char *why) {
    state = st;
    hal_->ee_write_now(EE_LATCH, LATCH_CELL(latched(st) ? st : 0));   /* first, at once */
    strncpy(reason, why, LINK_REASON_MAX - 1);
    reason[LINK_REASON_MAX - 1] = 0;
    save();
}

void Link::hold_cmd(bool on) {
    if (on && state != ST_HOLD) {
        feed();              /* the watchdog counts from here: an idle board's last OK may be old */
        state = ST_HOLD;
        board_->set_hold(true);
        event("HOLD", 0);
    } else if (!on && state == ST_HOLD) {
        board_->set_hold(false);
        feed();
        state = board_->busy() ? ST_RUN : ST_IDLE;
        event("RESUME", 0);
    }
}

void Link::clear_cmd() {
    if (latched(state)) {
        board_->hold_here();
        outputs_allowed = true;
        latch(ST_IDLE, "-");
        event("CLEAR", 0);
    }
}

/* ------------------------------------------------------------------ lines */

void Link::send(LineWriter *w) {
    size_t n;
    const uint8_t *d = w->finish(&n);
    if (!modbus_) hal_->uart_write(d, n);
}

void Link::send_er(int32_t seq, uint8_t code, const char *detail) {
    w_.begin(sess.next_bseq());
    w_.str("ER");
    w_.wid(seq);
    w_.num(code);
    char name[AB_ERROR_NAME_LEN];
    if (code < AB_N_ERRORS)
        AB_MEMCPY_P(name, AB_ERROR_NAMES[code], sizeof name);   /* in flash on AVR */
    else
        memcpy(name, "ERR", 4);
    w_.str(name);
    if (detail && detail[0]) w_.str(detail);
    send(&w_);
}

void Link::reply(uint16_t seq, uint8_t code, uint8_t free, const char *detail, const Payload *p) {
    if (code) {
        send_er(seq, code, detail);
        return;
    }
    w_.begin(sess.next_bseq());
    w_.str("OK");
    w_.num(seq);
    w_.num(free);
    if (p && p->len) w_.str(p->buf, p->len);
    send(&w_);
}

void Link::on_line(const uint8_t *raw, size_t n, bool tail) {
    AbLine l;
    int e = ab_decode(raw, n, AB_MAX_HOST_LINE, sess.epoch, &l);
    if (e) {
        if (!tail) send_er(-1, (uint8_t)e, "");   /* a tail (next_byte) is dropped silently */
        return;
    }
    int vi = ab_find_verb(l.verb, l.verb_len);
    Payload p;
    AbError err;
    err.code = 0;
    err.detail[0] = 0;
    uint8_t code, free = 0;
    const char *detail = err.detail;
    in_command_ = true;
    if (vi == AB_VERB_HELLO) {
        code = hello(l.seq, l, &p, &err);
        free = board_->free_slots();
    } else {
        uint8_t ro = 0;
        if (vi >= 0) AB_MEMCPY_P(&ro, &AB_COMMANDS[vi].read_only, 1);   /* in flash on AVR */
        switch (sess.classify(l.seq, ro != 0, false, 0, 0, 0)) {
            case S_EXEC: {
                code = execute(l.seq, vi, l, &p, &err);
                free = board_->free_slots();
                SessAnswer a;
                a.code = code;
                a.free = free;
                memcpy(a.detail, err.detail, AB_DETAIL_MAX);
                sess.record(l.seq, a);
                break;
            }
            case S_REPLAY: {
                const SessAnswer *a = sess.replay(l.seq);
                code = a->code;
                free = a->free;
                detail = a->detail;
                break;
            }
            case S_FRESH:
                code = execute(l.seq, vi, l, &p, &err);
                free = board_->free_slots();
                break;
            case S_NOSESSION:
                code = AB_ERR_NOSESSION;
                break;
            default: {
                code = AB_ERR_SEQ;
                Payload x;
                x.num(sess.expect);
                memcpy(err.detail, x.buf, x.len + 1);
                break;
            }
        }
    }
    in_command_ = false;
    if (code == 0) feed();   /* only a line answered OK feeds the watchdog */
    reply(l.seq, code, free, detail, &p);
    flush_events();
    if (pending_mode_ > 0) {   /* MODBUS addr: its OK is out, the UART speaks Modbus now */
        modbus_ = true;
        hal_->set_estop_byte(false);
        mb_init((uint8_t)pending_mode_, UART_BAUD);
        pending_mode_ = -1;
    }
}

uint8_t Link::execute(uint16_t seq, int vi, const AbLine &l, Payload *p, AbError *err) {
    (void)seq;
    int32_t v[AB_MAX_ARGS];
    int code = ab_parse_command(l.verb, l.verb_len, l.args, l.arg_len, l.nargs, board_->n_joints(), v, err);
    if (code) return (uint8_t)code;
    switch (vi) {
        case AB_VERB_LIM: {
            int32_t m[3];
            board_->limits((uint8_t)v[0], m);
            p->num(v[0]);
            for (int i = 0; i < 3; i++) p->num(m[i]);
            return 0;
        }
        case AB_VERB_STAT:
            p->str(STATE_NAMES[state]);
            if (done < 0) p->str("-"); else p->num(done);
            if (queued < 0) p->str("-"); else p->num(queued);
            p->num((int32_t)board_ms());
            p->str(latched(state) ? reason : "-");
            return 0;
        case AB_VERB_PING: p->num((int32_t)board_ms()); return 0;
        case AB_VERB_RATE: rate = v[0]; telem_acc_ = 0; return 0;
        case AB_VERB_WDOG: set_wdog(v[0]); return 0;
        case AB_VERB_CLR: clear_cmd(); return 0;
        case AB_VERB_HOLD:
        case AB_VERB_RESUME:
            if (latched(state)) return err->code = AB_ERR_LATCHED;
            hold_cmd(vi == AB_VERB_HOLD);
            return 0;
        default: break;
    }
    if (board_->motion_verb(vi) && (latched(state) || pend_latch_)) return err->code = AB_ERR_LATCHED;
    code = board_->command(vi, v, p, err);
    if (code) return err->code = (uint8_t)code;
    if (state == ST_IDLE && board_->busy()) {
        feed();              /* this line is answered OK: the period's watchdog counts from now */
        state = ST_RUN;
    }
    return 0;
}

uint8_t Link::hello(uint16_t seq, const AbLine &l, Payload *p, AbError *err) {
    int32_t v[AB_MAX_ARGS];
    int code = ab_parse_command(l.verb, l.verb_len, l.args, l.arg_len, l.nargs, board_->n_joints(), v, err);
    if (code) {
        /* Another version's HELLO may take other arguments: its first, the version,
           still gets the answer that names both versions. */
        if (l.nargs > 0 && !(l.arg_len[0] == 1 && l.args[0][0] == '0' + AB_PROTOCOL_VERSION)) {
            strcpy(err->detail, "2");
            return err->code = AB_ERR_PROTO;
        }
        return (uint8_t)code;
    }
    SessAction what = sess.classify(seq, false, true, v[0], v[1], v[2]);
    if (what == S_BADPROTO) {
        strcpy(err->detail, "2");
        return err->code = AB_ERR_PROTO;
    }
    if (what == S_STALE) {
        Payload x;
        x.num((int32_t)sess.epoch);
        memcpy(err->detail, x.buf, x.len + 1);
        return err->code = AB_ERR_STALE;
    }
    if (what != S_FRESH) {   /* NEW or RESYNC */
        if (what == S_NEW) {
            done = -1;
            queued = -1;
            board_->hold_here();
            if (state == ST_RUN || state == ST_HOLD) state = ST_IDLE;
        }
        sess.accept(seq, (uint16_t)v[1], (uint32_t)v[2]);
        if (!outputs_allowed && !latched(state)) {
            board_->hold_here();   /* first: the next period drives from here */
            outputs_allowed = true;
        }
        save();
    }
    p->str(FW_NAME);
    p->str(FW_VERSION);
    p->num(AB_PROTOCOL_VERSION);
    p->num(board_->n_joints());
    p->num(board_->qsize());
    p->num(rate);
    p->num(wdog_ms);
    if (done < 0) p->str("-"); else p->num(done);
    if (queued < 0) p->str("-"); else p->num(queued);
    p->str(STATE_NAMES[state]);
    return 0;
}

/* ------------------------------------------------------------------ telemetry */

void Link::telemetry(uint32_t now, uint8_t periods) {
    if (rate <= 0 || modbus_) return;
    telem_acc_ += rate * PERIOD_MS * periods;
    if (telem_acc_ < 1000) return;
    telem_acc_ -= 1000;
    if (telem_acc_ >= 1000) telem_acc_ = 0;
    /* Telemetry yields to replies and events: with no room for a whole line in the
       transmit queue this one is skipped (not queued behind), and no board seq is
       spent on it, so the host sees no gap. */
    if (hal_->tx_room() < AB_MAX_BOARD_LINE) return;
    w_.begin(sess.next_bseq());
    w_.str("T");
    w_.num((int32_t)(now & TICKS_MASK));
    w_.str(STATE_NAMES[state]);
    w_.wid(done);
    w_.num(board_->free_slots());
    board_->telemetry(&w_);
    send(&w_);
}

/* ------------------------------------------------------------------ Modbus */

void Link::switch_to_modbus(uint8_t addr) { pending_mode_ = addr; }
void Link::switch_to_line() { pending_mode_ = 0; }

void Link::modbus_pass() {
    static uint8_t out[MB_FRAME_MAX];
    int c;
    uint32_t at;
    while ((c = hal_->uart_read_at(&at)) >= 0) mb_feed((uint8_t)c, at);   /* the byte's arrival time */
    int n = mb_poll(hal_->us(), out, sizeof out);
    const mb_counters *st = mb_stats();
    if (st->frames != mb_frames_) {   /* a valid frame answered without exception feeds the watchdog */
        if (st->exceptions == mb_exceptions_) feed();
        mb_frames_ = st->frames;
        mb_exceptions_ = st->exceptions;
    }
    if (n > 0) hal_->uart_write(out, (size_t)n);
    if (pending_mode_ == 0) {   /* the command register said LINE: after this reply */
        pending_mode_ = -1;
        modbus_ = false;
        reader_.reset();
        hal_->set_estop_byte(true);
    }
}
