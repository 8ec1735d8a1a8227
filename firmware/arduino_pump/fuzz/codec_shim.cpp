/* A C interface to the board's codec and session rules (proto.cpp, session.cpp) for
 * the differential fuzzing in tests/fuzz_codecs.py, which loads it with ctypes and
 * checks that the C++, the MicroPython firmware's Python and the host agree.
 * Built as a shared library (make -C firmware/arduino_pump/fuzz shim), without the
 * sanitizers (the libFuzzer targets run this code under them).
 */
#include <stdio.h>
#include <string.h>

#include "proto.h"
#include "session.h"

/* Appends s[0..n) to out at `at` (cut at cap - 1, NUL-terminated) -> the new end. */
static size_t put(char *out, size_t cap, size_t at, const char *s, size_t n) {
    for (size_t i = 0; i < n && at + 1 < cap; i++) out[at++] = s[i];
    out[at < cap ? at : cap - 1] = 0;
    return at;
}

/* ab_decode -> 0 and "seq\tverb\tnargs\targ\targ..." in out (the first AB_MAX_ARGS
 * arguments: the rest are only counted), or the error code. */
extern "C" int shim_decode(const uint8_t *line, size_t n, size_t max_len, uint32_t epoch, char *out, size_t cap) {
    AbLine l;
    out[0] = 0;
    int e = ab_decode(line, n, max_len, epoch, &l);
    if (e) return e;
    char num[8];
    size_t at = put(out, cap, 0, num, (size_t)snprintf(num, sizeof num, "%u", (unsigned)l.seq));
    at = put(out, cap, at, "\t", 1);
    at = put(out, cap, at, l.verb, l.verb_len);
    at = put(out, cap, at, num, (size_t)snprintf(num, sizeof num, "\t%u", (unsigned)l.nargs));
    for (uint8_t i = 0; i < l.nargs && i < AB_MAX_ARGS; i++) {
        at = put(out, cap, at, "\t", 1);
        at = put(out, cap, at, l.args[i], l.arg_len[i]);
    }
    return 0;
}

/* ab_parse_command on nargs arguments -> 0 and the values, or the error code. */
extern "C" int shim_parse_command(const char *verb, size_t verb_len, const char *const *args,
                                  const uint8_t *arg_len, uint8_t nargs, uint8_t n_joints, int32_t *values) {
    AbError err;
    return ab_parse_command(verb, verb_len, args, arg_len, nargs, n_joints, values, &err);
}

/* LineReader over the bytes -> the number of items; per item its kind in kinds ("L"
 * line, "E" error, "S" e-stop), its code (errors) and its length (lines); the lines'
 * bytes one after the other in lines (room for n). */
extern "C" int shim_stream(const uint8_t *data, size_t n, char *kinds, uint8_t *codes, uint16_t *lens,
                           uint8_t *lines) {
    static LineReader reader;
    reader.reset();
    int k = 0;
    size_t at = 0;
    for (size_t i = 0; i < n; i++) {
        int item = reader.feed(data[i]);
        if (item == AB_ITEM_NONE) continue;
        kinds[k] = item == AB_ITEM_LINE ? 'L' : item == AB_ITEM_ERROR ? 'E' : 'S';
        codes[k] = item == AB_ITEM_ERROR ? reader.error() : 0;
        lens[k] = item == AB_ITEM_LINE ? (uint16_t)reader.length() : 0;
        if (item == AB_ITEM_LINE) {
            memcpy(lines + at, reader.line(), reader.length());
            at += reader.length();
        }
        k++;
    }
    return k;
}

/* One Session, as link.cpp keeps it. */
static Session g_sess;
extern "C" void shim_session_init(uint16_t sid, uint32_t epoch, int32_t hello_seq) { g_sess.init(sid, epoch, hello_seq); }
extern "C" int shim_session_classify(uint16_t seq, int read_only, int hello, int32_t proto, int32_t sid, int32_t epoch) {
    return g_sess.classify(seq, read_only != 0, hello != 0, proto, sid, epoch);
}
extern "C" void shim_session_accept(uint16_t seq, uint16_t sid, uint32_t epoch) { g_sess.accept(seq, sid, epoch); }
extern "C" void shim_session_record(uint16_t seq, uint8_t code) {
    SessAnswer a;
    memset(&a, 0, sizeof a);
    a.code = code;
    g_sess.record(seq, a);
}
extern "C" int shim_session_replay_code(uint16_t seq) { return g_sess.replay(seq)->code; }
/* session, epoch, hello_seq, expect */
extern "C" void shim_session_state(int64_t *out) {
    out[0] = g_sess.session;
    out[1] = g_sess.epoch;
    out[2] = g_sess.hello_seq;
    out[3] = g_sess.expect;
}
