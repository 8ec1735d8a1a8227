/* Modbus RTU frame parser/responder (modbus.h, docs/modbus.md).
 *
 * One static buffer holds the frame being received. A frame ends at a silence of
 * t3.5 after its last byte: mb_poll sees that gap and answers it; when bytes of a
 * next frame arrive before mb_poll ran (the gap seen by mb_feed), the first frame is
 * closed at its length and the new bytes queue behind it in the same buffer, so a
 * late poll loses nothing. A frame over MB_FRAME_MAX bytes is dropped whole.
 * No allocation, no Arduino header: this file also builds natively for the tests.
 */
#include "modbus.h"

#include <string.h>

static uint8_t s_buf[MB_FRAME_MAX];
static uint16_t s_len;        /* bytes in s_buf */
static uint16_t s_closed;     /* length of a closed (complete) frame at the start of s_buf, 0 none */
static uint8_t s_overrun;     /* the open frame outgrew the buffer: drop it at its end */
static uint8_t s_have_last;   /* s_last_us is valid (a byte has arrived) */
static uint32_t s_last_us;    /* when the newest byte arrived */
static uint32_t s_t35_us = 1750;
static uint8_t s_addr = 1;
static mb_counters s_stats;

uint16_t mb_crc16(const uint8_t *data, uint16_t len) {
    uint16_t crc = 0xFFFF;
    for (uint16_t i = 0; i < len; i++) {
        crc ^= data[i];
        for (uint8_t b = 0; b < 8; b++)
            crc = (crc & 1) ? (uint16_t)((crc >> 1) ^ 0xA001) : (uint16_t)(crc >> 1);
    }
    return crc;
}

uint32_t mb_t35_us(uint32_t baud) {
    if (baud == 0 || baud > 19200) return 1750;  /* the RTU spec's fixed value above 19200 baud */
    return (uint32_t)(38500000UL / baud);          /* 3.5 characters of 11 bits */
}

void mb_init(uint8_t addr, uint32_t baud) {
    s_len = 0;
    s_closed = 0;
    s_overrun = 0;
    s_have_last = 0;
    s_last_us = 0;
    s_t35_us = mb_t35_us(baud);
    s_addr = addr;
    memset(&s_stats, 0, sizeof s_stats);
}

void mb_set_address(uint8_t addr) { s_addr = addr; }
uint8_t mb_address(void) { return s_addr; }
const mb_counters *mb_stats(void) { return &s_stats; }

/* The open frame (after a closed one, if any) is complete: close it, or drop it. */
static void close_open_frame(void) {
    uint16_t open = (uint16_t)(s_len - s_closed);
    if (s_overrun) {
        s_stats.overruns++;
        s_len = s_closed;
        s_overrun = 0;
        return;
    }
    if (open == 0) return;
    if (s_closed == 0) {
        s_closed = s_len;
    } else {
        /* a third frame before the first was polled: the host does not wait for our
           answers; keep the first, drop this one as an overrun */
        s_stats.overruns++;
        s_len = s_closed;
    }
}

void mb_feed(uint8_t byte, uint32_t now_us) {
    if (s_have_last && (uint32_t)(now_us - s_last_us) >= s_t35_us) close_open_frame();
    s_have_last = 1;
    s_last_us = now_us;
    if (s_overrun) return;
    if (s_len >= MB_FRAME_MAX) {
        s_overrun = 1;
        s_len = s_closed;  /* the open frame's bytes so far go too */
        return;
    }
    s_buf[s_len++] = byte;
}

static uint16_t be16(const uint8_t *p) { return (uint16_t)(((uint16_t)p[0] << 8) | p[1]); }

static int put_crc(uint8_t *out, int n) {
    uint16_t crc = mb_crc16(out, (uint16_t)n);
    out[n] = (uint8_t)(crc & 0xFF);
    out[n + 1] = (uint8_t)(crc >> 8);
    return n + 2;
}

static int exception(uint8_t addr, uint8_t fc, int code, uint8_t *out, uint16_t cap) {
    s_stats.exceptions++;
    if (addr == MB_BROADCAST || cap < 5) return 0;
    if (code < 1 || code > 11) code = MB_EX_DEVICE_FAILURE;
    out[0] = addr;
    out[1] = (uint8_t)(fc | 0x80);
    out[2] = (uint8_t)code;
    return put_crc(out, 3);
}

/* FC3 / FC4: addr fc start count crc. */
static int read_registers(const uint8_t *f, uint16_t len, uint8_t *out, uint16_t cap) {
    uint8_t addr = f[0], fc = f[1];
    if (addr == MB_BROADCAST) return 0;  /* a broadcast read has no meaning: nothing runs */
    if (len != 8) return exception(addr, fc, MB_EX_ILLEGAL_VALUE, out, cap);
    uint16_t start = be16(f + 2), count = be16(f + 4);
    if (count < 1 || count > MB_READ_MAX) return exception(addr, fc, MB_EX_ILLEGAL_VALUE, out, cap);
    if ((uint32_t)start + count > 0x10000UL) return exception(addr, fc, MB_EX_ILLEGAL_ADDRESS, out, cap);
    if (cap < (uint16_t)(5 + 2 * count)) return exception(addr, fc, MB_EX_DEVICE_FAILURE, out, cap);
    out[0] = addr;
    out[1] = fc;
    out[2] = (uint8_t)(2 * count);
    for (uint16_t i = 0; i < count; i++) {
        uint16_t v = 0;
        uint16_t reg = (uint16_t)(start + i);
        int ex = fc == MB_FC_READ_HOLDING ? mb_read_holding(reg, &v) : mb_read_input(reg, &v);
        if (ex) return exception(addr, fc, ex, out, cap);
        out[3 + 2 * i] = (uint8_t)(v >> 8);
        out[4 + 2 * i] = (uint8_t)(v & 0xFF);
    }
    return put_crc(out, 3 + 2 * count);
}

/* Whether [start, start + count) touches the waypoint window. */
static int touches_window(uint16_t start, uint16_t count) {
    uint32_t end = (uint32_t)start + count;
    return start < MB_HR_WINDOW + MB_WINDOW_LEN && end > MB_HR_WINDOW;
}

/* FC6: addr 6 reg value crc; the reply echoes the request. */
static int write_single(const uint8_t *f, uint16_t len, uint8_t *out, uint16_t cap) {
    uint8_t addr = f[0], fc = f[1];
    if (len != 8) return exception(addr, fc, MB_EX_ILLEGAL_VALUE, out, cap);
    uint16_t reg = be16(f + 2), value = be16(f + 4);
    if (touches_window(reg, 1)) return exception(addr, fc, MB_EX_ILLEGAL_ADDRESS, out, cap);
    int ex = mb_write_holding(reg, value);
    if (ex) return exception(addr, fc, ex, out, cap);
    if (addr == MB_BROADCAST) return 0;
    memcpy(out, f, 6);
    return put_crc(out, 6);
}

/* FC16: addr 16 start count bytes data... crc; reply addr 16 start count crc.
 * Registers are written in address order; the first refusal stops the write (those
 * before it stay written) and is the answer. The window is one write of all five. */
static int write_multiple(const uint8_t *f, uint16_t len, uint8_t *out, uint16_t cap) {
    uint8_t addr = f[0], fc = f[1];
    if (len < 11) return exception(addr, fc, MB_EX_ILLEGAL_VALUE, out, cap);
    uint16_t start = be16(f + 2), count = be16(f + 4);
    uint8_t nbytes = f[6];
    if (count < 1 || count > MB_WRITE_MAX || nbytes != 2 * count || len != (uint16_t)(9 + nbytes))
        return exception(addr, fc, MB_EX_ILLEGAL_VALUE, out, cap);
    if ((uint32_t)start + count > 0x10000UL) return exception(addr, fc, MB_EX_ILLEGAL_ADDRESS, out, cap);
    const uint8_t *data = f + 7;
    int ex = 0;
    if (start == MB_HR_WINDOW && count == MB_WINDOW_LEN) {
        uint16_t regs[MB_WINDOW_LEN];
        for (uint16_t i = 0; i < MB_WINDOW_LEN; i++) regs[i] = be16(data + 2 * i);
        ex = mb_write_window(regs, MB_WINDOW_LEN);
    } else if (touches_window(start, count)) {
        ex = MB_EX_ILLEGAL_ADDRESS;  /* the window is written whole, alone */
    } else {
        for (uint16_t i = 0; i < count && !ex; i++) ex = mb_write_holding((uint16_t)(start + i), be16(data + 2 * i));
    }
    if (ex) return exception(addr, fc, ex, out, cap);
    if (addr == MB_BROADCAST) return 0;
    memcpy(out, f, 6);
    return put_crc(out, 6);
}

int mb_handle(const uint8_t *f, uint16_t len, uint8_t *out, uint16_t cap) {
    if (len < 4) {
        s_stats.short_frames++;
        return 0;
    }
    if (mb_crc16(f, len) != 0) {  /* the CRC over a frame and its own CRC is 0 */
        s_stats.crc_errors++;
        return 0;
    }
    uint8_t addr = f[0];
    if (addr != MB_BROADCAST && addr != s_addr) {
        s_stats.other_addr++;
        return 0;
    }
    s_stats.frames++;
    if (addr == MB_BROADCAST) s_stats.broadcasts++;
    switch (f[1]) {  /* lengths below count the whole frame, CRC included */
        case MB_FC_READ_HOLDING:
        case MB_FC_READ_INPUT:
            return read_registers(f, len, out, cap);
        case MB_FC_WRITE_SINGLE:
            return write_single(f, len, out, cap);
        case MB_FC_WRITE_MULTIPLE:
            return write_multiple(f, len, out, cap);
        default:
            return exception(addr, f[1], MB_EX_ILLEGAL_FUNCTION, out, cap);
    }
}

int mb_poll(uint32_t now_us, uint8_t *out, uint16_t cap) {
    if (s_closed == 0) {
        if (!s_have_last || (uint32_t)(now_us - s_last_us) < s_t35_us) return 0;
        close_open_frame();
        if (s_closed == 0) return 0;
    }
    uint16_t n = s_closed;
    int reply = mb_handle(s_buf, n, out, cap);
    memmove(s_buf, s_buf + n, (size_t)(s_len - n));  /* a next frame's first bytes, if any */
    s_len = (uint16_t)(s_len - n);
    s_closed = 0;
    return reply;
}
