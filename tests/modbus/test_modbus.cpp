/* Native unit tests of the Modbus RTU parser (firmware/arduino_pump/modbus.cpp), built
 * with g++ -fsanitize=address,undefined by tests/test_modbus_firmware.py. Every check
 * that fails prints its line; the exit status is the number of failures (0: all pass).
 * Expected bytes are worked out from the Modbus spec (and the CRC from its check values),
 * not from the parser. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fake_board.h"

static int g_checks, g_failed;
#define CHECK(cond)                                                              \
    do {                                                                         \
        g_checks++;                                                              \
        if (!(cond)) {                                                           \
            g_failed++;                                                          \
            fprintf(stderr, "%s:%d: %s: CHECK(%s) failed\n", __FILE__, __LINE__, \
                    __func__, #cond);                                            \
        }                                                                        \
    } while (0)

static const uint8_t ADDR = 7;
static const uint32_t CHAR_US = 87;  /* one 11-bit character at 115200 baud, rounded */

static uint8_t reply[MB_FRAME_MAX];

/* frame = body + CRC (low byte first) */
static uint16_t frame(uint8_t *out, const uint8_t *body, uint16_t n) {
    memcpy(out, body, n);
    uint16_t crc = mb_crc16(body, n);
    out[n] = (uint8_t)(crc & 0xFF);
    out[n + 1] = (uint8_t)(crc >> 8);
    return (uint16_t)(n + 2);
}

static int handle(const uint8_t *body, uint16_t n) {
    uint8_t f[MB_FRAME_MAX + 2];
    uint16_t len = frame(f, body, n);
    return mb_handle(f, len, reply, sizeof reply);
}

static void setup(void) {
    fb_reset();
    mb_init(ADDR, 115200);
}

static int is_exception(int n, uint8_t fc, uint8_t code) {
    return n == 5 && reply[0] == ADDR && reply[1] == (uint8_t)(fc | 0x80) && reply[2] == code &&
           mb_crc16(reply, 5) == 0;
}

static void test_crc(void) {
    const uint8_t check[] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
    CHECK(mb_crc16(check, 9) == 0x4B37);  /* CRC-16/MODBUS check value */
    const uint8_t req[] = {0x01, 0x03, 0x00, 0x00, 0x00, 0x0A};  /* the spec's classic example */
    CHECK(mb_crc16(req, 6) == 0xCDC5);    /* sent as C5 CD */
    const uint8_t req2[] = {0x11, 0x03, 0x00, 0x6B, 0x00, 0x03};  /* Modicon PI-MBUS-300 example */
    CHECK(mb_crc16(req2, 6) == 0x8776);   /* sent as 76 87 */
    CHECK(mb_crc16(req, 0) == 0xFFFF);
    uint8_t f[8];
    frame(f, req, 6);
    CHECK(mb_crc16(f, 8) == 0);           /* a frame with its own CRC sums to 0 */
}

static void test_t35(void) {
    CHECK(mb_t35_us(115200) == 1750);
    CHECK(mb_t35_us(38400) == 1750);
    CHECK(mb_t35_us(19200) == 2005);      /* 3.5 x 11 bits / 19200 */
    CHECK(mb_t35_us(9600) == 4010);
}

static void test_read_holding(void) {
    setup();
    const uint8_t req[] = {ADDR, 3, 0x00, MB_HR_KP, 0x00, 0x02};
    int n = handle(req, 6);
    CHECK(n == 9);
    CHECK(reply[0] == ADDR && reply[1] == 3 && reply[2] == 4);
    CHECK(reply[3] == ((1000 + MB_HR_KP) >> 8) && reply[4] == ((1000 + MB_HR_KP) & 0xFF));
    CHECK(reply[5] == ((1001 + MB_HR_KP) >> 8) && reply[6] == ((1001 + MB_HR_KP) & 0xFF));
    CHECK(mb_crc16(reply, 9) == 0);
    CHECK(mb_stats()->frames == 1 && mb_stats()->exceptions == 0);
    /* the window reads back the newest queued waypoint; none: 0xFFFF */
    const uint8_t win[] = {ADDR, 3, 0x00, MB_HR_WINDOW, 0x00, 1};
    n = handle(win, 6);
    CHECK(n == 7 && reply[3] == 0xFF && reply[4] == 0xFF);
    /* the largest read: 125 registers, a 255-byte reply */
    const uint8_t big[] = {ADDR, 4, 0x00, 0x00, 0x00, 125};
    fb.latched = 0;
    n = handle(big, 6);
    CHECK(is_exception(n, 4, MB_EX_ILLEGAL_ADDRESS));  /* 125 registers run past the input map */
}

static void test_read_input(void) {
    setup();
    const uint8_t req[] = {ADDR, 4, 0x00, MB_IR_STATE, 0x00, 0x03};
    int n = handle(req, 6);
    CHECK(n == 11 && reply[1] == 4 && reply[2] == 6);
    CHECK(reply[3] == ((2000 + MB_IR_STATE) >> 8) && reply[4] == ((2000 + MB_IR_STATE) & 0xFF));
    CHECK(reply[7] == ((2002 + MB_IR_STATE) >> 8) && reply[8] == ((2002 + MB_IR_STATE) & 0xFF));
    CHECK(mb_crc16(reply, 11) == 0);
}

static void test_write_single(void) {
    setup();
    const uint8_t req[] = {ADDR, 6, 0x00, MB_HR_DBAND + 1, 0x00, 70};
    int n = handle(req, 6);
    uint8_t f[8];
    frame(f, req, 6);
    CHECK(n == 8 && memcmp(reply, f, 8) == 0);  /* the reply echoes the request */
    CHECK(fb.holding[MB_HR_DBAND + 1] == 70);
    /* a negative set point travels as two's complement */
    const uint8_t neg[] = {ADDR, 6, 0x00, MB_HR_SETPOINT, 0xFF, 0x9C};  /* -100 */
    n = handle(neg, 6);
    CHECK(n == 8 && (int16_t)fb.holding[MB_HR_SETPOINT] == -100);
    /* the command register */
    const uint8_t cmd[] = {ADDR, 6, 0x00, MB_HR_COMMAND, 0x00, MB_CMD_ESTOP};
    n = handle(cmd, 6);
    CHECK(n == 8 && fb.last_cmd == MB_CMD_ESTOP);
}

static void test_write_multiple(void) {
    setup();
    const uint8_t req[] = {ADDR, 16, 0x00, MB_HR_SETPOINT, 0x00, 3, 6, 0x01, 0x00, 0x02, 0x00, 0xFC, 0x18};
    int n = handle(req, sizeof req);
    CHECK(n == 8 && reply[0] == ADDR && reply[1] == 16 && reply[2] == 0 && reply[3] == MB_HR_SETPOINT);
    CHECK(reply[4] == 0 && reply[5] == 3 && mb_crc16(reply, 8) == 0);
    CHECK(fb.holding[0] == 256 && fb.holding[1] == 512 && (int16_t)fb.holding[2] == -1000);
    /* the first refusal stops the write: those before it are written */
    const uint8_t stop[] = {ADDR, 16, 0x00, MB_HR_DBAND, 0x00, 3, 6, 0x00, 10, 0x07, 0xD0, 0x00, 30};
    n = handle(stop, sizeof stop);
    CHECK(is_exception(n, 16, MB_EX_ILLEGAL_VALUE));
    CHECK(fb.holding[MB_HR_DBAND] == 10 && fb.holding[MB_HR_DBAND + 1] == 1000 + MB_HR_DBAND + 1);
    CHECK(fb.holding[MB_HR_DBAND + 2] == 1000 + MB_HR_DBAND + 2);
}

static void test_window(void) {
    setup();
    const uint8_t wp[] = {ADDR, 16, 0x00, MB_HR_WINDOW, 0x00, 5, 10, 0x00, 42, 0x01, 0xF4,
                          0x00, 100, 0x01, 0x2C, 0xFF, 0xFF};
    int n = handle(wp, sizeof wp);
    CHECK(n == 8 && reply[1] == 16 && reply[3] == MB_HR_WINDOW && reply[5] == 5);
    CHECK(fb.queued == 1 && fb.window[0][0] == 42 && fb.window[0][1] == 500 && fb.window[0][2] == 100);
    CHECK(fb.window[0][3] == 300 && (int16_t)fb.window[0][4] == -1);
    const uint8_t rd[] = {ADDR, 3, 0x00, MB_HR_WINDOW, 0x00, 1};
    n = handle(rd, 6);
    CHECK(n == 7 && reply[3] == 0 && reply[4] == 42);
    n = handle(wp, sizeof wp);
    CHECK(n == 8 && fb.queued == 2);
    n = handle(wp, sizeof wp);  /* queue of 2 full: busy */
    CHECK(is_exception(n, 16, MB_EX_BUSY) && fb.queued == 2);
    fb.queued = 0;
    uint8_t bad[sizeof wp];
    memcpy(bad, wp, sizeof wp);
    bad[9] = 0;
    bad[10] = 0;  /* dur 0: out of range */
    n = handle(bad, sizeof bad);
    CHECK(is_exception(n, 16, MB_EX_ILLEGAL_VALUE) && fb.queued == 0);
    fb.latched = 1;
    n = handle(wp, sizeof wp);
    CHECK(is_exception(n, 16, MB_EX_DEVICE_FAILURE) && fb.queued == 0);
    fb.latched = 0;
    /* a write that does not cover the window exactly: 02, nothing written */
    int writes = fb.writes;
    const uint8_t part[] = {ADDR, 16, 0x00, MB_HR_WINDOW, 0x00, 2, 4, 0, 1, 0, 2};
    n = handle(part, sizeof part);
    CHECK(is_exception(n, 16, MB_EX_ILLEGAL_ADDRESS));
    const uint8_t over[] = {ADDR, 16, 0x00, MB_HR_WINDOW - 1, 0x00, 2, 4, 0, 1, 0, 2};
    n = handle(over, sizeof over);
    CHECK(is_exception(n, 16, MB_EX_ILLEGAL_ADDRESS));
    const uint8_t one[] = {ADDR, 6, 0x00, MB_HR_WINDOW + 4, 0x00, 1};
    n = handle(one, 6);
    CHECK(is_exception(n, 6, MB_EX_ILLEGAL_ADDRESS));
    CHECK(fb.writes == writes && fb.queued == 0);
}

static void test_exceptions(void) {
    setup();
    const uint8_t fc5[] = {ADDR, 5, 0x00, 0x01, 0xFF, 0x00};  /* write coil: not served */
    CHECK(is_exception(handle(fc5, 6), 5, MB_EX_ILLEGAL_FUNCTION));
    const uint8_t fc1[] = {ADDR, 1, 0x00, 0x00, 0x00, 0x01};
    CHECK(is_exception(handle(fc1, 6), 1, MB_EX_ILLEGAL_FUNCTION));
    const uint8_t addr[] = {ADDR, 3, 0x00, MB_HR_COUNT, 0x00, 0x01};
    CHECK(is_exception(handle(addr, 6), 3, MB_EX_ILLEGAL_ADDRESS));
    const uint8_t wrap[] = {ADDR, 4, 0xFF, 0xFF, 0x00, 0x02};  /* start + count past 65535 */
    CHECK(is_exception(handle(wrap, 6), 4, MB_EX_ILLEGAL_ADDRESS));
    const uint8_t zero[] = {ADDR, 3, 0x00, 0x00, 0x00, 0x00};
    CHECK(is_exception(handle(zero, 6), 3, MB_EX_ILLEGAL_VALUE));
    const uint8_t many[] = {ADDR, 4, 0x00, 0x00, 0x00, 126};
    CHECK(is_exception(handle(many, 6), 4, MB_EX_ILLEGAL_VALUE));
    const uint8_t longer[] = {ADDR, 3, 0x00, 0x00, 0x00, 0x01, 0x00};  /* FC3 with a stray byte */
    CHECK(is_exception(handle(longer, 7), 3, MB_EX_ILLEGAL_VALUE));
    const uint8_t nbytes[] = {ADDR, 16, 0x00, 0x00, 0x00, 2, 3, 0, 1, 0, 2};  /* byte count 3 for 2 */
    CHECK(is_exception(handle(nbytes, sizeof nbytes), 16, MB_EX_ILLEGAL_VALUE));
    const uint8_t cmd[] = {ADDR, 6, 0x00, MB_HR_COMMAND, 0x00, 9};
    CHECK(is_exception(handle(cmd, 6), 6, MB_EX_ILLEGAL_VALUE));
    /* a reply buffer too small for the answer: 04 */
    uint8_t f[16];
    const uint8_t rd[] = {ADDR, 3, 0x00, 0x00, 0x00, 10};
    uint16_t len = frame(f, rd, 6);
    uint8_t small[12];
    int n = mb_handle(f, len, small, sizeof small);
    CHECK(n == 5 && small[1] == 0x83 && small[2] == MB_EX_DEVICE_FAILURE && mb_crc16(small, 5) == 0);
    CHECK(mb_stats()->exceptions == 10);
}

static void test_silence(void) {
    setup();
    uint8_t f[8];
    const uint8_t rd[] = {ADDR, 3, 0x00, 0x00, 0x00, 0x01};
    uint16_t len = frame(f, rd, 6);
    f[3] ^= 0x01;  /* one bit flipped in transit */
    CHECK(mb_handle(f, len, reply, sizeof reply) == 0 && mb_stats()->crc_errors == 1);
    const uint8_t other[] = {(uint8_t)(ADDR + 1), 3, 0x00, 0x00, 0x00, 0x01};
    CHECK(handle(other, 6) == 0 && mb_stats()->other_addr == 1);
    CHECK(mb_handle(f, 3, reply, sizeof reply) == 0 && mb_stats()->short_frames == 1);
    CHECK(fb.reads == 0 && mb_stats()->frames == 0);
}

static void test_broadcast(void) {
    setup();
    const uint8_t wr[] = {MB_BROADCAST, 6, 0x00, MB_HR_COMMAND, 0x00, MB_CMD_ESTOP};
    CHECK(handle(wr, 6) == 0 && fb.last_cmd == MB_CMD_ESTOP);  /* executed, not answered */
    const uint8_t rd[] = {MB_BROADCAST, 3, 0x00, 0x00, 0x00, 0x01};
    CHECK(handle(rd, 6) == 0 && fb.reads == 0);                 /* ignored */
    const uint8_t wp[] = {MB_BROADCAST, 16, 0x00, MB_HR_WINDOW, 0x00, 5, 10, 0, 5, 0, 50, 0, 1, 0, 2, 0, 3};
    CHECK(handle(wp, sizeof wp) == 0 && fb.queued == 1 && fb.window[0][0] == 5);
    const uint8_t bad[] = {MB_BROADCAST, 6, 0x00, MB_HR_COMMAND, 0x00, 99};
    CHECK(handle(bad, 6) == 0);                                 /* a refusal is not answered either */
    CHECK(mb_stats()->broadcasts == 4 && mb_stats()->frames == 4);
}

/* Bytes fed one character time apart from t0; returns the time after the last. */
static uint32_t feed(const uint8_t *f, uint16_t n, uint32_t t0) {
    for (uint16_t i = 0; i < n; i++) mb_feed(f[i], t0 + i * CHAR_US);
    return t0 + (uint32_t)(n - 1) * CHAR_US;
}

static void test_framing(void) {
    setup();
    uint8_t f[8];
    const uint8_t rd[] = {ADDR, 4, 0x00, MB_IR_FREE, 0x00, 0x01};
    uint16_t len = frame(f, rd, 6);
    uint32_t last = feed(f, len, 1000);
    CHECK(mb_poll(last + 1749, reply, sizeof reply) == 0);  /* not yet t3.5 */
    CHECK(mb_poll(last + 1750, reply, sizeof reply) == 7);  /* the gap ends the frame */
    CHECK(reply[4] == ((2000 + MB_IR_FREE) & 0xFF));
    CHECK(mb_poll(last + 5000, reply, sizeof reply) == 0);  /* answered once */

    /* split across calls: polls between the bytes, gaps under t3.5 */
    uint32_t t = last + 10000;
    for (uint16_t i = 0; i < len; i++) {
        mb_feed(f[i], t);
        CHECK(mb_poll(t + 1000, reply, sizeof reply) == 0);
        t += 1700;
    }
    CHECK(mb_poll(t - 1700 + 1750, reply, sizeof reply) == 7);

    /* a gap of t3.5 inside a frame makes two frames, both dropped (bad CRC) */
    setup();
    t = 50000;
    feed(f, 3, t);
    t += 2 * CHAR_US + 1750;
    last = feed(f + 3, (uint16_t)(len - 3), t);
    CHECK(mb_poll(last + 1750, reply, sizeof reply) == 0);
    CHECK(mb_poll(last + 1760, reply, sizeof reply) == 0);
    CHECK(mb_stats()->crc_errors == 1 && mb_stats()->short_frames == 1 && fb.reads == 0);

    /* two frames fed before one poll: both answered, in order */
    setup();
    uint8_t g[8];
    const uint8_t rd2[] = {ADDR, 3, 0x00, MB_HR_WDOG, 0x00, 0x01};
    uint16_t len2 = frame(g, rd2, 6);
    last = feed(f, len, 0);
    last = feed(g, len2, last + 3000);
    int n = mb_poll(last + 10, reply, sizeof reply);
    CHECK(n == 7 && reply[1] == 4);
    CHECK(mb_poll(last + 20, reply, sizeof reply) == 0);  /* the second is not over yet */
    n = mb_poll(last + 1750, reply, sizeof reply);
    CHECK(n == 7 && reply[1] == 3 && reply[4] == ((1000 + MB_HR_WDOG) & 0xFF));

    /* the microsecond clock wraps mid-frame */
    setup();
    last = feed(f, len, 0xFFFFFFFFu - 200);
    CHECK(mb_poll(last + 1000, reply, sizeof reply) == 0);
    CHECK(mb_poll(last + 1750, reply, sizeof reply) == 7);

    /* an overrun (a frame longer than 256 bytes) is dropped whole, then all is well */
    setup();
    t = 0;
    for (int i = 0; i < 300; i++) mb_feed(0x55, t += CHAR_US);
    CHECK(mb_poll(t + 1750, reply, sizeof reply) == 0 && mb_stats()->overruns == 1);
    last = feed(f, len, t + 5000);
    CHECK(mb_poll(last + 1750, reply, sizeof reply) == 7 && mb_stats()->crc_errors == 0);

    /* a 9600-baud link: t3.5 is 4010 us */
    mb_init(ADDR, 9600);
    last = feed(f, len, 0);
    CHECK(mb_poll(last + 4009, reply, sizeof reply) == 0);
    CHECK(mb_poll(last + 4010, reply, sizeof reply) == 7);
}

static void test_address(void) {
    setup();
    mb_set_address(200);
    CHECK(mb_address() == 200);
    const uint8_t rd[] = {ADDR, 3, 0x00, 0x00, 0x00, 0x01};
    CHECK(handle(rd, 6) == 0);
    const uint8_t rd200[] = {200, 3, 0x00, 0x00, 0x00, 0x01};
    CHECK(handle(rd200, 6) == 7 && reply[0] == 200);
}

int main(void) {
    test_crc();
    test_t35();
    test_read_holding();
    test_read_input();
    test_write_single();
    test_write_multiple();
    test_window();
    test_exceptions();
    test_silence();
    test_broadcast();
    test_framing();
    test_address();
    printf("%d checks, %d failed\n", g_checks, g_failed);
    return g_failed ? 1 : 0;
}
