/* The small HAL between the portable board code (codec, session, link, traj,
 * controller, Modbus hook) and the chip. hal_avr.cpp implements it over the Arduino
 * core on the Mega; tests/native/fake_hal.h implements it for the native tests and
 * the fuzzer. No Arduino header here, so everything above it compiles with g++.
 */
#ifndef PUMP_HAL_H
#define PUMP_HAL_H

#include <stddef.h>
#include <stdint.h>

class Hal {
public:
    /* ---- time */
    virtual uint32_t ms() = 0;                 /* millis(): wraps at 2^32 */
    virtual uint32_t us() = 0;                 /* micros(): wraps at 2^32 */
    /* ---- link UART */
    virtual int uart_read() = 0;               /* next received byte, -1 when none */
    /* The same, and when the byte arrived (us() of its receive interrupt): a byte
     * that waited in the ring while the loop was busy keeps its own time, so the
     * Modbus t3.5 framing sees the wire's gaps, not the loop's. */
    virtual int uart_read_at(uint32_t *t_us) = 0;
    virtual void uart_write(const uint8_t *data, size_t n) = 0;  /* queues; waits if full */
    virtual size_t tx_room() = 0;              /* bytes the transmit queue takes without waiting */
    /* The receive path's e-stop: the byte 0x98 switches the motors off where it is
     * received (the RX interrupt on the Mega), before the main loop sees it. While
     * this is set write_duty() writes zero. The link clears it once it has latched
     * ESTOP. In Modbus mode the byte is data: set_estop_byte(false). */
    virtual bool estop_seen() = 0;
    virtual void clear_estop() = 0;
    /* An e-stop byte arrived while the receive ring was full (so the link never
     * reads it): returns that once and forgets it. The link latches ESTOP then. */
    virtual bool estop_dropped() = 0;
    virtual void set_estop_byte(bool on) = 0;
    /* ---- motors, sensors */
    virtual void outputs_off() = 0;            /* every EN at 0, IN1/IN2 low */
    virtual void write_duty(uint8_t k, int16_t duty) = 0;  /* per-mille, + inflates */
    virtual uint16_t read_adc(uint8_t k) = 0;  /* bend sensor k, 0..1023 */
    virtual uint8_t endstops() = 0;            /* bit 2k: k retracted, 2k+1: k extended; 1 = at it */
    /* ---- EEPROM (write-behind on the Mega: a byte takes 3.4 ms to program) */
    virtual void ee_read(uint16_t addr, void *dst, size_t n) = 0;
    virtual void ee_write(uint16_t addr, const void *src, size_t n) = 0;
    /* One byte programmed now, ahead of the write-behind queue (waits only for a byte
     * already being programmed: at most 3.4 ms on the Mega). For the latch cell. */
    virtual void ee_write_now(uint16_t addr, uint8_t value) = 0;
    /* ---- SRAM kept across a reset, undefined after a power cycle (a `.noinit`
     * area on the Mega: the C runtime neither copies nor clears it). KEEP_SIZE
     * bytes; written at once, so the link record there is never behind. */
    virtual void keep_read(void *dst, size_t n) = 0;
    virtual void keep_write(const void *src, size_t n) = 0;
    /* ---- the control period (docs/pump.md "The control period on a timer")
     * start_control: true when a hardware timer will call fn(arg) every PERIOD_MS from
     * now on, in its interrupt with interrupts enabled (never nested: a period that
     * comes while the last one still runs is counted as an overrun and skipped); false
     * (the native tests' fake) when the link is to schedule the period itself from
     * us(). control_lock/unlock: the main loop's side of the state it shares with the
     * period (link.h lists it): while locked the period cannot start (it starts at
     * unlock); other interrupts, the e-stop byte's among them, stay enabled. Nests.
     * Called from the period itself it is harmless. Each is a compiler barrier. */
    virtual bool start_control(void (*fn)(void *), void *arg) { (void)fn; (void)arg; return false; }
    virtual void control_lock() {}
    virtual void control_unlock() {}
    virtual uint16_t control_overruns() { return 0; }
};

/* The main loop's critical section against the control period (a scope). */
class CtlLock {
public:
    explicit CtlLock(Hal *h) : h_(h) { h_->control_lock(); }
    ~CtlLock() { h_->control_unlock(); }
private:
    Hal *h_;
};

#endif
