/* The sketch: the Arduino core's init() (timers, millis/micros, ADC, PWM), the HAL,
 * the board; then the main loop: one pass drains the receive ring, handles its lines,
 * runs the control period when it is due (micros(), 10 ms) and programs one EEPROM
 * byte if one is waiting. Our own main(): the core's would also poll its Serial. */
#include <Arduino.h>

#include "hal_avr.h"
#include "pump.h"

static AvrHal hal;
static PumpBoard board;

int main(void) {
    init();
    hal.begin();
    board.begin(&hal);
    for (;;) {
        board.poll();
        hal.service();
    }
}
