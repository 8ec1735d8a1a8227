/* The Mega 2560 HAL (hal_avr.h). The only file of the board with Arduino headers,
 * with main_avr.cpp. */
#include "hal_avr.h"

#include <Arduino.h>
#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <util/atomic.h>
#include <string.h>

#include "config.h"
#include "protodef.h"

static const uint8_t kEn[N_JOINTS] = PIN_EN;
static const uint8_t kIn1[N_JOINTS] = PIN_IN1;
static const uint8_t kIn2[N_JOINTS] = PIN_IN2;
static const uint8_t kBend[N_JOINTS] = PIN_BEND;
static const uint8_t kStopRet[N_JOINTS] = PIN_STOP_RET;
static const uint8_t kStopExt[N_JOINTS] = PIN_STOP_EXT;

static volatile uint8_t rx_buf[RX_RING];
static volatile uint16_t rx_time[RX_RING];  /* low 16 bits of micros() at each byte's interrupt */
static volatile uint8_t rx_head, rx_tail;   /* head: ISR writes; tail: loop reads */
static_assert(RX_RING <= 256, "rx_head/rx_tail are 8-bit");
static volatile uint8_t tx_buf[TX_RING];
static volatile uint16_t tx_head, tx_tail;
static volatile uint8_t estop_flag;         /* motors blocked: an e-stop byte came */
static volatile uint8_t estop_lost;         /* ... and the ring had no room for it */
static volatile uint8_t estop_on = 1;       /* 0 in Modbus mode: 0x98 is data */

/* The bend sensors, converted by the ADC on its own: its interrupt stores a result and
 * starts the next channel (A0, A1, A2, A0, ...: 104 us a conversion at the core's
 * 125 kHz ADC clock), so read_adc() is a load of a value at most ~0.3 ms old instead of
 * analogRead's ~112 us of waiting per channel inside the control period. */
static volatile uint16_t adc_val[N_JOINTS];
static volatile uint8_t adc_k;
static volatile uint8_t adc_rounds;

/* ADMUX and ADCSRB's MUX5 per channel, resolved in begin(): the interrupt stays short
 * (it delays the control period's interrupt when they meet). */
static uint8_t adc_mux[N_JOINTS], adc_mux5[N_JOINTS];

static inline __attribute__((always_inline)) void adc_start(uint8_t k) {
    ADCSRB = (uint8_t)((ADCSRB & ~_BV(MUX5)) | adc_mux5[k]);
    ADMUX = adc_mux[k];
    ADCSRA |= _BV(ADSC);
}

ISR(ADC_vect) {
    uint8_t lo = ADCL, hi = ADCH;               /* ADCL first: it locks ADCH */
    adc_val[adc_k] = (uint16_t)(((uint16_t)hi << 8) | lo);
    uint8_t k = (uint8_t)(adc_k + 1);
    if (k >= N_JOINTS) {
        k = 0;
        if (adc_rounds < 255) adc_rounds++;
    }
    adc_k = k;
    adc_start(k);
}

/* The L298 pins, resolved once (digitalWrite/analogWrite look them up on every call):
 * IN1/IN2 port bits; EN's timer compare register and its COMnx1 bit in TCCRnA. */
struct MotorPins {
    volatile uint8_t *in1, *in2, *en;
    uint8_t in1_bit, in2_bit, en_bit;
    volatile uint8_t *tccra, *ocr;
    uint8_t com_bit;
    bool wide;
};
static MotorPins mp[N_JOINTS];

static void pwm_regs(uint8_t timer, MotorPins *m) {
    switch (timer) {
        case TIMER1A: m->tccra = &TCCR1A; m->com_bit = _BV(COM1A1); m->ocr = (volatile uint8_t *)&OCR1A; m->wide = true; break;
        case TIMER1B: m->tccra = &TCCR1A; m->com_bit = _BV(COM1B1); m->ocr = (volatile uint8_t *)&OCR1B; m->wide = true; break;
        case TIMER2A: m->tccra = &TCCR2A; m->com_bit = _BV(COM2A1); m->ocr = &OCR2A; m->wide = false; break;
        case TIMER2B: m->tccra = &TCCR2A; m->com_bit = _BV(COM2B1); m->ocr = &OCR2B; m->wide = false; break;
        case TIMER3A: m->tccra = &TCCR3A; m->com_bit = _BV(COM3A1); m->ocr = (volatile uint8_t *)&OCR3A; m->wide = true; break;
        case TIMER4A: m->tccra = &TCCR4A; m->com_bit = _BV(COM4A1); m->ocr = (volatile uint8_t *)&OCR4A; m->wide = true; break;
        default: m->tccra = 0; m->ocr = 0; m->com_bit = 0; m->wide = false; break;   /* no PWM: on/off */
    }
}


/* Every EN low (PWM disconnected) and every IN low: the L298 outputs float, the
 * motors stop. Called from the receive interrupt, so the callers outside it block
 * interrupts around their own pin writes (analogWrite's read-modify-write of TCCRnA
 * is not atomic). */
static inline __attribute__((always_inline)) void motors_off() {
    for (uint8_t k = 0; k < N_JOINTS; k++) {  /* as digitalWrite(LOW) (PWM off), on the registers */
        const MotorPins &m = mp[k];
        if (m.tccra) *m.tccra &= (uint8_t)~m.com_bit;
        *m.en &= (uint8_t)~m.en_bit;
        *m.in1 &= (uint8_t)~m.in1_bit;
        *m.in2 &= (uint8_t)~m.in2_bit;
    }
}

/* The low 16 bits of micros(), inline (interrupts are off in an interrupt): the core's
 * micros() is a call of ~6 us, and the receive interrupt is the one that meets the
 * control period's most often (a byte every 87 us while the host streams). */
extern volatile unsigned long timer0_overflow_count;   /* wiring.c's */
static inline uint16_t micros16() {
    uint16_t m = (uint16_t)timer0_overflow_count;
    uint8_t t = TCNT0;
    if ((TIFR0 & _BV(TOV0)) && t < 255) m++;
    return (uint16_t)((uint16_t)((m << 8) + t) << 2);   /* 64 / 16 MHz: 4 us a count */
}

/* One received byte: the e-stop at once, then the ring with its time. The receive
 * interrupt's body, and the control period's alignment wait polls it (below). */
static inline __attribute__((always_inline)) void rx_take() {
    uint8_t status = UCSR0A;
    uint8_t b = UDR0;
    (void)status;
    if (b == AB_ESTOP_BYTE && estop_on) {   /* the receive path's e-stop: at once */
        motors_off();
        estop_flag = 1;
    }
    uint8_t next = (uint8_t)((rx_head + 1) % RX_RING);
    if (next == rx_tail) {                  /* ring full: the byte is lost */
        if (b == AB_ESTOP_BYTE && estop_on) estop_lost = 1;
        return;
    }
    rx_buf[rx_head] = b;
    rx_time[rx_head] = micros16();
    rx_head = next;
}

ISR(USART0_RX_vect) { rx_take(); }

ISR(USART0_UDRE_vect) {
    if (tx_head == tx_tail) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (uint16_t)((tx_tail + 1) % TX_RING);
}

void AvrHal::begin() {
    for (uint8_t k = 0; k < N_JOINTS; k++) {
        pinMode(kEn[k], OUTPUT);
        pinMode(kIn1[k], OUTPUT);
        pinMode(kIn2[k], OUTPUT);
        pinMode(kStopRet[k], INPUT_PULLUP);
        pinMode(kStopExt[k], INPUT_PULLUP);
        digitalWrite(kEn[k], LOW);          /* also turns the pin's PWM off */
        digitalWrite(kIn1[k], LOW);
        digitalWrite(kIn2[k], LOW);
    }
    for (uint8_t k = 0; k < N_JOINTS; k++) {
        MotorPins &m = mp[k];
        m.in1 = portOutputRegister(digitalPinToPort(kIn1[k]));
        m.in1_bit = digitalPinToBitMask(kIn1[k]);
        m.in2 = portOutputRegister(digitalPinToPort(kIn2[k]));
        m.in2_bit = digitalPinToBitMask(kIn2[k]);
        m.en = portOutputRegister(digitalPinToPort(kEn[k]));
        m.en_bit = digitalPinToBitMask(kEn[k]);
        pwm_regs(digitalPinToTimer(kEn[k]), &m);
    }
    /* the ADC on its own (init() enabled it with the /128 prescaler), then one full
       round so the first read_adc() is a real sample */
    for (uint8_t k = 0; k < N_JOINTS; k++) {
        uint8_t ch = kBend[k];
        adc_mux[k] = (uint8_t)(_BV(REFS0) | (ch & 7));   /* AVcc reference, as analogRead's DEFAULT */
        adc_mux5[k] = (ch >> 3) & 1 ? _BV(MUX5) : 0;
    }
    ADCSRA |= _BV(ADIE);
    adc_k = 0;
    adc_start(0);
    while (adc_rounds < 1) {
    }
    ee_begin();
    /* 115200 baud, 8N1, double speed (as the core: UBRR 16, 2.1 % fast) */
    UCSR0A = _BV(U2X0);
    uint16_t ubrr = (uint16_t)((F_CPU / 8 / UART_BAUD) - 1);
    UBRR0H = (uint8_t)(ubrr >> 8);
    UBRR0L = (uint8_t)ubrr;
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

uint32_t AvrHal::ms() { return millis(); }
uint32_t AvrHal::us() { return micros(); }

int AvrHal::uart_read() {
    if (rx_head == rx_tail) return -1;
    uint8_t b = rx_buf[rx_tail];
    rx_tail = (uint8_t)((rx_tail + 1) % RX_RING);
    return b;
}

/* The byte's time: the low 16 bits stamped in the interrupt, widened against now
 * (exact while a byte waits less than 65 ms in the ring: the loop drains it every
 * pass, and a pass is far shorter). */
int AvrHal::uart_read_at(uint32_t *t_us) {
    if (rx_head == rx_tail) return -1;
    uint32_t now = micros();
    uint8_t b = rx_buf[rx_tail];
    uint16_t t = rx_time[rx_tail];
    rx_tail = (uint8_t)((rx_tail + 1) % RX_RING);
    *t_us = now - (uint16_t)((uint16_t)now - t);
    return b;
}

size_t AvrHal::tx_room() {
    uint16_t used;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { used = (uint16_t)((tx_head + TX_RING - tx_tail) % TX_RING); }
    return (size_t)(TX_RING - 1 - used);
}

void AvrHal::uart_write(const uint8_t *data, size_t n) {
    for (size_t i = 0; i < n; i++) {
        uint16_t next = (uint16_t)((tx_head + 1) % TX_RING);
        while (next == tx_tail) {           /* full: the UDRE interrupt drains it */
        }
        tx_buf[tx_head] = data[i];
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
            tx_head = next;
            UCSR0B |= _BV(UDRIE0);
        }
    }
}

bool AvrHal::estop_seen() { return estop_flag != 0; }
void AvrHal::clear_estop() { estop_flag = 0; }

bool AvrHal::estop_dropped() {
    if (!estop_lost) return false;
    estop_lost = 0;
    return true;
}

void AvrHal::set_estop_byte(bool on) { estop_on = on ? 1 : 0; }

void AvrHal::outputs_off() {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { motors_off(); }
}

/* Direct register writes (the pins resolved in begin()): EN's compare value with its
 * COMnx1 bit set is the PWM (255 = always on in the core's 8-bit phase-correct mode);
 * off is COMnx1 clear and the pin low, as digitalWrite(LOW). Interrupts are blocked
 * around it so the receive interrupt's e-stop cannot interleave. */
void AvrHal::write_duty(uint8_t k, int16_t duty) {
    if (duty > 1000) duty = 1000;
    if (duty < -1000) duty = -1000;
    uint16_t mag = (uint16_t)(duty < 0 ? -duty : duty);
    uint8_t pwm = (uint8_t)((uint16_t)(mag * 51u) / 200u);   /* x 255 / 1000 in 16 bits */
    const MotorPins &m = mp[k];
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        if (estop_flag || pwm == 0) {
            if (m.tccra) *m.tccra &= (uint8_t)~m.com_bit;
            *m.en &= (uint8_t)~m.en_bit;
            *m.in1 &= (uint8_t)~m.in1_bit;
            *m.in2 &= (uint8_t)~m.in2_bit;
        } else {
            if (duty > 0) {
                *m.in2 &= (uint8_t)~m.in2_bit;
                *m.in1 |= m.in1_bit;
            } else {
                *m.in1 &= (uint8_t)~m.in1_bit;
                *m.in2 |= m.in2_bit;
            }
            if (m.tccra) {
                if (m.wide) *(volatile uint16_t *)m.ocr = pwm;
                else *m.ocr = pwm;
                *m.tccra |= m.com_bit;
            } else {
                *m.en |= m.en_bit;
            }
        }
    }
}

uint16_t AvrHal::read_adc(uint8_t k) {
    uint16_t v;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { v = adc_val[k]; }
    return v;
}

uint8_t AvrHal::endstops() {
    uint8_t bits = 0;
    for (uint8_t k = 0; k < N_JOINTS; k++) {
        if (digitalRead(kStopRet[k]) == LOW) bits |= (uint8_t)(1u << (2 * k));
        if (digitalRead(kStopExt[k]) == LOW) bits |= (uint8_t)(2u << (2 * k));
    }
    return bits;
}

/* ------------------------------------------------------------------ the control period
 * Timer5 (not used by the core's millis (Timer0) nor by the EN pins' PWM (Timer2: pins
 * 9 and 10, Timer1: pin 11); its pins 44-46 are not wired) in CTC mode at F_CPU / 8:
 * OCR5A + 1 = 20,000 counts = 10 ms exactly, so its compare-match interrupt comes at a
 * fixed cycle every period whatever the main loop is doing. The interrupt re-enables
 * interrupts at once (after its re-entry check), so the receive interrupt's e-stop cuts
 * the outputs within its own latency while the period runs; a compare match that comes
 * while the period is still running is counted (ctl_overruns) and skipped, never nested.
 * The main loop's critical sections against the period (control_lock) mask only this
 * interrupt (OCIE5A), never the others: a compare match inside one sets OCF5A and the
 * period starts at the unlock. Only the main loop writes TIMSK5 outside the period;
 * the period's own lock/unlock pairs restore it before the main loop runs again. */
#define CTL_COUNTS ((uint16_t)(F_CPU / 8UL / 1000UL * PERIOD_MS))
static_assert(F_CPU / 8UL / 1000UL * PERIOD_MS <= 65536UL, "the period fits Timer5 at /8");
static void (*volatile ctl_fn)(void *);
static void *volatile ctl_arg;
static volatile uint8_t ctl_busy;           /* the period is running (its interrupt is on the stack) */
volatile uint16_t ctl_overruns;             /* (a global: the simavr harness watches it) compare matches that found it running: skipped */
static volatile uint8_t ctl_depth;          /* control_lock nesting */

/* The period proper, entered with interrupts off and ctl_busy set; returns with them off.
 * A function of its own so that the simavr harness times it ("period" probe). */
extern "C" void __attribute__((noinline)) ctl_period(void) {
    sei();                                  /* the e-stop (USART0 RX) and the rest stay live */
    ctl_fn(ctl_arg);
    cli();
}

/* The period starts at a fixed cycle: the interrupt is entered up to ~30 us after the
 * compare match (other interrupts running then: the receive, ADC, UDRE and Timer0
 * ones, ~5-10 us each, or a short lock of the main loop's with those inside it), so it
 * waits, interrupts off, until CTL_ALIGN counts (0.5 us each) after the match before
 * the period proper begins. While it waits it takes the received bytes itself (rx_take: the e-stop byte
 * cuts the outputs within ~1 us of its arrival, as in its own interrupt); the ADC, UDRE
 * and Timer0 interrupts wait at most CTL_ALIGN (their next event is 87 us or more away).
 * An entry later than that (a long lock: SETLIM, HELLO, CLR) starts at once. */
#define CTL_ALIGN 80                        /* 40 us */
static inline __attribute__((always_inline)) void ctl_enter() {
    while (TCNT5 < CTL_ALIGN) {
        if (UCSR0A & _BV(RXC0)) rx_take();
    }
    ctl_busy = 1;
    ctl_period();
    ctl_busy = 0;
}

ISR(TIMER5_COMPA_vect) {
    if (ctl_busy) {                         /* never nested: counted and skipped */
        if (ctl_overruns != 0xFFFF) ctl_overruns++;
        return;
    }
    ctl_enter();
}

bool AvrHal::start_control(void (*fn)(void *), void *arg) {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        ctl_fn = fn;
        ctl_arg = arg;
        TCCR5B = 0;                         /* stopped while it is set up */
        TCCR5A = 0;                         /* OC5A..C disconnected, WGM 0100: CTC on OCR5A */
        TCNT5 = 0;
        OCR5A = (uint16_t)(CTL_COUNTS - 1);
        TIFR5 = _BV(OCF5A);
        TIMSK5 = ctl_depth ? 0 : _BV(OCIE5A);
        TCCR5B = _BV(WGM52) | _BV(CS51);    /* clk / 8 */
    }
    return true;
}

void AvrHal::control_lock() {
    asm volatile("" ::: "memory");
    if (ctl_depth++ == 0) TIMSK5 = 0;
    asm volatile("" ::: "memory");
}

/* On the chip a compare match that came while OCIE5A was clear left OCF5A set, and the
 * interrupt runs as soon as OCIE5A is set again (hardware clears the flag on entry), so
 * the test below finds it clear. simavr 1.6 does not raise an interrupt whose flag was
 * set while it was disabled (measured: such a period was lost), so there the flag is
 * still set and the period runs here, at once, as the interrupt would have. */
void AvrHal::control_unlock() {
    asm volatile("" ::: "memory");
    if (--ctl_depth == 0 && ctl_fn) {
        TIMSK5 = _BV(OCIE5A);
        asm volatile("nop");                /* the pending interrupt is taken here on the chip */
        if (TIFR5 & _BV(OCF5A)) {
            uint8_t sreg = SREG;
            cli();
            if (!ctl_busy && (TIFR5 & _BV(OCF5A))) {
                TIFR5 = _BV(OCF5A);
                ctl_enter();
            }
            SREG = sreg;
        }
    }
    asm volatile("" ::: "memory");
}

uint16_t AvrHal::control_overruns() {
    uint16_t n;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { n = ctl_overruns; }
    return n;
}
