/* The HAL over the Arduino core on the Mega 2560 (hal.h): USART0 with its own
 * receive and transmit interrupts (the e-stop byte is acted on in the receive
 * interrupt itself), the L298 pins, the bend-sensor ADC channels, the end-stop
 * inputs, and the EEPROM behind a RAM shadow written one byte per main-loop pass
 * (programming a byte takes 3.4 ms; a blocking write would stall the receive path).
 */
#ifndef PUMP_HAL_AVR_H
#define PUMP_HAL_AVR_H

#include "hal.h"

/* The receive ring outlasts the longest main-loop pass: a pass reaches ~5.4 ms
 * (telemetry formatting and send, a line's CRC and parse; 13 ms measured when it waits
 * for room in the transmit ring with telemetry on: 150 bytes), 62 bytes at 115200 baud,
 * so the core's 64 bytes overflowed (~1 W line in 10 lost as ER CRC while streaming).
 * 256: an 8-bit index wraps by itself, and ~22 ms of wire fits. */
#define RX_RING 256
#define TX_RING 512          /* a telemetry line and the replies around it */

void ee_begin();             /* hal_avr_ee.cpp: the EEPROM's shadow, at boot */

class AvrHal : public Hal {
public:
    void begin();
    void service();          /* once per main-loop pass: one EEPROM byte if due */
    uint32_t ms();
    uint32_t us();
    int uart_read();
    int uart_read_at(uint32_t *t_us);
    void uart_write(const uint8_t *data, size_t n);
    size_t tx_room();
    bool estop_seen();
    void clear_estop();
    bool estop_dropped();
    void set_estop_byte(bool on);
    void outputs_off();
    void write_duty(uint8_t k, int16_t duty);
    uint16_t read_adc(uint8_t k);
    uint8_t endstops();
    void ee_read(uint16_t addr, void *dst, size_t n);
    void ee_write(uint16_t addr, const void *src, size_t n);
    void ee_write_now(uint16_t addr, uint8_t value);
    void keep_read(void *dst, size_t n);
    void keep_write(const void *src, size_t n);
    bool start_control(void (*fn)(void *), void *arg);
    void control_lock();
    void control_unlock();
    uint16_t control_overruns();
};

#endif
