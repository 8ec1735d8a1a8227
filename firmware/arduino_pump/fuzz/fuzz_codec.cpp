/* libFuzzer target: the line codec of proto.cpp alone (ab_decode, LineReader,
 * ab_parse_command, LineWriter), under ASan and UBSan.
 *
 * Input: a 5-byte header, then the bytes (the same layout as tests/fuzz_codecs.py's
 * "codec" target, so each corpus seeds the other):
 *   bytes 0..3  the receiver's epoch, little-endian, masked to 30 bits (0..EPOCH_MAX)
 *   byte 4      bit 0: max_len 192 (a board line) else 96 (a host line);
 *               bits 1..3: the board's joint count for ab_parse_command (0..7)
 *   the rest    one line for ab_decode, and the same bytes as a stream for LineReader
 * Invariants, checked by abort(): decode returns 0 or LONG/PARSE/CRC; a decoded verb
 * and its arguments lie inside the input, are non-empty and hold no space or "*";
 * ab_parse_command returns 0 (a known verb) or a code of the table; a decoded line written again by LineWriter (epoch 0) decodes to the
 * same seq, verb and arguments; every line LineReader gives fits a host line.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "proto.h"

static void require(bool ok, const char *what) {
    if (!ok) {
        fprintf(stderr, "fuzz invariant broken: %s\n", what);
        abort();
    }
}

static bool inside(const char *p, size_t n, const uint8_t *data, size_t size) {
    return (const uint8_t *)p >= data && (const uint8_t *)p + n <= data + size;
}

static void check_line(const uint8_t *line, size_t n, size_t max_len, uint32_t epoch, uint8_t n_joints) {
    AbLine l;
    int e = ab_decode(line, n, max_len, epoch, &l);
    require(e == 0 || e == AB_ERR_LONG || e == AB_ERR_PARSE || e == AB_ERR_CRC, "decode's code");
    if (e != 0) return;
    require(l.verb_len > 0 && inside(l.verb, l.verb_len, line, n), "verb inside the line");
    uint8_t kept = l.nargs < AB_MAX_ARGS ? l.nargs : AB_MAX_ARGS;
    for (uint8_t i = 0; i < kept; i++) {
        require(l.arg_len[i] > 0 && inside(l.args[i], l.arg_len[i], line, n), "argument inside the line");
        require(!memchr(l.args[i], ' ', l.arg_len[i]) && !memchr(l.args[i], '*', l.arg_len[i]),
                "argument without space or *");
    }
    int32_t values[AB_MAX_ARGS];
    AbError err;
    int code = ab_parse_command(l.verb, l.verb_len, l.args, l.arg_len, l.nargs, n_joints, values, &err);
    require(code >= 0 && code < AB_N_ERRORS && code == err.code, "parse_command's code");
    require(memchr(err.detail, 0, AB_DETAIL_MAX) != NULL, "error detail terminated");
    if (code == 0) require(ab_find_verb(l.verb, l.verb_len) >= 0, "an accepted command has a known verb");
    /* the encoder and the decoder agree: seq verb args again, CRC from epoch 0 */
    if (l.nargs <= AB_MAX_ARGS) {
        LineWriter w;
        w.begin(l.seq);
        w.str(l.verb, l.verb_len);
        for (uint8_t i = 0; i < kept; i++) w.str(l.args[i], l.arg_len[i]);
        size_t m;
        const uint8_t *out = w.finish(&m);
        require(m <= AB_MAX_BOARD_LINE, "a written line fits");   /* its body came from a line that fit */
        {
            AbLine r;
            require(ab_decode(out, m, AB_MAX_BOARD_LINE, 0, &r) == 0, "a written line decodes");
            require(r.seq == l.seq && r.verb_len == l.verb_len && !memcmp(r.verb, l.verb, l.verb_len) &&
                        r.nargs == l.nargs, "written line: same seq, verb, count");
            for (uint8_t i = 0; i < kept; i++)
                require(r.arg_len[i] == l.arg_len[i] && !memcmp(r.args[i], l.args[i], l.arg_len[i]),
                        "written line: same arguments");
        }
    }
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    if (size < 5 || size > 4096) return 0;
    uint32_t epoch = ((uint32_t)data[0] | (uint32_t)data[1] << 8 | (uint32_t)data[2] << 16 |
                      (uint32_t)data[3] << 24) & 0x3FFFFFFFu;
    size_t max_len = (data[4] & 1) ? AB_MAX_BOARD_LINE : AB_MAX_HOST_LINE;
    uint8_t n_joints = (uint8_t)((data[4] >> 1) & 7);
    const uint8_t *line = data + 5;
    size_t n = size - 5;
    /* a copy of exactly n bytes on the heap, so ASan sees any read past the line */
    uint8_t *copy = (uint8_t *)malloc(n ? n : 1);
    memcpy(copy, line, n);
    check_line(copy, n, max_len, epoch, n_joints);
    LineReader reader;
    for (size_t i = 0; i < n; i++) {
        int item = reader.feed(copy[i]);
        if (item == AB_ITEM_LINE) {
            require(reader.length() > 0 && reader.length() <= AB_MAX_HOST_LINE - 1, "a line fits");
            check_line(reader.line(), reader.length(), AB_MAX_HOST_LINE, epoch, n_joints);
        } else if (item == AB_ITEM_ERROR) {
            require(reader.error() == AB_ERR_LONG || reader.error() == AB_ERR_PARSE, "stream error code");
        }
    }
    free(copy);
    return 0;
}
