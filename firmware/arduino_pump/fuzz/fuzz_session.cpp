/* libFuzzer target: the session rules of session.cpp (Session::classify, accept,
 * record, replay) driven as link.cpp drives them, under ASan and UBSan.
 *
 * Input: 8-byte operations (the same layout as tests/fuzz_codecs.py's "session"
 * target, which runs them against firmware/common/session.py as well):
 *   byte 0      kind % 4: 0 HELLO, 1 a read-only verb, 2 a verb that is not, 3 a reset
 *               (the board restarts: session, epoch and hello_seq kept, as in EEPROM)
 *   bytes 1..2  seq, little-endian; with bit 7 of byte 0 set, seq is taken relative to
 *               the expected seq (expect + (int8)byte 1), so the fuzzer reaches the ring
 *   bytes 3..4  HELLO: the session id, little-endian
 *   byte 5      HELLO: the epoch relative to the board's: epoch + (int8)byte 5
 *   byte 6      HELLO: the protocol version (2 when bit 6 of byte 0 is set)
 *   byte 7      the answer code recorded for an executed line
 * Invariants, checked by abort(): no seq executes twice in one epoch (what the rules
 * exist for); EXEC only at the expected seq; REPLAY only of an answered seq 1..RING
 * behind, and it returns that seq's first answer; NEW/RESYNC only for epoch E + 1, after
 * which the session is open, expect = seq + 1 and the epoch is the HELLO's; a refused
 * HELLO (STALE, BADPROTO) or a copy (FRESH) changes nothing; the epoch never goes back.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "session.h"

static void require(bool ok, const char *what) {
    if (!ok) {
        fprintf(stderr, "fuzz invariant broken: %s\n", what);
        abort();
    }
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    static uint8_t executed[65536];   /* executed[seq]: 1 + its answer code, this epoch */
    if (size > 8 * 512) return 0;
    memset(executed, 0, sizeof executed);
    Session s;
    s.init(0, 0, -1);
    for (size_t i = 0; i + 8 <= size; i += 8) {
        const uint8_t *op = data + i;
        uint8_t kind = op[0] & 3;
        uint16_t seq = (uint16_t)(op[1] | op[2] << 8);
        if ((op[0] & 0x80) && s.open()) seq = (uint16_t)(s.expect + (int8_t)op[1]);
        uint32_t before_epoch = s.epoch;
        int32_t before_expect = s.expect;
        uint16_t before_session = s.session;
        if (kind == 3) {
            s.init(s.session, s.epoch, s.hello_seq);
            require(!s.open(), "a reset closes the session");
            continue;
        }
        if (kind == 0) {
            int32_t proto = (op[0] & 0x40) ? AB_PROTOCOL_VERSION : op[6];
            uint16_t sid = (uint16_t)(op[3] | op[4] << 8);
            int64_t e = (int64_t)s.epoch + (int8_t)op[5];
            if (e < 0 || e > AB_EPOCH_MAX) continue;   /* the argument check refuses it first */
            SessAction a = s.classify(seq, false, true, proto, sid, (int32_t)e);
            if (a == S_NEW || a == S_RESYNC) {
                require(e == (int64_t)s.epoch + 1, "only the next epoch opens");
                require((a == S_RESYNC) == (sid == s.session), "RESYNC is the same session");
                s.accept(seq, sid, (uint32_t)e);
                memset(executed, 0, sizeof executed);
                require(s.open() && s.expect == (uint16_t)(seq + 1) && s.epoch == (uint32_t)e,
                        "an accepted HELLO opens E at seq + 1");
            } else {
                require(a == S_FRESH || a == S_STALE || a == S_BADPROTO, "a HELLO's action");
                if (a == S_BADPROTO) require(proto != AB_PROTOCOL_VERSION, "BADPROTO: another version");
                if (a == S_FRESH) require((int32_t)seq == s.hello_seq && e == s.epoch, "FRESH: the HELLO's copy");
                require(s.epoch == before_epoch && s.expect == before_expect && s.session == before_session,
                        "a refused or copied HELLO changes nothing");
            }
            continue;
        }
        bool ro = kind == 1;
        SessAction a = s.classify(seq, ro, false, 0, 0, 0);
        switch (a) {
            case S_EXEC: {
                require((int32_t)seq == s.expect, "EXEC at the expected seq");
                require(!executed[seq], "no seq executes twice in one epoch");
                SessAnswer ans;
                memset(&ans, 0, sizeof ans);
                ans.code = (uint8_t)(op[7] % AB_N_ERRORS);
                ans.free = op[7];
                s.record(seq, ans);
                executed[seq] = (uint8_t)(1 + ans.code);
                require(s.expect == (uint16_t)(seq + 1), "record advances expect");
                break;
            }
            case S_REPLAY: {
                require(!ro, "a read-only verb is never replayed");
                uint16_t behind = (uint16_t)((uint16_t)s.expect - seq);
                require(behind >= 1 && behind <= AB_RING, "REPLAY: 1..RING behind");
                const SessAnswer *r = s.replay(seq);
                require(r->seq == (int32_t)seq && executed[seq] == 1 + r->code, "REPLAY: that seq's first answer");
                break;
            }
            case S_FRESH:
                require(ro, "FRESH only for a read-only verb");
                break;
            case S_NOSESSION:
                require(!s.open() && !ro, "NOSESSION: no HELLO since boot");
                break;
            case S_SEQERR:
                require(s.open(), "SEQERR only in a session");
                break;
            default:
                require(false, "a HELLO action for a line that is not a HELLO");
        }
        require(s.epoch >= before_epoch, "the epoch never goes back");
    }
    return 0;
}
