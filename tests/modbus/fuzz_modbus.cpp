/* Fuzz target for the Modbus RTU frame parser (firmware/arduino_pump/modbus.cpp).
 *
 * LLVMFuzzerTestOneInput reads its input as a byte stream with timing: each step is
 * (gap, byte), gap 0..255 in units of 16 us, so the fuzzer decides where frames end
 * (t3.5 = 1750 us); a poll runs after every byte. The first input byte's bits pick
 * whether frames are CRC-fixed before being fed (bit 0: mutants get past the CRC to
 * the function codes; else fed raw), a latched board (bit 1) and a full queue (bit 2). Invariants after every poll: the reply fits the buffer, carries a
 * good CRC, comes from our address, echoes the request's function code (bit 7 set for
 * an exception, then 5 bytes), and a read's byte count matches its length; the
 * accessors are only called with what the map allows (fake_board.h checks addresses).
 *
 * With clang: clang++ -fsanitize=fuzzer,address,undefined -DMB_LIBFUZZER ...
 * Without it (this project's default), main() is a deterministic mutation driver:
 * seeds of every function code, mutated by bit flips, byte changes, insertions,
 * deletions, truncation and splices, half of them CRC-fixed, fed with random gaps,
 * for N iterations (argv[1], default 200000) under ASan/UBSan. Exit 0: no invariant
 * broken; a broken one aborts with its message (and the input in hex).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fake_board.h"

static const uint8_t ADDR = 7;

static void fail(const char *why, const uint8_t *data, size_t size) {
    fprintf(stderr, "invariant broken: %s\ninput:", why);
    for (size_t i = 0; i < size && i < 600; i++) fprintf(stderr, " %02x", data[i]);
    fprintf(stderr, "\n");
    abort();
}

static unsigned long seen_fc[256], seen_ex[12];  /* what the replies were: coverage, printed by the driver */

static void check_reply(const uint8_t *out, int n, const uint8_t *data, size_t size) {
    if (n < 0 || n > MB_FRAME_MAX) fail("reply length outside 0..256", data, size);
    if (n == 0) return;
    if (n < 5) fail("reply under 5 bytes", data, size);
    if (mb_crc16(out, (uint16_t)n) != 0) fail("reply CRC", data, size);
    if (out[0] != ADDR) fail("reply from another address (or to a broadcast)", data, size);
    uint8_t fc = (uint8_t)(out[1] & 0x7F);
    if (fc != 3 && fc != 4 && fc != 6 && fc != 16 && !(out[1] & 0x80)) fail("reply function code", data, size);
    if (out[1] & 0x80) {
        if (n != 5 || out[2] < 1 || out[2] > 11) fail("exception reply shape", data, size);
    } else if (fc == 3 || fc == 4) {
        if (n != 5 + out[2] || out[2] == 0 || (out[2] & 1)) fail("read reply byte count", data, size);
    } else if (n != 8) {
        fail("write reply length", data, size);
    }
    seen_fc[out[1]]++;
    if (out[1] & 0x80) seen_ex[out[2]]++;
}

/* The stream: data[0] bit 0 = fix CRCs; then (gap, byte) pairs. With CRC fixing, a
 * gap >= t3.5 ends a frame: the bytes since the last gap get their CRC appended. */
extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    static uint8_t out[MB_FRAME_MAX];
    static uint8_t pending[MB_FRAME_MAX];
    if (size < 1) return 0;
    fb_reset();
    fb.latched = data[0] & 2;
    if (data[0] & 4) fb.qsize = 0;  /* a full queue: busy */
    mb_init(ADDR, 115200);
    int fix = data[0] & 1;
    uint32_t now = 0xFFFFF000u;  /* the clock wraps during the run */
    uint16_t np = 0;
    for (size_t i = 1; i + 1 < size; i += 2) {
        uint32_t gap = (uint32_t)data[i] * 16u;
        uint8_t byte = data[i + 1];
        if (fix && gap >= 1750 && np >= 2 && np + 2 <= MB_FRAME_MAX) {
            uint16_t crc = mb_crc16(pending, np);
            mb_feed((uint8_t)(crc & 0xFF), now += 87);
            mb_feed((uint8_t)(crc >> 8), now += 87);
        }
        if (gap >= 1750) np = 0;
        now += gap;
        mb_feed(byte, now);
        if (np < MB_FRAME_MAX) pending[np++] = byte;
        check_reply(out, mb_poll(now, out, sizeof out), data, size);
    }
    if (fix && np >= 2 && np + 2 <= MB_FRAME_MAX) {
        uint16_t crc = mb_crc16(pending, np);
        mb_feed((uint8_t)(crc & 0xFF), now += 87);
        mb_feed((uint8_t)(crc >> 8), now += 87);
    }
    check_reply(out, mb_poll(now + 1750, out, sizeof out), data, size);
    check_reply(out, mb_poll(now + 3500, out, sizeof out), data, size);
    const mb_counters *s = mb_stats();
    if (s->exceptions > s->frames) fail("more exceptions than frames", data, size);
    if (fb.queued > fb.qsize) fail("queue over its size", data, size);
    return 0;
}

#ifndef MB_LIBFUZZER
/* ------------------------------------------------------------------ the driver */
static uint64_t rng = 0x9E3779B97F4A7C15ull;
static uint32_t rnd(uint32_t n) {  /* xorshift64*: deterministic, seeded above; rnd(0) = 0 */
    if (n == 0) return 0;
    rng ^= rng >> 12;
    rng ^= rng << 25;
    rng ^= rng >> 27;
    return (uint32_t)((rng * 2685821657736338717ull) >> 33) % n;
}

static const uint8_t SEEDS[][17] = {
    {7, 3, 0, 0, 0, 39},
    {7, 4, 0, 0, 0, 46},
    {7, 4, 0, 17, 0, 2},
    {7, 6, 0, 36, 0, 4},
    {7, 6, 0, 12, 0x03, 0xE9},
    {7, 16, 0, 0, 0, 3, 6, 0, 1, 0, 2, 0, 3},
    {7, 16, 0, 100, 0, 5, 10, 0, 1, 0, 20, 0, 1, 0, 2, 0xFF, 0xFE},
    {0, 16, 0, 100, 0, 5, 10, 0, 1, 0, 20, 0, 1, 0, 2, 0, 3},
    {0, 6, 0, 36, 0, 1},
    {7, 5, 0, 1, 0xFF, 0},
    {7, 3, 0xFF, 0xFF, 0, 2},
};
static const size_t SEED_LEN[] = {6, 6, 6, 6, 6, 13, 17, 17, 6, 6, 6};

int main(int argc, char **argv) {
    long iters = argc > 1 ? atol(argv[1]) : 200000;
    static uint8_t frame[600], input[1400];
    for (long it = 0; it < iters; it++) {
        size_t nf = 0;
        int frames = 1 + (int)rnd(3);
        input[0] = (uint8_t)rnd(8);
        size_t ni = 1;
        for (int k = 0; k < frames; k++) {
            size_t s = rnd(sizeof SEED_LEN / sizeof SEED_LEN[0]);
            memcpy(frame, SEEDS[s], SEED_LEN[s]);
            nf = SEED_LEN[s];
            int muts = (int)rnd(4);
            for (int m = 0; m < muts; m++) {
                switch (rnd(6)) {
                    case 0: if (nf) frame[rnd((uint32_t)nf)] ^= (uint8_t)(1u << rnd(8)); break;
                    case 1: if (nf) frame[rnd((uint32_t)nf)] = (uint8_t)rnd(256); break;
                    case 2:  /* insert bytes (grows up to an overrun) */
                        for (uint32_t c = 1 + rnd(rnd(8) == 0 ? 280 : 4); c && nf < sizeof frame; c--) {
                            size_t at = rnd((uint32_t)nf + 1);
                            memmove(frame + at + 1, frame + at, nf - at);
                            frame[at] = (uint8_t)rnd(256);
                            nf++;
                        }
                        break;
                    case 3:
                        if (nf > 1) {
                            size_t at = rnd((uint32_t)nf);
                            memmove(frame + at, frame + at + 1, nf - at - 1);
                            nf--;
                        }
                        break;
                    case 4: nf = rnd((uint32_t)nf + 1); break;
                    default:  /* a count or byte count that matches, or not */
                        if (nf > 6) frame[6] = (uint8_t)(2 * frame[5] + (rnd(3) == 0 ? rnd(3) : 0));
                        break;
                }
            }
            for (size_t b = 0; b < nf && ni + 2 < sizeof input; b++) {
                uint8_t gap = b == 0 ? (uint8_t)(110 + rnd(146)) : (uint8_t)(rnd(20) == 0 ? rnd(256) : 5 + rnd(3));
                input[ni++] = gap;
                input[ni++] = frame[b];
            }
        }
        LLVMFuzzerTestOneInput(input, ni);
    }
    printf("%ld inputs; replies fc3 %lu fc4 %lu fc6 %lu fc16 %lu; exceptions", iters, seen_fc[3], seen_fc[4],
           seen_fc[6], seen_fc[16]);
    for (int c = 1; c < 12; c++)
        if (seen_ex[c]) printf(" %02d:%lu", c, seen_ex[c]);
    printf("\n");
    return 0;
}
#endif
