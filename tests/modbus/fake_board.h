/* A small board behind the Modbus parser for the native tests and the fuzz target:
 * plain register arrays with the map's rules that the parser must pass through
 * (addresses that do not exist: 02, a command out of range: 03, a full queue: 06,
 * latched: 04). It is test code, not the pump's accessors (those are pump.cpp's). */
#ifndef MB_FAKE_BOARD_H
#define MB_FAKE_BOARD_H

#include <stdint.h>
#include <string.h>

#include "../../firmware/arduino_pump/modbus.h"

struct FakeBoard {
    uint16_t holding[MB_HR_COUNT];
    uint16_t input[MB_IR_COUNT];
    uint16_t window[8][MB_WINDOW_LEN];  /* queued waypoints */
    int queued;
    int qsize;
    int latched;
    int reads;   /* accessor calls, to see that a broadcast read runs none */
    int writes;
    uint16_t last_cmd;
};

static FakeBoard fb;

static void fb_reset(void) {
    memset(&fb, 0, sizeof fb);
    fb.qsize = 2;
    for (int i = 0; i < MB_HR_COUNT; i++) fb.holding[i] = (uint16_t)(1000 + i);
    for (int i = 0; i < MB_IR_COUNT; i++) fb.input[i] = (uint16_t)(2000 + i);
    fb.holding[MB_HR_COMMAND] = 0;
}

extern "C" int mb_read_holding(uint16_t addr, uint16_t *value) {
    fb.reads++;
    if (addr >= MB_HR_WINDOW && addr < MB_HR_WINDOW + MB_WINDOW_LEN) {
        *value = fb.queued ? fb.window[fb.queued - 1][addr - MB_HR_WINDOW] : (uint16_t)MB_NONE;
        return 0;
    }
    if (addr >= MB_HR_COUNT) return MB_EX_ILLEGAL_ADDRESS;
    *value = fb.holding[addr];
    return 0;
}

extern "C" int mb_write_holding(uint16_t addr, uint16_t value) {
    fb.writes++;
    if (addr >= MB_HR_COUNT) return MB_EX_ILLEGAL_ADDRESS;
    if (addr == MB_HR_COMMAND) {
        if (value < MB_CMD_HOLD || value > MB_CMD_LINE) return MB_EX_ILLEGAL_VALUE;
        fb.last_cmd = value;
        return 0;
    }
    if (addr >= MB_HR_DBAND && addr < MB_HR_DBAND + MB_N_JOINTS && value > 1000) return MB_EX_ILLEGAL_VALUE;
    fb.holding[addr] = value;
    return 0;
}

extern "C" int mb_write_window(const uint16_t *regs, uint16_t count) {
    fb.writes++;
    if (count != MB_WINDOW_LEN) return 99;  /* the parser never does this: an odd code shows it */
    if (fb.latched) return MB_EX_DEVICE_FAILURE;
    if (regs[1] < 1 || regs[1] > 60000) return MB_EX_ILLEGAL_VALUE;
    if (fb.queued >= fb.qsize) return MB_EX_BUSY;
    memcpy(fb.window[fb.queued++], regs, sizeof fb.window[0]);
    return 0;
}

extern "C" int mb_read_input(uint16_t addr, uint16_t *value) {
    fb.reads++;
    if (addr >= MB_IR_COUNT) return MB_EX_ILLEGAL_ADDRESS;
    *value = fb.input[addr];
    return 0;
}

#endif
