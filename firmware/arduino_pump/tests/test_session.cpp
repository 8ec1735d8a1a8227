/* The session rules, case for case as tests/firmware/test_fw_session.py. */
#include <string.h>

#include "check.h"
#include "session.h"

static SessAction hello(const Session &s, uint16_t seq, int32_t proto, int32_t sid, int32_t epoch) {
    return s.classify(seq, false, true, proto, sid, epoch);
}
static SessAction other(const Session &s, uint16_t seq, bool ro = false) { return s.classify(seq, ro, false, 0, 0, 0); }

static SessAnswer ok(uint8_t free) {
    SessAnswer a;
    a.seq = -1;
    a.code = 0;
    a.free = free;
    a.detail[0] = 0;
    return a;
}
static SessAnswer er(uint8_t code) {
    SessAnswer a = ok(0);
    a.code = code;
    return a;
}

static void opened(Session *s, uint16_t seq, uint16_t sid, uint32_t epoch) {
    s->init(0, epoch - 1, -1);   /* a board that last saw epoch - 1: only E + 1 opens */
    CHECK(hello(*s, seq, 2, sid, (int32_t)epoch) == S_NEW);
    s->accept(seq, sid, epoch);
}

void run_session() {
    Session s;
    /* no session before HELLO; read-only verbs answer anyway */
    CHECK(!s.open() && other(s, 0) == S_NOSESSION && other(s, 5) == S_NOSESSION);
    CHECK(other(s, 5, true) == S_FRESH);
    /* a wrong proto is refused before anything else */
    opened(&s, 1, 7, 1);
    CHECK(hello(s, 9, 1, 7, 5) == S_BADPROTO && hello(s, 1, 3, 7, 1) == S_BADPROTO && hello(s, 1, 65535, 7, 1) == S_BADPROTO);
    CHECK(s.session == 7 && s.epoch == 1 && s.hello_seq == 1 && s.expect == 2);
    /* newer epoch: other session NEW, same session RESYNC */
    s.init(0, 0, -1);
    CHECK(hello(s, 300, 2, 9, 1) == S_NEW);
    s.accept(300, 9, 1);
    CHECK(s.open() && s.expect == 301 && s.session == 9 && s.epoch == 1 && s.hello_seq == 300);
    CHECK(hello(s, 5, 2, 9, 2) == S_RESYNC && hello(s, 5, 2, 10, 2) == S_NEW);
    /* only the next epoch: one that jumps ahead is STALE (it would leave none for a resync) */
    CHECK(hello(s, 5, 2, 9, 3) == S_STALE && hello(s, 5, 2, 10, 1000) == S_STALE && hello(s, 5, 2, 9, AB_EPOCH_MAX) == S_STALE);
    s.accept(65535, 9, 2);
    CHECK(s.expect == 0 && other(s, 0) == S_EXEC);
    /* accept clears the replay ring */
    opened(&s, 1, 7, 1);
    s.record(2, ok(31));
    CHECK(other(s, 2) == S_REPLAY);
    s.accept(3, 7, 2);
    CHECK(other(s, 2) == S_SEQERR);
    /* a copy of the opening HELLO is FRESH and changes nothing */
    opened(&s, 1, 7, 4);
    for (uint16_t q = 2; q < 60; q++) s.record(q, ok(32));
    CHECK(hello(s, 1, 2, 7, 4) == S_FRESH && s.expect == 60 && s.epoch == 4);
    /* stale HELLOs */
    opened(&s, 10, 7, 4);
    CHECK(hello(s, 10, 2, 7, 3) == S_STALE && hello(s, 10, 2, 8, 4) == S_STALE);
    CHECK(hello(s, 11, 2, 7, 4) == S_STALE && hello(s, 10, 2, 8, 3) == S_STALE);
    CHECK(s.session == 7 && s.epoch == 4 && s.hello_seq == 10 && s.expect == 11);
    /* what a reset leaves needs a newer epoch */
    s.init(7, 4, 10);
    CHECK(!s.open() && s.expect == -1 && other(s, 11) == S_NOSESSION);
    CHECK(hello(s, 10, 2, 7, 4) == S_FRESH && hello(s, 12, 2, 7, 4) == S_STALE && hello(s, 12, 2, 7, 5) == S_RESYNC);
    /* in order: executed and recorded, an error advances too */
    opened(&s, 1, 7, 1);
    CHECK(other(s, 2) == S_EXEC);
    s.record(2, ok(31));
    CHECK(s.expect == 3 && other(s, 3) == S_EXEC);
    s.record(3, er(AB_ERR_RANGE));
    CHECK(s.expect == 4);
    /* a retransmit is replayed, with the first answer */
    opened(&s, 1, 7, 1);
    s.record(2, ok(31));
    s.record(3, er(AB_ERR_FULL));
    CHECK(other(s, 2) == S_REPLAY && s.replay(2)->code == 0 && s.replay(2)->free == 31);
    CHECK(other(s, 3) == S_REPLAY && s.replay(3)->code == AB_ERR_FULL);
    /* read-only retransmits are answered fresh */
    CHECK(other(s, 2, true) == S_FRESH && other(s, 1, true) == S_FRESH);
    /* ahead and far behind are SEQ errors */
    opened(&s, 100, 7, 1);
    for (uint16_t q = 101; q < 134; q++) s.record(q, ok(32));
    CHECK(s.expect == 134 && other(s, 135) == S_SEQERR);
    CHECK(other(s, 134 - 32) == S_REPLAY && other(s, 134 - 33) == S_SEQERR && other(s, 134 - 33, true) == S_SEQERR);
    CHECK(other(s, 60000) == S_SEQERR);
    /* behind but never accepted */
    opened(&s, 10, 7, 1);
    CHECK(other(s, 9) == S_SEQERR && other(s, 10) == S_SEQERR);
    /* wraparound */
    opened(&s, 65534, 7, 1);
    s.record(65535, ok(31));
    CHECK(s.expect == 0);
    s.record(0, ok(30));
    CHECK(other(s, 65535) == S_REPLAY && other(s, 0) == S_REPLAY && other(s, 1) == S_EXEC);
    /* board line counter wraps */
    s.bseq = 65535;
    CHECK(s.next_bseq() == 65535 && s.bseq == 0);
}
