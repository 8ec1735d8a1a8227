/* Protocol v2 codec in C++ (docs/protocol.md §1-§3), the twin of
 * firmware/common/proto.py, checked by the same vectors (tests/vectors/lines.json).
 *
 *   ab_crc32(data, n, epoch)   CRC-32/ISO-HDLC continued from the epoch (zlib.crc32)
 *   ab_decode(...)             one host line -> seq, verb, args (LONG, PARSE, CRC, PARSE)
 *   LineReader                 bytes -> lines, stream errors and the e-stop byte
 *   ab_parse_command(...)      a command's arguments, checked in the spec's order
 *   LineWriter                 one board line: fields, then "*CRC\n" from epoch 0
 *
 * The verbs, ranges, codes and constants are the generated protodef.h. Pure: no
 * I/O, no allocation; every buffer has a fixed bound.
 */
#ifndef PUMP_PROTO_H
#define PUMP_PROTO_H

#include <stddef.h>
#include <stdint.h>

#include "protodef.h"

#define AB_MAX_ARGS 16       /* pointers kept per line; more are counted (ARGS later) */
#define AB_DETAIL_MAX 12     /* an error detail: an argument's name or a number */

uint32_t ab_crc32(const uint8_t *data, size_t n, uint32_t epoch);

/* The body's second space-separated field is exactly HELLO: its CRC uses epoch 0. */
bool ab_is_hello(const char *body, size_t n);

struct AbLine {
    uint16_t seq;
    const char *verb;
    uint8_t verb_len;
    uint8_t nargs;                       /* all arguments, even past AB_MAX_ARGS */
    const char *args[AB_MAX_ARGS];
    uint8_t arg_len[AB_MAX_ARGS];
};

/* Decodes a line (with or without its LF, a CR before the LF ignored) whose bytes
 * stay valid while `out` is used. -> 0, or AB_ERR_LONG / AB_ERR_PARSE / AB_ERR_CRC. */
int ab_decode(const uint8_t *line, size_t n, size_t max_len, uint32_t epoch, AbLine *out);

/* A decimal integer written as the protocol writes it (no "+", no leading zeros,
 * no "-0"). Any length: a value past +-2^31 saturates (out of every range).
 * -> false when the form is wrong. */
bool ab_parse_int(const char *s, size_t n, int32_t *value);

/* The index of verb in AB_COMMANDS, or -1. */
int ab_find_verb(const char *verb, size_t n);

struct AbError {
    uint8_t code;                        /* 0: none */
    char detail[AB_DETAIL_MAX];          /* "" when none */
};

/* Checks a command's arguments for an n-joint board: VERB, count (ARGS), every
 * argument's form (ARGS), each range in turn (RANGE, detail the joint number of a
 * joint value or the argument's name), the cross-argument rule (RANGE). values gets
 * the integers (room for AB_MAX_ARGS). -> 0 or the code, also left in err. */
int ab_parse_command(const char *verb, size_t verb_len, const char *const *args,
                     const uint8_t *arg_len, uint8_t nargs, uint8_t n_joints,
                     int32_t *values, AbError *err);

/* ------------------------------------------------------------------ the byte stream */
enum { AB_ITEM_NONE = 0, AB_ITEM_LINE, AB_ITEM_ERROR, AB_ITEM_ESTOP };

class LineReader {
public:
    LineReader() : len_(0), mode_(0) {}
    void reset() { len_ = 0; mode_ = 0; }
    /* One byte -> AB_ITEM_*; a LINE is in line()/length() (LF stripped, a CR before
     * it kept) until the next feed; an ERROR's code is in error(). */
    int feed(uint8_t b);
    const uint8_t *line() const { return buf_; }
    size_t length() const { return len_line_; }
    uint8_t error() const { return err_; }

private:
    uint8_t buf_[AB_MAX_HOST_LINE];
    uint8_t len_;
    uint8_t mode_;
    uint8_t len_line_;
    uint8_t err_;
};

/* ------------------------------------------------------------------ board lines */
class LineWriter {
public:
    /* Starts a line with the board seq. Fields that would make it longer than
     * AB_MAX_BOARD_LINE are dropped (never happens for the lines this board sends). */
    void begin(uint16_t bseq);
    void str(const char *s);
    void str(const char *s, size_t n);
    void num(int32_t v);
    void wid(int32_t v) { if (v < 0) str("-"); else num(v); }   /* "-": no id */
    /* Appends "*CRC\n" (epoch 0) -> the whole line. */
    const uint8_t *finish(size_t *n);

private:
    char buf_[AB_MAX_BOARD_LINE + 1];
    uint8_t len_;
    bool full_;
};

#endif
