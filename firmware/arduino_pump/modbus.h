/* Modbus RTU for the syringe-pump board: a pure frame parser/responder (docs/modbus.md).
 *
 * Why it is shaped this way: the same code runs on the Mega and natively under
 * g++ -fsanitize=address,undefined (tests/test_modbus_firmware.py) and a fuzzer, so it
 * includes no Arduino header, allocates nothing, keeps one static frame buffer, and
 * reaches the board only through the four register accessors below, which the board
 * implements (pump.cpp). Framing is by time, as the RTU spec says: a frame ends after a
 * silence of t3.5 (3.5 character times; fixed at 1750 us above 19200 baud).
 *
 *   mb_init(addr, 115200);
 *   loop: while (ring has a byte) mb_feed(byte, micros() of its RX interrupt);
 *         n = mb_poll(micros(), reply, sizeof reply); if (n > 0) Serial.write(reply, n);
 *
 * A frame with a bad CRC, for another address, too short or too long is dropped in
 * silence (as RTU slaves do: the master times out and retries); every drop is counted
 * in mb_stats(). Broadcast (address 0): writes are executed, nothing is answered; a
 * broadcast read is ignored.
 *
 * Accessors return 0 or a Modbus exception code (MB_EX_*): the parser answers that
 * exception for the request. A code outside 1..11 is answered as MB_EX_DEVICE_FAILURE.
 */
#ifndef ARMBRIDGE_MODBUS_H
#define ARMBRIDGE_MODBUS_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ------------------------------------------------------------------ wire facts */
#define MB_FRAME_MAX 256     /* RTU ADU: address + PDU (253) + CRC */
#define MB_READ_MAX 125      /* FC3/FC4 registers per request */
#define MB_WRITE_MAX 123     /* FC16 registers per request */
#define MB_BROADCAST 0
#define MB_ADDR_MIN 1
#define MB_ADDR_MAX 247

#define MB_FC_READ_HOLDING 3
#define MB_FC_READ_INPUT 4
#define MB_FC_WRITE_SINGLE 6
#define MB_FC_WRITE_MULTIPLE 16

#define MB_EX_ILLEGAL_FUNCTION 1
#define MB_EX_ILLEGAL_ADDRESS 2
#define MB_EX_ILLEGAL_VALUE 3
#define MB_EX_DEVICE_FAILURE 4
#define MB_EX_BUSY 6

/* ------------------------------------------------------------------ register map
 * Protocol addresses (0-based, as on the wire). Signed values are int16 two's
 * complement; units as the line protocol (mrad, mrad/s, ms, per-mille). Joint j
 * (1..3) of a per-joint group G is G + j - 1. docs/modbus.md is the full table. */
#define MB_N_JOINTS 3

/* Holding registers (FC3 read, FC6/FC16 write). */
#define MB_HR_SETPOINT 0     /* 0..2: set point q_j (mrad); write = move there at vmax */
#define MB_HR_KP 3           /* 3..5: kp (thousandths of duty per-mille per mrad), as GAIN */
#define MB_HR_KI 6           /* 6..8: ki, as GAIN */
#define MB_HR_KD 9           /* 9..11: kd, as GAIN */
#define MB_HR_DBAND 12       /* 12..14: dead band (mrad, 0..1000), as DBAND */
#define MB_HR_LIM_MIN 15     /* 15..17: joint min (mrad), as SETLIM */
#define MB_HR_LIM_MAX 18     /* 18..20: joint max (mrad) */
#define MB_HR_VMAX 21        /* 21..23: joint vmax (mrad/s, 1..32767) */
#define MB_HR_BEND 24        /* 24..35: per joint 4 registers adc_a a adc_b b, as BEND (EEPROM) */
#define MB_HR_COMMAND 36     /* write one of MB_CMD_*; reads 0 */
#define MB_HR_WDOG 37        /* watchdog (ms, 50..10000), as WDOG */
#define MB_HR_ADDRESS 38     /* this board's Modbus address (1..247, EEPROM; used after the reply) */
#define MB_HR_COUNT 39       /* holding registers 0..38 exist besides the window */

#define MB_HR_WINDOW 100     /* 100..104: id dur q1 q2 q3, queued by one FC16 covering all five */
#define MB_WINDOW_LEN (2 + MB_N_JOINTS)

#define MB_CMD_HOLD 1
#define MB_CMD_RESUME 2
#define MB_CMD_CLR 3
#define MB_CMD_ESTOP 4
#define MB_CMD_LINE 5        /* back to the line protocol (EEPROM), after the reply is sent */

/* Input registers (FC4 read). */
#define MB_IR_ANGLE 0        /* 0..2: measured angle (mrad) */
#define MB_IR_TARGET 3       /* 3..5: set point now (mrad) */
#define MB_IR_DUTY 6         /* 6..8: motor duty (per-mille, signed: + inflates) */
#define MB_IR_SYRINGE 9      /* 9..11: syringe position (per-mille of travel) */
#define MB_IR_STATE 12       /* index into STATES: 0 IDLE 1 RUN 2 HOLD 3 ESTOP 4 WDOG 5 FAULT */
#define MB_IR_LATCH 13       /* latch reason: MB_LATCH_* */
#define MB_IR_DONE 14        /* last done waypoint id, 0xFFFF none */
#define MB_IR_FREE 15        /* free queue slots */
#define MB_IR_ENDSTOPS 16    /* bit 2(j-1): joint j's retracted stop, bit 2(j-1)+1: extended; 1 = at it */
#define MB_IR_MS_HI 17       /* board ms, high word: reading it latches the low word for MB_IR_MS_LO */
#define MB_IR_MS_LO 18       /* board ms, low word */
#define MB_IR_QUEUED 19      /* last queued waypoint id, 0xFFFF none */
#define MB_IR_FW_NAME 32     /* 32..39: firmware name, 2 ASCII chars per register (high byte first), NUL padded */
#define MB_IR_FW_VERSION 40  /* 40..42: firmware version major, minor, patch */
#define MB_IR_PROTO 43       /* the line protocol's version (2) */
#define MB_IR_NJOINTS 44     /* n = 3 */
#define MB_IR_QSIZE 45       /* waypoint queue size */
#define MB_IR_COUNT 46

#define MB_NONE 0xFFFFu      /* "no id" in MB_IR_DONE, MB_IR_QUEUED */

#define MB_LATCH_NONE 0
#define MB_LATCH_ESTOP 1     /* the e-stop byte, or MB_CMD_ESTOP */
#define MB_LATCH_WDOG 2
#define MB_LATCH_FOLLOW 16   /* 16 + j: joint j's following error (FOLLOW:j) */

/* ------------------------------------------------------------------ the board's side */
int mb_read_holding(uint16_t addr, uint16_t *value);
int mb_write_holding(uint16_t addr, uint16_t value);
/* The waypoint window: regs = id dur q1 q2 q3 (count == MB_WINDOW_LEN); queue it or
 * return MB_EX_BUSY (queue full), MB_EX_ILLEGAL_VALUE (a value out of range),
 * MB_EX_DEVICE_FAILURE (latched). */
int mb_write_window(const uint16_t *regs, uint16_t count);
int mb_read_input(uint16_t addr, uint16_t *value);

/* ------------------------------------------------------------------ the parser */
typedef struct {
    uint32_t frames;       /* valid frames for this address or broadcast (feed the watchdog on a change) */
    uint32_t broadcasts;   /* of those, broadcast */
    uint32_t exceptions;   /* exception replies produced */
    uint32_t crc_errors;   /* dropped: bad CRC */
    uint32_t short_frames; /* dropped: under 4 bytes */
    uint32_t overruns;     /* dropped: over MB_FRAME_MAX bytes without a t3.5 gap */
    uint32_t other_addr;   /* ignored: for another device */
} mb_counters;

uint16_t mb_crc16(const uint8_t *data, uint16_t len);  /* CRC-16/MODBUS: poly 0xA001 refl., init 0xFFFF */
uint32_t mb_t35_us(uint32_t baud);                     /* 1750 us above 19200 baud, else 38.5e6 / baud */

void mb_init(uint8_t addr, uint32_t baud);             /* empties the buffer, zeroes the counters */
void mb_set_address(uint8_t addr);
uint8_t mb_address(void);
void mb_feed(uint8_t byte, uint32_t now_us);           /* one received byte and when it arrived (its RX interrupt) */
/* When a frame has ended (t3.5 since its last byte), handle it: the reply's length
 * written into out (cap >= MB_FRAME_MAX), or 0 (nothing to send). */
int mb_poll(uint32_t now_us, uint8_t *out, uint16_t cap);
/* Handle one complete frame now (no timing): what mb_poll does at the gap. */
int mb_handle(const uint8_t *frame, uint16_t len, uint8_t *out, uint16_t cap);
const mb_counters *mb_stats(void);

#ifdef __cplusplus
}
#endif

#endif
