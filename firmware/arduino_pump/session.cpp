/* Session rules (session.h): the table of firmware/common/session.py. */
#include "session.h"

void Session::init(uint16_t sid, uint32_t epoch_v, int32_t hseq) {
    session = sid;
    epoch = epoch_v;
    hello_seq = hseq;
    expect = -1;
    bseq = 0;
    for (int i = 0; i < AB_RING; i++) ring_[i].seq = -1;
}

SessAction Session::classify(uint16_t seq, bool read_only, bool hello, int32_t proto_v,
                             int32_t sid, int32_t epoch_v) const {
    if (hello) {
        if (proto_v != AB_PROTOCOL_VERSION) return S_BADPROTO;
        if ((uint32_t)epoch_v == epoch + 1) return sid == session ? S_RESYNC : S_NEW;   /* only the next */
        if ((uint32_t)epoch_v == epoch && sid == session && (int32_t)seq == hello_seq) return S_FRESH;
        return S_STALE;
    }
    if (expect < 0) return read_only ? S_FRESH : S_NOSESSION;
    if ((int32_t)seq == expect) return S_EXEC;
    uint16_t behind = (uint16_t)((uint16_t)expect - seq);
    if (behind >= 1 && behind <= AB_RING) {
        if (read_only) return S_FRESH;
        if (ring_[seq % AB_RING].seq == (int32_t)seq) return S_REPLAY;
    }
    return S_SEQERR;
}

void Session::accept(uint16_t seq, uint16_t sid, uint32_t epoch_v) {
    session = sid;
    epoch = epoch_v;
    hello_seq = seq;
    for (int i = 0; i < AB_RING; i++) ring_[i].seq = -1;
    expect = (uint16_t)(seq + 1);
}

void Session::record(uint16_t seq, const SessAnswer &a) {
    SessAnswer &r = ring_[seq % AB_RING];
    r = a;
    r.seq = seq;
    expect = (uint16_t)(seq + 1);
}
