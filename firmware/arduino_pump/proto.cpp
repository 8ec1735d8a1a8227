/* Protocol v2 codec (proto.h). The checks follow firmware/common/proto.py line by
 * line, in the order of docs/protocol.md §1 and §3.
 *
 * CRC: a 16-entry (nibble) table, 64 bytes of flash (PROGMEM on the AVR): two table
 * steps per byte. Against the table-free loop (8 shift/xor steps of 32 bits per
 * byte, ~1 KB less than nothing but ~4x slower on an 8-bit core) it costs 64 bytes;
 * against the 1 KiB byte table it saves 960 bytes of flash for one more step per
 * byte. A 96-byte line is checked in a fraction of a millisecond at 16 MHz.
 */
#include "proto.h"

#include <string.h>

#ifdef __AVR__
#include <avr/pgmspace.h>
#define CRC_TABLE_ATTR PROGMEM
#define CRC_ENTRY(i) pgm_read_dword(&kCrcNibble[i])
#else
#define CRC_TABLE_ATTR
#define CRC_ENTRY(i) kCrcNibble[i]
#endif

/* kCrcNibble[i] = the reflected CRC step of the 4-bit value i (poly 0xEDB88320). */
static const uint32_t kCrcNibble[16] CRC_TABLE_ATTR = {
    0x00000000UL, 0x1DB71064UL, 0x3B6E20C8UL, 0x26D930ACUL, 0x76DC4190UL, 0x6B6B51F4UL,
    0x4DB26158UL, 0x5005713CUL, 0xEDB88320UL, 0xF00F9344UL, 0xD6D6A3E8UL, 0xCB61B38CUL,
    0x9B64C2B0UL, 0x86D3D2D4UL, 0xA00AE278UL, 0xBDBDF21CUL,
};

uint32_t ab_crc32(const uint8_t *data, size_t n, uint32_t epoch) {
    uint32_t crc = ~epoch;
    for (size_t i = 0; i < n; i++) {
        crc ^= data[i];
        crc = (crc >> 4) ^ CRC_ENTRY(crc & 15u);
        crc = (crc >> 4) ^ CRC_ENTRY(crc & 15u);
    }
    return ~crc;
}

bool ab_is_hello(const char *body, size_t n) {
    const char *sp = (const char *)memchr(body, ' ', n);
    if (sp == NULL) return false;
    size_t rest = n - (size_t)(sp + 1 - body);
    if (rest < 5 || memcmp(sp + 1, "HELLO", 5) != 0) return false;
    return rest == 5 || sp[6] == ' ';
}

bool ab_parse_int(const char *s, size_t n, int32_t *value) {
    size_t i = 0;
    bool neg = false;
    if (n > 0 && s[0] == '-') {
        neg = true;
        i = 1;
    }
    if (i >= n) return false;
    if (s[i] == '0' && (neg || n - i > 1)) return false;   /* "-0", leading zeros */
    int64_t v = 0;
    for (; i < n; i++) {
        char c = s[i];
        if (c < '0' || c > '9') return false;
        if (v <= 0x7FFFFFFFLL) v = v * 10 + (c - '0');      /* past 2^31: saturates below */
    }
    if (v > 0x7FFFFFFFLL) v = 0x7FFFFFFFLL;
    *value = (int32_t)(neg ? -v : v);
    return true;
}

static int hexval(uint8_t c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

int ab_decode(const uint8_t *line, size_t n, size_t max_len, uint32_t epoch, AbLine *out) {
    if (n && line[n - 1] == '\n') n--;
    if (n + 1 > max_len) return AB_ERR_LONG;
    if (n && line[n - 1] == '\r') n--;
    if (n < 9 || line[n - 9] != '*') return AB_ERR_PARSE;
    for (size_t i = 0; i < n; i++)
        if (line[i] < 0x20 || line[i] > 0x7E) return AB_ERR_PARSE;
    uint32_t want = 0;
    for (size_t i = n - 8; i < n; i++) {
        int h = hexval(line[i]);
        if (h < 0) return AB_ERR_PARSE;
        want = (want << 4) | (uint32_t)h;
    }
    const char *body = (const char *)line;
    size_t bn = n - 9;
    if (ab_is_hello(body, bn)) epoch = AB_HELLO_EPOCH;
    if (ab_crc32(line, bn, epoch) != want) return AB_ERR_CRC;
    /* split on single spaces: seq, verb, args; an empty field is a PARSE error */
    size_t field = 0, start = 0;
    out->nargs = 0;
    for (size_t i = 0; i <= bn; i++) {
        if (i < bn && body[i] != ' ') continue;
        const char *f = body + start;
        size_t fl = i - start;
        if (field == 0) {
            int32_t seq;
            if (fl > 5 || !ab_parse_int(f, fl, &seq) || seq < 0 || seq > 0xFFFF) return AB_ERR_PARSE;
            out->seq = (uint16_t)seq;
        } else if (field == 1) {
            if (fl < 1 || fl > 8) return AB_ERR_PARSE;
            for (size_t k = 0; k < fl; k++)
                if (f[k] < 'A' || f[k] > 'Z') return AB_ERR_PARSE;
            out->verb = f;
            out->verb_len = (uint8_t)fl;
        } else {
            if (fl == 0) return AB_ERR_PARSE;   /* a double or trailing space */
            if (memchr(f, '*', fl) != NULL) return AB_ERR_PARSE;
            if (out->nargs < AB_MAX_ARGS) {
                out->args[out->nargs] = f;
                out->arg_len[out->nargs] = (uint8_t)fl;
            }
            if (out->nargs < 255) out->nargs++;
        }
        field++;
        start = i + 1;
    }
    if (field < 2) return AB_ERR_PARSE;
    return 0;
}

/* ------------------------------------------------------------------ commands */

int ab_find_verb(const char *verb, size_t n) {
    for (int i = 0; i < AB_N_COMMANDS; i++) {
        const char *v = AB_COMMANDS[i].verb;
        if (strlen(v) == n && memcmp(v, verb, n) == 0) return i;
    }
    return -1;
}

static void set_detail_num(AbError *err, int32_t v) {
    char tmp[AB_DETAIL_MAX];
    size_t k = 0;
    uint32_t u = v < 0 ? (uint32_t)(-(int64_t)v) : (uint32_t)v;
    do {
        tmp[k++] = (char)('0' + u % 10);
        u /= 10;
    } while (u && k < sizeof tmp - 2);
    size_t o = 0;
    if (v < 0) err->detail[o++] = '-';
    while (k) err->detail[o++] = tmp[--k];
    err->detail[o] = 0;
}

static void set_detail_str(AbError *err, const char *s) {
    strncpy(err->detail, s, AB_DETAIL_MAX - 1);
    err->detail[AB_DETAIL_MAX - 1] = 0;
}

static int fail(AbError *err, int code) {
    err->code = (uint8_t)code;
    return code;
}

int ab_parse_command(const char *verb, size_t verb_len, const char *const *args,
                     const uint8_t *arg_len, uint8_t nargs, uint8_t n_joints,
                     int32_t *values, AbError *err) {
    err->code = 0;
    err->detail[0] = 0;
    int vi = ab_find_verb(verb, verb_len);
    if (vi < 0) return fail(err, AB_ERR_VERB);
    const ab_command &c = AB_COMMANDS[vi];
    bool has_q = c.n_args > 0 && c.args[c.n_args - 1].kind == AB_ARG_Q;
    unsigned want = has_q ? (unsigned)(c.n_args - 1 + n_joints) : c.n_args;
    if (nargs != want || want > AB_MAX_ARGS) return fail(err, AB_ERR_ARGS);
    for (unsigned i = 0; i < want; i++)
        if (!ab_parse_int(args[i], arg_len[i], &values[i])) return fail(err, AB_ERR_ARGS);
    for (unsigned i = 0; i < want; i++) {
        unsigned si = i < c.n_args ? i : (unsigned)(c.n_args - 1);
        const ab_arg_spec &s = c.args[si];
        int32_t lo = s.lo, hi = s.hi;
        if (s.kind == AB_ARG_JOINT) {
            lo = 1;
            hi = n_joints;
        }
        if (values[i] < lo || values[i] > hi) {
            if (has_q && i >= (unsigned)(c.n_args - 1))
                set_detail_num(err, (int32_t)(i - (c.n_args - 1) + 1));
            else
                set_detail_str(err, s.name);
            return fail(err, AB_ERR_RANGE);
        }
    }
    if (c.min_arg >= 0 && c.max_arg >= 0 && values[c.min_arg] > values[c.max_arg]) {
        set_detail_str(err, c.args[c.min_arg].name);
        return fail(err, AB_ERR_RANGE);
    }
    return 0;
}

/* ------------------------------------------------------------------ the byte stream */

enum { MODE_NORMAL = 0, MODE_DROP_LONG = 1, MODE_DROP_SILENT = 2 };

int LineReader::feed(uint8_t b) {
    if (b == AB_ESTOP_BYTE) {
        if (len_ || mode_ != MODE_NORMAL) {
            mode_ = MODE_DROP_SILENT;
            len_ = 0;
        }
        return AB_ITEM_ESTOP;
    }
    if (b == '\n') {
        int item = AB_ITEM_NONE;
        if (mode_ == MODE_DROP_LONG) {
            err_ = AB_ERR_LONG;
            item = AB_ITEM_ERROR;
        } else if (mode_ == MODE_NORMAL) {
            if (len_) {
                len_line_ = len_;
                item = AB_ITEM_LINE;
            } else {
                err_ = AB_ERR_PARSE;
                item = AB_ITEM_ERROR;
            }
        }
        len_ = 0;
        mode_ = MODE_NORMAL;
        return item;
    }
    if (mode_ != MODE_NORMAL) return AB_ITEM_NONE;
    if (len_ + 1 > AB_MAX_HOST_LINE - 1) {   /* no room left for the LF */
        mode_ = MODE_DROP_LONG;
        len_ = 0;
    } else {
        buf_[len_++] = b;
    }
    return AB_ITEM_NONE;
}

/* ------------------------------------------------------------------ board lines */

void LineWriter::begin(uint16_t bseq) {
    len_ = 0;
    full_ = false;
    num(bseq);
}

void LineWriter::str(const char *s, size_t n) {
    size_t room = AB_MAX_BOARD_LINE - 10;   /* "*XXXXXXXX\n" */
    size_t need = (len_ ? 1 : 0) + n;
    if (full_ || len_ + need > room) {
        full_ = true;
        return;
    }
    if (len_) buf_[len_++] = ' ';
    memcpy(buf_ + len_, s, n);
    len_ = (uint8_t)(len_ + n);
}

void LineWriter::str(const char *s) { str(s, strlen(s)); }

void LineWriter::num(int32_t v) {
    char tmp[12];
    size_t k = 0;
    uint32_t u = v < 0 ? (uint32_t)(-(int64_t)v) : (uint32_t)v;
    do {
        tmp[sizeof tmp - 1 - k++] = (char)('0' + u % 10);
        u /= 10;
    } while (u);
    if (v < 0) tmp[sizeof tmp - 1 - k++] = '-';
    str(tmp + sizeof tmp - k, k);
}

const uint8_t *LineWriter::finish(size_t *n) {
    static const char hex[] = "0123456789ABCDEF";
    uint32_t crc = ab_crc32((const uint8_t *)buf_, len_, 0);
    buf_[len_++] = '*';
    for (int i = 7; i >= 0; i--) buf_[len_++] = hex[(crc >> (4 * i)) & 15];
    buf_[len_++] = '\n';
    *n = len_;
    return (const uint8_t *)buf_;
}
