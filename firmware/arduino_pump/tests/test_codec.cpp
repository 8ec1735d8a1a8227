/* The codec against every case of the shared vectors (tests/vectors/lines.json, as
 * converted by tools/vectors2txt.py), mirroring tests/firmware/test_fw_proto.py,
 * plus the codec's own edge cases. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "check.h"
#include "proto.h"

static std::string unhex(const std::string &t) {
    std::string out;
    for (size_t i = 1; i + 1 < t.size(); i += 2) out += (char)strtol(t.substr(i, 2).c_str(), NULL, 16);
    return out;
}

static std::string frame(const std::string &body, uint32_t epoch) {
    char crc[16];
    snprintf(crc, sizeof crc, "*%08X\n",
             (unsigned)ab_crc32((const uint8_t *)body.data(), body.size(), ab_is_hello(body.data(), body.size()) ? 0 : epoch));
    return body + crc;
}

static int decode(const std::string &l, size_t max, uint32_t epoch, AbLine *out) {
    return ab_decode((const uint8_t *)l.data(), l.size(), max, epoch, out);
}

static int parse(const char *verb, std::vector<std::string> args, uint8_t n, int32_t *v, AbError *e) {
    const char *p[AB_MAX_ARGS];
    uint8_t len[AB_MAX_ARGS];
    for (size_t i = 0; i < args.size() && i < AB_MAX_ARGS; i++) {
        p[i] = args[i].data();
        len[i] = (uint8_t)args[i].size();
    }
    return ab_parse_command(verb, strlen(verb), p, len, (uint8_t)args.size(), n, v, e);
}

static void vectors(const char *path) {
    std::ifstream f(path);
    CHECK_MSG(f.good(), "cannot read %s", path);
    std::string rec;
    int counts[8] = {0};
    while (std::getline(f, rec)) {
        std::istringstream in(rec);
        std::string kind;
        in >> kind;
        if (kind == "meta") {
            int v, mh, mb, es;
            in >> v >> mh >> mb >> es;
            CHECK(v == AB_PROTOCOL_VERSION && mh == AB_MAX_HOST_LINE && mb == AB_MAX_BOARD_LINE && es == AB_ESTOP_BYTE);
            counts[0]++;
        } else if (kind == "crc") {
            std::string d;
            unsigned long epoch, crc;
            in >> d >> epoch >> crc;
            std::string data = unhex(d);
            CHECK_MSG(ab_crc32((const uint8_t *)data.data(), data.size(), (uint32_t)epoch) == (uint32_t)crc, "%s", rec.c_str());
            counts[1]++;
        } else if (kind == "good") {
            std::string l, verb;
            unsigned long epoch;
            int seq, nargs;
            in >> l >> epoch >> seq >> verb >> nargs;
            std::string line = unhex(l);
            AbLine out;
            int e = decode(line, AB_MAX_BOARD_LINE, (uint32_t)epoch, &out);
            CHECK_MSG(e == 0 && out.seq == seq && std::string(out.verb, out.verb_len) == unhex(verb) && out.nargs == nargs,
                      "%s -> %d", rec.c_str(), e);
            for (int i = 0; i < nargs && i < AB_MAX_ARGS && e == 0; i++) {
                std::string a;
                in >> a;
                CHECK(std::string(out.args[i], out.arg_len[i]) == unhex(a));
            }
            if (epoch == 0 && e == 0) {   /* board lines are epoch 0: the writer gives the same bytes */
                LineWriter w;
                w.begin(out.seq);
                w.str(out.verb, out.verb_len);
                for (int i = 0; i < nargs && i < AB_MAX_ARGS; i++) w.str(out.args[i], out.arg_len[i]);
                size_t n;
                const uint8_t *d = w.finish(&n);
                std::string want = line;
                if (want.size() >= 2 && want.compare(want.size() - 2, 2, "\r\n") == 0) want = want.substr(0, want.size() - 2) + "\n";
                if (want.empty() || want[want.size() - 1] != '\n') want += "\n";
                CHECK_MSG(std::string((const char *)d, n) == want, "%s", rec.c_str());
            }
            counts[2]++;
        } else if (kind == "bad") {
            std::string l;
            unsigned long epoch;
            int code;
            in >> l >> epoch >> code;
            AbLine out;
            int e = decode(unhex(l), AB_MAX_HOST_LINE, (uint32_t)epoch, &out);
            CHECK_MSG(e == code, "%s -> %d", rec.c_str(), e);
            counts[3]++;
        } else if (kind == "cmd") {
            std::string verb;
            int n, code, nargs, nvals;
            in >> verb >> n >> code >> nargs;
            std::vector<std::string> args;
            for (int i = 0; i < nargs; i++) {
                std::string a;
                in >> a;
                args.push_back(unhex(a));
            }
            in >> nvals;
            int32_t v[AB_MAX_ARGS];
            AbError err;
            std::string vs = unhex(verb);
            int e = parse(vs.c_str(), args, (uint8_t)n, v, &err);
            CHECK_MSG(e == code, "%s -> %d", rec.c_str(), e);
            for (int i = 0; i < nvals && e == 0; i++) {
                long x;
                in >> x;
                CHECK_MSG(v[i] == x, "%s value %d", rec.c_str(), i);
            }
            counts[4]++;
        } else if (kind == "stream") {
            std::string b;
            int nitems;
            in >> b >> nitems;
            std::string bytes = unhex(b);
            std::vector<std::string> want, got;
            for (int i = 0; i < nitems; i++) {
                std::string it;
                in >> it;
                want.push_back(it[0] == 'L' ? "L:" + unhex(it.substr(2)) : it);
            }
            LineReader r;
            for (size_t i = 0; i < bytes.size(); i++) {
                int item = r.feed((uint8_t)bytes[i]);
                if (item == AB_ITEM_LINE) got.push_back("L:" + std::string((const char *)r.line(), r.length()));
                else if (item == AB_ITEM_ERROR) got.push_back("E:" + std::to_string(r.error()));
                else if (item == AB_ITEM_ESTOP) got.push_back("S");
            }
            CHECK_MSG(got == want, "%s", rec.c_str());
            counts[5]++;
        } else if (kind == "example") {
            std::string side, l;
            unsigned long epoch;
            in >> side >> l >> epoch;
            AbLine out;
            if (side == "host") {
                std::string line = unhex(l);   /* out points into it */
                int e = decode(line, AB_MAX_HOST_LINE, (uint32_t)epoch, &out);
                CHECK_MSG(e == 0, "%s", rec.c_str());
                int32_t v[AB_MAX_ARGS];
                AbError err;
                if (e == 0)
                    CHECK_MSG(ab_parse_command(out.verb, out.verb_len, out.args, out.arg_len, out.nargs, 3, v, &err) == 0,
                              "%s", rec.c_str());
            } else {
                CHECK_MSG(decode(unhex(l), AB_MAX_BOARD_LINE, 0, &out) == 0, "%s", rec.c_str());
            }
            counts[6]++;
        }
    }
    printf("vectors: meta %d, crc %d, good %d, bad %d, commands %d, streams %d, example %d\n", counts[0], counts[1],
           counts[2], counts[3], counts[4], counts[5], counts[6]);
    CHECK(counts[0] == 1 && counts[1] > 0 && counts[2] > 0 && counts[3] > 0 && counts[4] > 800 && counts[5] > 0 && counts[6] > 0);
}

static void edges() {
    AbLine out;
    /* the length bound is 96 with the LF, also when the LF is not there */
    std::string body = "1 W 0 500 " + std::string(60, '1');
    body += std::string(96 - body.size() - 10, '1');
    std::string ok = frame(body, 0);
    CHECK(ok.size() == 96 && decode(ok, 96, 0, &out) == 0 && out.seq == 1);
    std::string lng = frame(body + "1", 0);
    CHECK(lng.size() == 97 && decode(lng, 96, 0, &out) == AB_ERR_LONG);
    CHECK(decode(lng.substr(0, 96), 96, 0, &out) == AB_ERR_LONG);
    /* a "*" inside the body is PARSE; a CR before the LF is ignored */
    CHECK(decode(frame("1 PING a*b", 0), 96, 0, &out) == AB_ERR_PARSE);
    std::string r = frame("42 RATE 10", 5);
    CHECK(decode(r.substr(0, r.size() - 1) + "\r\n", 96, 5, &out) == 0 && out.seq == 42 && out.nargs == 1);
    CHECK(decode(r, 96, 6, &out) == AB_ERR_CRC);
    /* the HELLO rule */
    CHECK(ab_is_hello("1 HELLO 2 3 4", 13) && ab_is_hello("1 HELLO", 7));
    CHECK(!ab_is_hello("1 HELLOX 2", 10) && !ab_is_hello("1  HELLO 2", 10) && !ab_is_hello("HELLO", 5));
    /* RANGE details: the joint of a joint value, else the argument's name */
    int32_t v[AB_MAX_ARGS];
    AbError e;
    CHECK(parse("W", {"0", "1", "0", "1000001", "0"}, 3, v, &e) == AB_ERR_RANGE && strcmp(e.detail, "2") == 0);
    CHECK(parse("W", {"0", "0", "0", "0", "0"}, 3, v, &e) == AB_ERR_RANGE && strcmp(e.detail, "dur") == 0);
    CHECK(parse("SETLIM", {"1", "5", "4", "1"}, 3, v, &e) == AB_ERR_RANGE && strcmp(e.detail, "min") == 0);
    CHECK(parse("HELLO", {"2", "1", "1073741824"}, 3, v, &e) == AB_ERR_RANGE && strcmp(e.detail, "epoch") == 0);
    CHECK(parse("BEND", {"1", "900", "0", "100", "5"}, 3, v, &e) == AB_ERR_RANGE && strcmp(e.detail, "adc_a") == 0);
    /* integers: saturating, canonical */
    int32_t x;
    CHECK(ab_parse_int("-2147483648", 11, &x) && x == -2147483647);
    CHECK(ab_parse_int("99999999999999999999", 20, &x) && x == 2147483647);
    CHECK(!ab_parse_int("-", 1, &x) && !ab_parse_int("", 0, &x) && !ab_parse_int("007", 3, &x));
    /* the reader keeps its state across chunks */
    LineReader rd;
    int items = 0;
    for (int i = 0; i < 96; i++) items += rd.feed('a') != AB_ITEM_NONE;
    CHECK(items == 0);
    CHECK(rd.feed('\n') == AB_ITEM_ERROR && rd.error() == AB_ERR_LONG);
    CHECK(rd.feed('b') == AB_ITEM_NONE && rd.feed('\n') == AB_ITEM_LINE && rd.length() == 1);
    /* the writer never passes 192 bytes */
    LineWriter w;
    w.begin(65535);
    w.str("T");
    for (int i = 0; i < 30; i++) w.str("xxxxxxxxxx");
    size_t n;
    const uint8_t *d = w.finish(&n);
    CHECK(n <= AB_MAX_BOARD_LINE && d[n - 1] == '\n' && decode(std::string((const char *)d, n), 192, 0, &out) == 0);
    w.begin(7);
    w.num(-2147483647 - 1);
    d = w.finish(&n);
    CHECK(std::string((const char *)d, n - 10) == "7 -2147483648");
    /* num(): every digit count and the powers of ten at its edges, as printf writes them */
    static const int64_t nums[] = {0, 1, 9, 10, 11, 99, 100, 101, 999, 1000, 9999, 10000, 65535, 65536, 99999,
                                   100000, 999999, 1000000, 9999999, 10000000, 99999999, 100000000, 999999999,
                                   1000000000, 1999999999, 2000000000, 2147483647, -1, -9, -10, -65535,
                                   -1000000000, -2147483647, -2147483648LL};
    for (int64_t v : nums) {
        w.begin(0);
        w.num((int32_t)v);
        d = w.finish(&n);
        char want[24];
        snprintf(want, sizeof want, "0 %lld", (long long)v);
        CHECK(std::string((const char *)d, n - 10) == want);
    }
    /* ab_parse_int: saturates at 2^31 - 1 exactly where the value passes it */
    static const char *ints[] = {"214748364", "2147483646", "2147483647", "2147483648", "2147483649",
                                 "2147483650", "21474836470", "4294967295", "4294967296", "-2147483647",
                                 "-2147483649", "999999999", "1000000000", "7", "-7"};
    for (const char *t : ints) {
        long long ref = strtoll(t, nullptr, 10);
        long long cap = ref > 2147483647LL ? 2147483647LL : ref < -2147483647LL ? -2147483647LL : ref;
        CHECK(ab_parse_int(t, strlen(t), &x) && x == cap);
    }
}

void run_codec(const char *path) {
    vectors(path);
    edges();
}
