/* A fake HAL and a pneumatic stand-in plant for the native tests and the fuzzer.
 *
 * Time is simulated (us). The receive side acts as the Mega's RX interrupt: the
 * e-stop byte switches the motors off where it is pushed, before the board polls.
 * The EEPROM is a byte array the test keeps across a simulated reset.
 * The plant, per pump k: the syringe moves at duty/1000 of a stroke per
 * SYRINGE_STROKE_MS; the joint bends only past 5 % of the stroke (the elastomer's
 * threshold) and then by 1200 mrad per stroke; the bend sensor reads the default
 * calibration (205 counts straight, 716 at 1047 mrad); end stops at both ends of the
 * stroke, and a test can force a stop on.
 */
#ifndef PUMP_FAKE_HAL_H
#define PUMP_FAKE_HAL_H

#include <string.h>

#include <deque>
#include <string>

#include "config.h"
#include "hal.h"
#include "protodef.h"

class FakeHal : public Hal {
public:
    /* noinit: the .noinit SRAM a test keeps across a reset; NULL (a power cycle):
     * an area of its own, filled with noise as SRAM powers up. */
    explicit FakeHal(uint8_t *eeprom, uint8_t *noinit = NULL)
        : t_us(1000), ee(eeprom), keep(noinit ? noinit : own_keep), estop_flag(false), estop_on(true),
                                        lost(false), off_calls(0), tx_limit(100000) {
        for (int k = 0; k < N_JOINTS; k++) {
            duty[k] = 0;
            syringe[k] = 0.0;
            force_stop[k] = 0;
            adc_bias[k] = 0;
        }
        for (int i = 0; i < KEEP_SIZE; i++) own_keep[i] = (uint8_t)(0xA5 ^ (i * 37));
    }
    uint32_t ms() { return (uint32_t)(t_us / 1000); }
    uint32_t us() { return (uint32_t)t_us; }
    int uart_read() {
        uint32_t t;
        return uart_read_at(&t);
    }
    int uart_read_at(uint32_t *t) {
        if (rx.empty()) return -1;
        int b = rx.front();
        *t = rx_t.front();
        rx.pop_front();
        rx_t.pop_front();
        return b;
    }
    void uart_write(const uint8_t *d, size_t n) { tx.append((const char *)d, n); }
    size_t tx_room() { return tx.size() >= tx_limit ? 0 : tx_limit - tx.size(); }
    bool estop_seen() { return estop_flag; }
    void clear_estop() { estop_flag = false; }
    bool estop_dropped() { bool l = lost; lost = false; return l; }
    void set_estop_byte(bool on) { estop_on = on; }
    void outputs_off() {
        off_calls++;
        for (int k = 0; k < N_JOINTS; k++) duty[k] = 0;
    }
    void write_duty(uint8_t k, int16_t d) { duty[k] = estop_flag ? 0 : d; }
    uint16_t read_adc(uint8_t k) {
        double a = angle(k);
        double adc = 205.0 + a * (716.0 - 205.0) / 1047.0 + adc_bias[k];
        if (adc < 0) adc = 0;
        if (adc > 1023) adc = 1023;
        return (uint16_t)(adc + 0.5);
    }
    uint8_t endstops() {
        uint8_t bits = 0;
        for (int k = 0; k < N_JOINTS; k++) {
            if (syringe[k] <= 0.0 || force_stop[k] == 1) bits |= (uint8_t)(1u << (2 * k));
            if (syringe[k] >= 1.0 || force_stop[k] == 2) bits |= (uint8_t)(2u << (2 * k));
        }
        return bits;
    }
    void ee_read(uint16_t a, void *d, size_t n) { memcpy(d, ee + a, n); }
    void ee_write(uint16_t a, const void *s, size_t n) { memcpy(ee + a, s, n); }
    void ee_write_now(uint16_t a, uint8_t v) { ee[a] = v; }
    void keep_read(void *d, size_t n) { memcpy(d, keep, n < KEEP_SIZE ? n : KEEP_SIZE); }
    void keep_write(const void *s, size_t n) { memcpy(keep, s, n < KEEP_SIZE ? n : KEEP_SIZE); }

    /* ---- the test's side */
    void push(const std::string &bytes) {
        for (size_t i = 0; i < bytes.size(); i++) {
            uint8_t b = (uint8_t)bytes[i];
            if (b == AB_ESTOP_BYTE && estop_on) {   /* the RX interrupt */
                outputs_off();
                estop_flag = true;
            }
            rx.push_back(b);
            rx_t.push_back((uint32_t)t_us);   /* the RX interrupt's time */
        }
    }
    double angle(int k) const {
        double s = syringe[k] - 0.05;
        return s > 0 ? s * 1200.0 : 0.0;
    }
    void step_plant(uint32_t dt_us) {
        for (int k = 0; k < N_JOINTS; k++) {
            double ds = duty[k] / 1000.0 * dt_us / 1000.0 / SYRINGE_STROKE_MS;
            if ((ds > 0 && force_stop[k] == 2) || (ds < 0 && force_stop[k] == 1)) ds = 0;
            syringe[k] += ds;
            if (syringe[k] < 0) syringe[k] = 0;
            if (syringe[k] > 1) syringe[k] = 1;
        }
        t_us += dt_us;
    }

    uint64_t t_us;
    uint8_t *ee;
    uint8_t *keep;              /* the .noinit area: kept across a reset by the test */
    uint8_t own_keep[KEEP_SIZE];
    bool estop_flag, estop_on, lost;
    int off_calls;
    size_t tx_limit;
    int16_t duty[N_JOINTS];
    double syringe[N_JOINTS];
    int force_stop[N_JOINTS];   /* 1: retracted stop on, 2: extended stop on */
    int adc_bias[N_JOINTS];     /* counts added to the sensor (noise: a straight joint reads -1 count) */
    std::deque<uint8_t> rx;
    std::deque<uint32_t> rx_t;
    std::string tx;
};

#endif
