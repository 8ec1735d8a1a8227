// A tiny Arduino Mega sketch for the simavr harness tests (tests/test_emulator_pump.py):
// it echoes lines, reads the ADC and the end-stop pins, drives the pump board's
// motor 1 pins (EN 9 = OC2B PWM, IN1 22, IN2 23) and keeps a byte in EEPROM.
// Not the pump firmware: a stand-in with known behaviour, to test the harness.
#include <Arduino.h>
#include <avr/eeprom.h>

static char line[96];
static uint8_t len;
static unsigned long next_ms;
static volatile uint16_t samples;

static void reply(const char *text, long value)
{
    Serial.print(text);
    Serial.print(' ');
    Serial.println(value);
}

static void handle(void)
{
    line[len] = 0;
    if (line[0] == 'A') {                 // A ch: one ADC reading
        reply("ADC", analogRead(A0 + atoi(line + 2)));
    } else if (line[0] == 'P') {          // P duty: motor 1, + IN1 high, - IN2 high
        int d = atoi(line + 2);
        digitalWrite(22, d > 0 ? HIGH : LOW);
        digitalWrite(23, d < 0 ? HIGH : LOW);
        analogWrite(9, d < 0 ? -d : d);
        reply("PWM", d);
    } else if (line[0] == 'D') {          // D: end stops 30, 31
        reply("PINS", digitalRead(30) * 10 + digitalRead(31));
    } else if (line[0] == 'W') {          // W v: EEPROM byte 0
        eeprom_write_byte((uint8_t *)0, (uint8_t)atoi(line + 2));
        reply("EE", eeprom_read_byte((uint8_t *)0));
    } else if (line[0] == 'R') {
        reply("EE", eeprom_read_byte((uint8_t *)0));
    } else if (line[0] == 'S') {
        reply("SAMPLES", samples);
    } else {
        Serial.print("ECHO ");
        Serial.println(line);
    }
}

void setup(void)
{
    Serial.begin(115200);
    pinMode(22, OUTPUT);
    pinMode(23, OUTPUT);
    pinMode(30, INPUT_PULLUP);
    pinMode(31, INPUT_PULLUP);
    Serial.println("BOOT sketch");
    next_ms = millis() + 10;
}

void loop(void)
{
    while (Serial.available()) {
        int c = Serial.read();
        if (c == 0x98) {                  // the e-stop byte: motor off at once
            analogWrite(9, 0);
            digitalWrite(22, LOW);
            digitalWrite(23, LOW);
            len = 0;
            Serial.println("ESTOP");
        } else if (c == '\n') {
            handle();
            len = 0;
        } else if (len < sizeof line - 1) {
            line[len++] = (char)c;
        }
    }
    if ((long)(millis() - next_ms) >= 0) {  // a 10 ms "control tick": three ADC reads
        next_ms += 10;
        analogRead(A0);
        analogRead(A1);
        analogRead(A2);
        samples++;
    }
}
