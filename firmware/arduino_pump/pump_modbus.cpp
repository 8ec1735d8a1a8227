/* The board's side of Modbus RTU: the register accessors modbus.cpp calls
 * (modbus.h has the map; docs/modbus.md the full table). Holding registers go
 * through the same checks as the line protocol's verbs (SETLIM, DBAND, BEND, GAIN,
 * WDOG, the waypoint queue), so the board enforces its limits whichever interface
 * speaks. A refusal is an exception code: ILLEGAL_ADDRESS for a register that does
 * not exist, ILLEGAL_VALUE for a value the verb would refuse RANGE, BUSY for a full
 * queue, DEVICE_FAILURE while latched (ESTOP, WDOG, FAULT).
 *
 * Under Modbus there is no HELLO: the first write answered without exception
 * opens the outputs (as an accepted HELLO does), unless a latch holds (then CLR).
 * Opening holds the arm where it is (hold_here: the queue emptied, the set point
 * the measured angle), so a move opens the outputs before it is queued, never
 * after (issue 21: the first waypoint after a reset was acknowledged and then
 * dropped), and a refused move closes them again: as if it had not come.
 * A set-point write (0..2) is a waypoint from the last queued target to the new
 * value at the joint's vmax, with the reserved id 65535 (done reads 0xFFFF then).
 */
#include <string.h>

#include "modbus.h"
#include "pump.h"

#define SETPOINT_ID 0xFFFFu

static bool latched_now() {
    uint8_t s = g_pump->link.state;
    return s == ST_ESTOP || s == ST_WDOG || s == ST_FAULT;
}

static void opened() {
    Link &l = g_pump->link;
    if (!l.outputs_allowed && !latched_now()) {
        g_pump->hold_here();   /* first: the next period drives from here */
        l.outputs_allowed = true;
    }
}

static int16_t s16(uint16_t v) { return (int16_t)v; }

/* A move (the window, or a set point when `only` is 0..2: t[only] = val, the other
 * joints at the last queued target), queued with the outputs opened first. */
static int queue_move(uint16_t id, uint16_t dur, int32_t *t, int8_t only, uint16_t val) {
    PumpBoard &b = *g_pump;
    if (latched_now()) return MB_EX_DEVICE_FAILURE;
    bool was_open = b.link.outputs_allowed;
    opened();
    if (only >= 0) {
        float last[N_JOINTS];
        {
            CtlLock l(b.hal());
            b.traj.last_target(last);
        }
        for (uint8_t j = 0; j < N_JOINTS; j++) t[j] = (int32_t)(last[j] < 0 ? last[j] - 0.5f : last[j] + 0.5f);
        t[only] = s16(val);
    }
    AbError err;
    int code = b.queue(id, dur, t, &err);
    if (code) {
        b.link.outputs_allowed = was_open;   /* refused: nothing opened (the queue was empty) */
        return code == AB_ERR_FULL ? MB_EX_BUSY : MB_EX_ILLEGAL_VALUE;
    }
    if (b.link.state == ST_IDLE) {
        b.link.feed();        /* the period's watchdog counts from this frame */
        b.link.state = ST_RUN;
    }
    return 0;
}

int mb_read_holding(uint16_t addr, uint16_t *val) {
    PumpBoard &b = *g_pump;
    if (addr < MB_HR_KP) {
        float x;
        {
            CtlLock l(b.hal());
            x = b.traj.sp[addr];
        }
        *val = (uint16_t)(int16_t)(x < 0 ? x - 0.5f : x + 0.5f);
    } else if (addr < MB_HR_KI) {
        int32_t kp = b.gain[addr - MB_HR_KP].kp;
        *val = (uint16_t)(kp > 0xFFFF ? 0xFFFF : kp);
    } else if (addr < MB_HR_KD) {
        int32_t v = b.ki[addr - MB_HR_KI];
        *val = (uint16_t)(v > 0xFFFF ? 0xFFFF : v);
    } else if (addr < MB_HR_DBAND) {
        int32_t v = b.kd[addr - MB_HR_KD];
        *val = (uint16_t)(v > 0xFFFF ? 0xFFFF : v);
    } else if (addr < MB_HR_LIM_MIN) {
        *val = (uint16_t)b.gain[addr - MB_HR_DBAND].dband;
    } else if (addr < MB_HR_BEND) {
        uint8_t k = (uint8_t)((addr - MB_HR_LIM_MIN) / MB_N_JOINTS);   /* 0 min, 1 max, 2 vmax */
        uint8_t j = (uint8_t)((addr - MB_HR_LIM_MIN) % MB_N_JOINTS);
        *val = (uint16_t)(int16_t)b.lim[j][k];
    } else if (addr < MB_HR_COMMAND) {
        const BendCal &c = b.cal[(addr - MB_HR_BEND) / 4];
        switch ((addr - MB_HR_BEND) % 4) {
            case 0: *val = c.adc_a; break;
            case 1: *val = (uint16_t)(int16_t)c.a; break;
            case 2: *val = c.adc_b; break;
            default: *val = (uint16_t)(int16_t)c.b; break;
        }
    } else if (addr == MB_HR_COMMAND) {
        *val = 0;
    } else if (addr == MB_HR_WDOG) {
        *val = (uint16_t)b.link.wdog_ms;
    } else if (addr == MB_HR_ADDRESS) {
        *val = mb_address();
    } else if (addr >= MB_HR_WINDOW && addr < MB_HR_WINDOW + MB_WINDOW_LEN) {   /* the newest queued */
        const Waypoint &w = b.last_wp;
        uint16_t i = (uint16_t)(addr - MB_HR_WINDOW);
        *val = i == 0 ? w.id : i == 1 ? w.dur : (uint16_t)(int16_t)w.q[i - 2];
    } else {
        return MB_EX_ILLEGAL_ADDRESS;
    }
    return 0;
}

static int write_holding(uint16_t addr, uint16_t val) {
    PumpBoard &b = *g_pump;
    if (addr < MB_HR_KP) {
        int32_t t[N_JOINTS];
        return queue_move(SETPOINT_ID, 1, t, (int8_t)addr, val);
    } else if (addr < MB_HR_KI) {
        CtlLock l(b.hal());
        b.gain[addr - MB_HR_KP].kp = val;
    } else if (addr < MB_HR_KD) {
        b.ki[addr - MB_HR_KI] = val;
    } else if (addr < MB_HR_DBAND) {
        b.kd[addr - MB_HR_KD] = val;
    } else if (addr < MB_HR_LIM_MIN) {
        if (val > 1000) return MB_EX_ILLEGAL_VALUE;
        CtlLock l(b.hal());
        b.gain[addr - MB_HR_DBAND].dband = val;
    } else if (addr < MB_HR_BEND) {
        uint8_t k = (uint8_t)((addr - MB_HR_LIM_MIN) / MB_N_JOINTS);
        uint8_t j = (uint8_t)((addr - MB_HR_LIM_MIN) % MB_N_JOINTS);
        int32_t m[3] = {b.lim[j][0], b.lim[j][1], b.lim[j][2]};
        m[k] = s16(val);
        if (b.setlim((uint8_t)(j + 1), m[0], m[1], m[2])) return MB_EX_ILLEGAL_VALUE;
    } else if (addr < MB_HR_COMMAND) {
        uint8_t j = (uint8_t)((addr - MB_HR_BEND) / 4);
        BendCal c = b.cal[j];
        switch ((addr - MB_HR_BEND) % 4) {
            case 0: c.adc_a = val; break;
            case 1: c.a = s16(val); break;
            case 2: c.adc_b = val; break;
            default: c.b = s16(val); break;
        }
        /* one register at a time: a calibration the board would refuse stays unwritten */
        if (b.set_bend((uint8_t)(j + 1), c)) return MB_EX_ILLEGAL_VALUE;
    } else if (addr == MB_HR_COMMAND) {
        switch (val) {
            case MB_CMD_HOLD:
            case MB_CMD_RESUME:
                if (latched_now()) return MB_EX_DEVICE_FAILURE;
                b.link.hold_cmd(val == MB_CMD_HOLD);
                break;
            case MB_CMD_CLR: b.link.clear_cmd(); break;
            case MB_CMD_ESTOP: b.link.latch_estop_cmd(); break;
            case MB_CMD_LINE:
                b.modbus_addr = 0;
                b.save_settings();
                b.link.switch_to_line();
                break;
            default: return MB_EX_ILLEGAL_VALUE;
        }
    } else if (addr == MB_HR_WDOG) {
        if (val < 50 || val > 10000) return MB_EX_ILLEGAL_VALUE;
        b.link.set_wdog(val);
    } else if (addr == MB_HR_ADDRESS) {
        if (val < MB_ADDR_MIN || val > MB_ADDR_MAX) return MB_EX_ILLEGAL_VALUE;
        b.modbus_addr = (uint8_t)val;
        b.save_settings();
        mb_set_address((uint8_t)val);
    } else {
        return MB_EX_ILLEGAL_ADDRESS;
    }
    return 0;
}

int mb_write_holding(uint16_t addr, uint16_t val) {
    int ex = write_holding(addr, val);
    if (!ex) opened();
    return ex;
}

int mb_write_window(const uint16_t *regs, uint16_t count) {
    if (count != MB_WINDOW_LEN) return MB_EX_ILLEGAL_VALUE;
    if (latched_now()) return MB_EX_DEVICE_FAILURE;
    if (regs[1] < 1 || regs[1] > 60000) return MB_EX_ILLEGAL_VALUE;
    int32_t t[N_JOINTS];
    for (uint8_t j = 0; j < N_JOINTS; j++) t[j] = s16(regs[2 + j]);
    return queue_move(regs[0], regs[1], t, -1, 0);
}

/* The latch's first cause (docs/protocol.md §9): an e-stop over WDOG or FAULT keeps
 * theirs as the reason, and input 13 names it. */
static uint16_t latch_code() {
    const Link &l = g_pump->link;
    if (!latched_now()) return MB_LATCH_NONE;
    if (strncmp(l.reason, "FOLLOW:", 7) == 0) return (uint16_t)(MB_LATCH_FOLLOW + (l.reason[7] - '0'));
    if (l.state == ST_WDOG || strcmp(l.reason, "WDOG") == 0) return MB_LATCH_WDOG;
    if (l.state == ST_ESTOP) return MB_LATCH_ESTOP;
    return MB_LATCH_NONE;
}

int mb_read_input(uint16_t addr, uint16_t *val) {
    static uint16_t ms_lo;   /* latched by reading MB_IR_MS_HI */
    PumpBoard &b = *g_pump;
    if (addr < MB_IR_STATE) {   /* the period's values (link.h): copied under the lock, converted after */
        int32_t v;
        float x = 0.0f;
        {
            CtlLock l(b.hal());
            if (addr < MB_IR_TARGET) v = b.q[addr];
            else if (addr < MB_IR_DUTY) x = b.traj.sp[addr - MB_IR_TARGET], v = 0;
            else if (addr < MB_IR_SYRINGE) v = b.u[addr - MB_IR_DUTY];
            else v = b.syringe_raw((uint8_t)(addr - MB_IR_SYRINGE));
        }
        if (addr >= MB_IR_TARGET && addr < MB_IR_DUTY) v = (int32_t)(x < 0 ? x - 0.5f : x + 0.5f);
        else if (addr >= MB_IR_SYRINGE) v /= 1000;
        *val = (uint16_t)(int16_t)v;
    } else if (addr == MB_IR_STATE) {
        *val = b.link.state;
    } else if (addr == MB_IR_LATCH) {
        *val = latch_code();
    } else if (addr == MB_IR_DONE) {
        *val = b.link.done < 0 ? MB_NONE : (uint16_t)b.link.done;
    } else if (addr == MB_IR_FREE) {
        *val = b.traj.free();
    } else if (addr == MB_IR_ENDSTOPS) {
        *val = b.stops;
    } else if (addr == MB_IR_MS_HI) {
        uint32_t ms = b.link.board_ms();
        ms_lo = (uint16_t)ms;
        *val = (uint16_t)(ms >> 16);
    } else if (addr == MB_IR_MS_LO) {
        *val = ms_lo;
    } else if (addr == MB_IR_QUEUED) {
        *val = b.link.queued < 0 ? MB_NONE : (uint16_t)b.link.queued;
    } else if (addr >= MB_IR_FW_NAME && addr < MB_IR_FW_VERSION) {
        static const char name[] = FW_NAME;
        uint8_t i = (uint8_t)(2 * (addr - MB_IR_FW_NAME));
        uint8_t hi = i < sizeof name - 1 ? (uint8_t)name[i] : 0;
        uint8_t lo = (size_t)(i + 1) < sizeof name - 1 ? (uint8_t)name[i + 1] : 0;
        *val = (uint16_t)((hi << 8) | lo);
    } else if (addr == MB_IR_FW_VERSION) {
        *val = FW_VERSION_MAJOR;
    } else if (addr == MB_IR_FW_VERSION + 1) {
        *val = FW_VERSION_MINOR;
    } else if (addr == MB_IR_FW_VERSION + 2) {
        *val = FW_VERSION_PATCH;
    } else if (addr == MB_IR_PROTO) {
        *val = AB_PROTOCOL_VERSION;
    } else if (addr == MB_IR_NJOINTS) {
        *val = N_JOINTS;
    } else if (addr == MB_IR_QSIZE) {
        *val = QSIZE;
    } else {
        return MB_EX_ILLEGAL_ADDRESS;
    }
    return 0;
}
