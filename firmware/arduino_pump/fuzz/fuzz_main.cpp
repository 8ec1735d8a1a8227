/* The fallback fuzz driver where clang (libFuzzer) is not installed: deterministic
 * mutation fuzzing of fuzz_target.cpp, compiled with g++ and the sanitizers.
 *
 * Seeds: the lines of the shared vectors (vectors.txt from tools/vectors2txt.py:
 * good and bad lines, byte streams, command arguments turned into line bodies) and
 * a few hand-made ones (a W, SETLIM, BEND, MODBUS, a Modbus write). Each iteration
 * takes a seed or an earlier input, applies 1..8 mutations from a fixed xorshift
 * stream (bit flip, byte set, insert, delete, duplicate a chunk, splice another
 * seed, insert LF or the e-stop byte, replace a number by a boundary value) and
 * runs it. Bounded by --seconds (wall clock) and --iterations; the same seed gives
 * the same inputs. A broken invariant or a sanitizer report aborts the run.
 *   usage: fuzz_line --seconds S [--iterations N] [--seed X] --seeds vectors.txt
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <signal.h>
#include <time.h>

#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <vector>

#include "fuzz_stats.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* The input being run: a broken invariant (abort) prints it and writes it to
 * fuzz-crash.bin, to be replayed with --replay FILE. */
static const std::string *g_current;
static void on_abort(int) {
    if (g_current) {
        FILE *f = fopen("fuzz-crash.bin", "wb");
        if (f) {
            fwrite(g_current->data(), 1, g_current->size(), f);
            fclose(f);
        }
        fprintf(stderr, "crashing input (%zu bytes, mode %d) written to fuzz-crash.bin:\n", g_current->size(),
                g_current->empty() ? -1 : (unsigned char)(*g_current)[0] % 3);
        for (size_t i = 1; i < g_current->size(); i++) {
            unsigned char c = (unsigned char)(*g_current)[i];
            if (c >= 0x20 && c < 0x7F) fputc(c, stderr);
            else fprintf(stderr, "\\x%02x", c);
        }
        fputc('\n', stderr);
    }
    signal(SIGABRT, SIG_DFL);
}

static void run(const std::string &s) {
    g_current = &s;
    LLVMFuzzerTestOneInput((const uint8_t *)s.data(), s.size());
    g_current = NULL;
}

static uint64_t rng = 0x9E3779B97F4A7C15ULL;
static uint64_t next() {
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return rng;
}
static size_t below(size_t n) { return n ? (size_t)(next() % n) : 0; }

static std::string unhex(const std::string &t) {
    std::string out;
    for (size_t i = 1; i + 1 < t.size(); i += 2) out += (char)strtol(t.substr(i, 2).c_str(), NULL, 16);
    return out;
}

static std::vector<std::string> load_seeds(const char *path) {
    std::vector<std::string> seeds;
    std::ifstream f(path);
    std::string rec;
    while (std::getline(f, rec)) {
        std::istringstream in(rec);
        std::string kind, a;
        in >> kind >> a;
        if (kind == "good" || kind == "bad" || kind == "stream") {
            seeds.push_back(std::string(1, '\0') + unhex(a));           /* raw bytes */
            std::string l = unhex(a);
            size_t star = l.rfind('*');
            if (star != std::string::npos) seeds.push_back(std::string(1, '\1') + l.substr(0, star));
        } else if (kind == "cmd") {
            std::string body = "2 " + unhex(a);
            int n, code, nargs;
            in >> n >> code >> nargs;
            for (int i = 0; i < nargs; i++) {
                std::string x;
                in >> x;
                body += " " + unhex(x);
            }
            seeds.push_back(std::string(1, '\1') + body);
        }
    }
    const char *own[] = {"2 W 0 500 100 200 300\n3 W 1 500 0 0 0\n4 HOLD\n5 RESUME",
                         "2 SETLIM 1 0 100 50\n3 W 7 100 50 50 50\n4 STAT",
                         "2 BEND 1 100 0 900 500\n3 DBAND 2 0\n4 GAIN 3 9000 1 1",
                         "2 MODBUS 7", "2 WDOG 50\n3 W 1 60000 524 960 1047", "2 CLR\n3 RATE 100"};
    for (size_t i = 0; i < sizeof own / sizeof own[0]; i++) seeds.push_back(std::string(1, '\1') + own[i]);
    const uint8_t mb[] = {2, 1, 16, 0, 100, 0, 5, 10, 0, 1, 0, 100, 0, 50, 0, 60, 0, 70};
    seeds.push_back(std::string((const char *)mb, sizeof mb));
    const uint8_t mb2[] = {2, 1, 6, 0, 36, 0, 4};
    seeds.push_back(std::string((const char *)mb2, sizeof mb2));
    return seeds;
}

static void mutate(std::string &s, const std::vector<std::string> &seeds) {
    static const char *nums[] = {"0", "-1", "1", "65535", "65536", "1000000", "-1000001", "2147483648",
                                 "1073741823", "99999999999", "-0", "01", "524", "1047", "247"};
    int n = 1 + (int)below(8);
    for (int k = 0; k < n; k++) {
        size_t pos = below(s.size() + 1);
        switch (below(10)) {
            case 0: if (pos < s.size()) s[pos] = (char)(s[pos] ^ (1 << below(8))); break;
            case 1: if (pos < s.size()) s[pos] = (char)below(256); break;
            case 2: s.insert(pos, 1, (char)below(256)); break;
            case 3: if (pos < s.size()) s.erase(pos, 1 + below(8)); break;
            case 4: if (pos < s.size()) s.insert(pos, s.substr(pos, 1 + below(16))); break;
            case 5: {
                const std::string &o = seeds[below(seeds.size())];
                size_t a = below(o.size());
                s.insert(pos, o.substr(a, 1 + below(40)));
                break;
            }
            case 6: s.insert(pos, 1, '\n'); break;
            case 7: s.insert(pos, 1, (char)0x98); break;
            case 8: s.insert(pos, std::string(" ") + nums[below(sizeof nums / sizeof nums[0])]); break;
            default: if (!s.empty()) s[0] = (char)below(3); break;   /* another mode */
        }
        if (s.size() > 1024) s.resize(1024);
    }
}

int main(int argc, char **argv) {
    double seconds = 20;
    unsigned long long iterations = ~0ULL;
    const char *seed_path = NULL, *replay = NULL;
    signal(SIGABRT, on_abort);
    for (int i = 1; i + 1 < argc; i += 2) {
        if (!strcmp(argv[i], "--seconds")) seconds = atof(argv[i + 1]);
        else if (!strcmp(argv[i], "--iterations")) iterations = strtoull(argv[i + 1], NULL, 10);
        else if (!strcmp(argv[i], "--seed")) rng = strtoull(argv[i + 1], NULL, 0) | 1;
        else if (!strcmp(argv[i], "--seeds")) seed_path = argv[i + 1];
        else if (!strcmp(argv[i], "--replay")) replay = argv[i + 1];
    }
    if (replay) {
        std::ifstream f(replay, std::ios::binary);
        std::string s((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
        run(s);
        printf("replayed %zu bytes: no invariant broken\n", s.size());
        return 0;
    }
    if (!seed_path) {
        fprintf(stderr, "usage: %s --seconds S [--iterations N] [--seed X] --seeds vectors.txt\n", argv[0]);
        return 2;
    }
    std::vector<std::string> seeds = load_seeds(seed_path), pool;
    if (seeds.size() < 10) {
        fprintf(stderr, "too few seeds in %s\n", seed_path);
        return 2;
    }
    for (size_t i = 0; i < seeds.size(); i++)   /* every seed once, unmutated */
        run(seeds[i]);
    time_t t0 = time(NULL);
    unsigned long long it = 0;
    while (it < iterations && difftime(time(NULL), t0) < seconds) {
        std::string s = (pool.empty() || below(2)) ? seeds[below(seeds.size())] : pool[below(pool.size())];
        mutate(s, seeds);
        run(s);
        if (pool.size() < 256) pool.push_back(s);
        else pool[below(pool.size())] = s;
        it++;
    }
    const FuzzStats &st = g_fuzz_stats;
    printf("fuzz: %llu mutated inputs + %zu seeds in %.0f s, %llu runs, 0 invariant failures\n", it, seeds.size(),
           difftime(time(NULL), t0), (unsigned long long)st.runs);
    printf("fuzz: answers OK %llu, events %llu, modbus frames %llu; errors:", (unsigned long long)st.ok,
           (unsigned long long)st.events, (unsigned long long)st.modbus);
    for (int c = 1; c < AB_N_ERRORS; c++) printf(" %s %llu", AB_ERROR_NAMES[c], (unsigned long long)st.errors[c]);
    printf("\n");
    return 0;
}
