/* Protocol v2 codec (proto.h). The checks follow firmware/common/proto.py line by
 * line, in the order of docs/protocol.md §1 and §3.
 *
 * CRC: the 256-entry byte table, 1 KiB of flash (PROGMEM on the AVR; the Mega has
 * 248 KiB): one table step per byte, a byte-wide shift. The 16-entry nibble table it
 * replaced took two steps of 4-bit shifts of 32 bits per byte, about 3x slower on the
 * 8-bit core: checking each host line and framing each reply cost ~0.4 ms of the ~3 ms
 * a W line lasts at 115200 baud, and a stream at line rate left the control period
 * late (docs/pump.md, "CPU time per line").
 */
#include "proto.h"

#include <string.h>

#ifdef __AVR__
#include <avr/pgmspace.h>
#define FLASH_TABLE PROGMEM
#define TABLE_DWORD(t, i) pgm_read_dword(&(t)[i])
#else
#define FLASH_TABLE
#define TABLE_DWORD(t, i) ((t)[i])
#endif

/* kCrcTable[i] = the reflected CRC-32 of the byte i (poly 0xEDB88320), 8 steps. */
static const uint32_t kCrcTable[256] FLASH_TABLE = {
    0x00000000UL, 0x77073096UL, 0xEE0E612CUL, 0x990951BAUL, 0x076DC419UL, 0x706AF48FUL,
    0xE963A535UL, 0x9E6495A3UL, 0x0EDB8832UL, 0x79DCB8A4UL, 0xE0D5E91EUL, 0x97D2D988UL,
    0x09B64C2BUL, 0x7EB17CBDUL, 0xE7B82D07UL, 0x90BF1D91UL, 0x1DB71064UL, 0x6AB020F2UL,
    0xF3B97148UL, 0x84BE41DEUL, 0x1ADAD47DUL, 0x6DDDE4EBUL, 0xF4D4B551UL, 0x83D385C7UL,
    0x136C9856UL, 0x646BA8C0UL, 0xFD62F97AUL, 0x8A65C9ECUL, 0x14015C4FUL, 0x63066CD9UL,
    0xFA0F3D63UL, 0x8D080DF5UL, 0x3B6E20C8UL, 0x4C69105EUL, 0xD56041E4UL, 0xA2677172UL,
    0x3C03E4D1UL, 0x4B04D447UL, 0xD20D85FDUL, 0xA50AB56BUL, 0x35B5A8FAUL, 0x42B2986CUL,
    0xDBBBC9D6UL, 0xACBCF940UL, 0x32D86CE3UL, 0x45DF5C75UL, 0xDCD60DCFUL, 0xABD13D59UL,
    0x26D930ACUL, 0x51DE003AUL, 0xC8D75180UL, 0xBFD06116UL, 0x21B4F4B5UL, 0x56B3C423UL,
    0xCFBA9599UL, 0xB8BDA50FUL, 0x2802B89EUL, 0x5F058808UL, 0xC60CD9B2UL, 0xB10BE924UL,
    0x2F6F7C87UL, 0x58684C11UL, 0xC1611DABUL, 0xB6662D3DUL, 0x76DC4190UL, 0x01DB7106UL,
    0x98D220BCUL, 0xEFD5102AUL, 0x71B18589UL, 0x06B6B51FUL, 0x9FBFE4A5UL, 0xE8B8D433UL,
    0x7807C9A2UL, 0x0F00F934UL, 0x9609A88EUL, 0xE10E9818UL, 0x7F6A0DBBUL, 0x086D3D2DUL,
    0x91646C97UL, 0xE6635C01UL, 0x6B6B51F4UL, 0x1C6C6162UL, 0x856530D8UL, 0xF262004EUL,
    0x6C0695EDUL, 0x1B01A57BUL, 0x8208F4C1UL, 0xF50FC457UL, 0x65B0D9C6UL, 0x12B7E950UL,
    0x8BBEB8EAUL, 0xFCB9887CUL, 0x62DD1DDFUL, 0x15DA2D49UL, 0x8CD37CF3UL, 0xFBD44C65UL,
    0x4DB26158UL, 0x3AB551CEUL, 0xA3BC0074UL, 0xD4BB30E2UL, 0x4ADFA541UL, 0x3DD895D7UL,
    0xA4D1C46DUL, 0xD3D6F4FBUL, 0x4369E96AUL, 0x346ED9FCUL, 0xAD678846UL, 0xDA60B8D0UL,
    0x44042D73UL, 0x33031DE5UL, 0xAA0A4C5FUL, 0xDD0D7CC9UL, 0x5005713CUL, 0x270241AAUL,
    0xBE0B1010UL, 0xC90C2086UL, 0x5768B525UL, 0x206F85B3UL, 0xB966D409UL, 0xCE61E49FUL,
    0x5EDEF90EUL, 0x29D9C998UL, 0xB0D09822UL, 0xC7D7A8B4UL, 0x59B33D17UL, 0x2EB40D81UL,
    0xB7BD5C3BUL, 0xC0BA6CADUL, 0xEDB88320UL, 0x9ABFB3B6UL, 0x03B6E20CUL, 0x74B1D29AUL,
    0xEAD54739UL, 0x9DD277AFUL, 0x04DB2615UL, 0x73DC1683UL, 0xE3630B12UL, 0x94643B84UL,
    0x0D6D6A3EUL, 0x7A6A5AA8UL, 0xE40ECF0BUL, 0x9309FF9DUL, 0x0A00AE27UL, 0x7D079EB1UL,
    0xF00F9344UL, 0x8708A3D2UL, 0x1E01F268UL, 0x6906C2FEUL, 0xF762575DUL, 0x806567CBUL,
    0x196C3671UL, 0x6E6B06E7UL, 0xFED41B76UL, 0x89D32BE0UL, 0x10DA7A5AUL, 0x67DD4ACCUL,
    0xF9B9DF6FUL, 0x8EBEEFF9UL, 0x17B7BE43UL, 0x60B08ED5UL, 0xD6D6A3E8UL, 0xA1D1937EUL,
    0x38D8C2C4UL, 0x4FDFF252UL, 0xD1BB67F1UL, 0xA6BC5767UL, 0x3FB506DDUL, 0x48B2364BUL,
    0xD80D2BDAUL, 0xAF0A1B4CUL, 0x36034AF6UL, 0x41047A60UL, 0xDF60EFC3UL, 0xA867DF55UL,
    0x316E8EEFUL, 0x4669BE79UL, 0xCB61B38CUL, 0xBC66831AUL, 0x256FD2A0UL, 0x5268E236UL,
    0xCC0C7795UL, 0xBB0B4703UL, 0x220216B9UL, 0x5505262FUL, 0xC5BA3BBEUL, 0xB2BD0B28UL,
    0x2BB45A92UL, 0x5CB36A04UL, 0xC2D7FFA7UL, 0xB5D0CF31UL, 0x2CD99E8BUL, 0x5BDEAE1DUL,
    0x9B64C2B0UL, 0xEC63F226UL, 0x756AA39CUL, 0x026D930AUL, 0x9C0906A9UL, 0xEB0E363FUL,
    0x72076785UL, 0x05005713UL, 0x95BF4A82UL, 0xE2B87A14UL, 0x7BB12BAEUL, 0x0CB61B38UL,
    0x92D28E9BUL, 0xE5D5BE0DUL, 0x7CDCEFB7UL, 0x0BDBDF21UL, 0x86D3D2D4UL, 0xF1D4E242UL,
    0x68DDB3F8UL, 0x1FDA836EUL, 0x81BE16CDUL, 0xF6B9265BUL, 0x6FB077E1UL, 0x18B74777UL,
    0x88085AE6UL, 0xFF0F6A70UL, 0x66063BCAUL, 0x11010B5CUL, 0x8F659EFFUL, 0xF862AE69UL,
    0x616BFFD3UL, 0x166CCF45UL, 0xA00AE278UL, 0xD70DD2EEUL, 0x4E048354UL, 0x3903B3C2UL,
    0xA7672661UL, 0xD06016F7UL, 0x4969474DUL, 0x3E6E77DBUL, 0xAED16A4AUL, 0xD9D65ADCUL,
    0x40DF0B66UL, 0x37D83BF0UL, 0xA9BCAE53UL, 0xDEBB9EC5UL, 0x47B2CF7FUL, 0x30B5FFE9UL,
    0xBDBDF21CUL, 0xCABAC28AUL, 0x53B39330UL, 0x24B4A3A6UL, 0xBAD03605UL, 0xCDD70693UL,
    0x54DE5729UL, 0x23D967BFUL, 0xB3667A2EUL, 0xC4614AB8UL, 0x5D681B02UL, 0x2A6F2B94UL,
    0xB40BBE37UL, 0xC30C8EA1UL, 0x5A05DF1BUL, 0x2D02EF8DUL,
};

uint32_t ab_crc32(const uint8_t *data, size_t n, uint32_t epoch) {
    uint32_t crc = ~epoch;
    for (size_t i = 0; i < n; i++) {
        crc = (crc >> 8) ^ TABLE_DWORD(kCrcTable, (uint8_t)(crc ^ data[i]));
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
    /* 32 bits, saturating at 2^31 - 1 (a 64-bit multiply per digit cost the AVR ~35 us) */
    uint32_t v = 0;
    for (; i < n; i++) {
        char c = s[i];
        if (c < '0' || c > '9') return false;
        uint8_t d = (uint8_t)(c - '0');
        if (v > 214748364UL || (v == 214748364UL && d > 7)) v = 0x7FFFFFFFUL;   /* past 2^31 - 1 */
        else v = v * 10u + d;
    }
    *value = neg ? -(int32_t)v : (int32_t)v;
    return true;
}

/* The decimal digits of u into out (no terminator); returns how many. Subtracting
   powers of ten: the AVR has no divider, and u % 10, u / 10 on 32 bits cost ~70 us a
   digit pair there (a 5-digit number ~130 us, three or four of them in each reply). */
static uint8_t decimal(uint32_t u, char *out) {
    static const uint32_t kPow10[9] FLASH_TABLE = {1000000000UL, 100000000UL, 10000000UL, 1000000UL,
                                                      100000UL, 10000UL, 1000UL, 100UL, 10UL};
    uint8_t k = 0;
    for (uint8_t p = 0; p < 9; p++) {
        uint32_t m = TABLE_DWORD(kPow10, p);
        if (u < m && k == 0) continue;   /* no leading zeros */
        char d = '0';
        while (u >= m) {
            u -= m;
            d++;
        }
        out[k++] = d;
    }
    out[k++] = (char)('0' + u);
    return k;
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
    if (n >= AB_VERB_LEN) return -1;
    for (int i = 0; i < AB_N_COMMANDS; i++) {
        char v[AB_VERB_LEN];
        AB_MEMCPY_P(v, AB_COMMANDS[i].verb, sizeof v);   /* the table is in flash on AVR */
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
    ab_command c;
    AB_MEMCPY_P(&c, &AB_COMMANDS[vi], sizeof c);   /* the tables are in flash on AVR: copy a row */
    ab_arg_spec s;
    bool has_q = false;
    if (c.n_args > 0) {
        AB_MEMCPY_P(&s, &c.args[c.n_args - 1], sizeof s);
        has_q = s.kind == AB_ARG_Q;
    }
    unsigned want = has_q ? (unsigned)(c.n_args - 1 + n_joints) : c.n_args;
    if (nargs != want || want > AB_MAX_ARGS) return fail(err, AB_ERR_ARGS);
    for (unsigned i = 0; i < want; i++)
        if (!ab_parse_int(args[i], arg_len[i], &values[i])) return fail(err, AB_ERR_ARGS);
    for (unsigned i = 0; i < want; i++) {
        unsigned si = i < c.n_args ? i : (unsigned)(c.n_args - 1);
        AB_MEMCPY_P(&s, &c.args[si], sizeof s);
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
        AB_MEMCPY_P(&s, &c.args[c.min_arg], sizeof s);
        set_detail_str(err, s.name);
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
    char tmp[11];
    uint8_t k = 0;
    uint32_t u = (uint32_t)v;
    if (v < 0) {
        tmp[k++] = '-';
        u = 0u - u;   /* |v|, INT32_MIN included */
    }
    k = (uint8_t)(k + decimal(u, tmp + k));
    str(tmp, k);
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
