/* Session rules of the board (docs/protocol.md §6), exactly as
 * firmware/common/session.py: HELLO with epochs, the executed seq, the replay ring
 * of the last AB_RING answers. Pure: the link drives it.
 *
 *   verb   condition                                            -> action
 *   HELLO  proto != 2                                           -> BADPROTO
 *   HELLO  epoch == E + 1, session != stored                    -> NEW
 *   HELLO  epoch == E + 1, session == stored                    -> RESYNC
 *   HELLO  epoch == E, session == stored, seq == hello_seq      -> FRESH
 *   HELLO  otherwise                                            -> STALE
 *   other  no HELLO since boot: read-only -> FRESH, else        -> NOSESSION
 *   other  seq == expect                                        -> EXEC
 *   other  1..RING behind: read-only -> FRESH, answered -> REPLAY
 *   other  otherwise                                            -> SEQERR
 * Only the next epoch opens: a HELLO that jumped ahead (to AB_EPOCH_MAX) would leave
 * none for a later resync; refused STALE E, the host retries with E + 1.
 */
#ifndef PUMP_SESSION_H
#define PUMP_SESSION_H

#include <stdint.h>

#include "proto.h"

enum SessAction { S_EXEC, S_REPLAY, S_FRESH, S_SEQERR, S_NOSESSION, S_NEW, S_RESYNC, S_STALE, S_BADPROTO };

/* The answer first given to an executed seq: OK (code 0) with its FREE, or ER
 * code with its detail. Executed verbs that are not read-only have no payload. */
struct SessAnswer {
    int32_t seq;             /* -1: empty slot */
    uint8_t code;            /* 0: OK */
    uint8_t free;            /* OK: free slots after it */
    char detail[AB_DETAIL_MAX];
};

class Session {
public:
    Session() { init(0, 0, -1); }
    void init(uint16_t session, uint32_t epoch, int32_t hello_seq);
    bool open() const { return expect >= 0; }
    SessAction classify(uint16_t seq, bool read_only, bool hello, int32_t proto_v,
                        int32_t sid, int32_t epoch_v) const;
    void accept(uint16_t seq, uint16_t sid, uint32_t epoch_v);
    void record(uint16_t seq, const SessAnswer &a);
    const SessAnswer *replay(uint16_t seq) const { return &ring_[seq % AB_RING]; }
    uint16_t next_bseq() { return bseq++; }

    uint16_t session;
    uint32_t epoch;
    int32_t hello_seq;       /* -1: none */
    int32_t expect;          /* -1: no HELLO accepted since boot */
    uint16_t bseq;           /* board line counter (mod 65536) */

private:
    SessAnswer ring_[AB_RING];
};

#endif
