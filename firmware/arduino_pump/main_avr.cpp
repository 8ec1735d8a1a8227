/* The sketch: the Arduino core's init() (timers, millis/micros, ADC, PWM), the HAL,
 * the board; then the main loop: one pass drains the receive ring, handles its lines,
 * sends what the control periods raised (events, telemetry) and programs one EEPROM
 * byte if one is waiting. The control period itself runs in the Timer5 interrupt
 * (hal_avr.cpp), started by the link at the end of board.begin(). Our own main(): the
 * core's would also poll its Serial. */
#include <Arduino.h>

#include "hal_avr.h"
#include "pump.h"

static AvrHal hal;
static PumpBoard board;

/* One pass of the main loop, a function of its own (not inlined) so that the simavr
 * harness can time each pass (pump_hal.pump_timing's "pass" probe). */
extern "C" void __attribute__((noinline)) main_loop_pass(void) {
    board.poll();
    hal.service();
}

int main(void) {
    init();
    hal.begin();
    board.begin(&hal);
    for (;;) main_loop_pass();
}
