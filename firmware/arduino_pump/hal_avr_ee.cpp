/* The Mega 2560 HAL's memories (hal_avr.h): the EEPROM behind a RAM shadow, written one
 * byte per main-loop pass (programming a byte takes 3.4 ms: a blocking write would stall
 * the receive path), and the .noinit SRAM kept across a reset. Main loop only: the
 * control period never touches them. */
#include "hal_avr.h"

#include <Arduino.h>
#include <avr/eeprom.h>
#include <string.h>

#include "config.h"

static uint8_t ee_shadow[EE_SIZE];
static uint8_t ee_dirty[(EE_SIZE + 7) / 8];
/* Kept across a reset (not a power cycle): the C runtime leaves .noinit as it was. */
static uint8_t keep_area[KEEP_SIZE] __attribute__((section(".noinit")));

void ee_begin() { eeprom_read_block(ee_shadow, (const void *)0, EE_SIZE); }

void AvrHal::service() {
    if (EECR & _BV(EEPE)) return;           /* the last byte is still being programmed */
    for (uint16_t i = 0; i < EE_SIZE; i++) {
        if (ee_dirty[i >> 3] & (1u << (i & 7))) {
            ee_dirty[i >> 3] &= (uint8_t)~(1u << (i & 7));
            if (eeprom_read_byte((const uint8_t *)i) != ee_shadow[i])
                eeprom_write_byte((uint8_t *)i, ee_shadow[i]);   /* starts it; does not wait */
            return;
        }
    }
}

void AvrHal::ee_read(uint16_t addr, void *dst, size_t n) {
    uint8_t *d = (uint8_t *)dst;
    for (size_t i = 0; i < n; i++) d[i] = addr + i < EE_SIZE ? ee_shadow[addr + i] : 0xFF;
}

void AvrHal::ee_write_now(uint16_t addr, uint8_t value) {
    if (addr >= EE_SIZE) return;
    ee_shadow[addr] = value;
    ee_dirty[addr >> 3] &= (uint8_t)~(1u << (addr & 7));
    if (eeprom_read_byte((const uint8_t *)addr) != value)
        eeprom_write_byte((uint8_t *)addr, value);   /* waits for EEPE, starts it, returns */
}

void AvrHal::ee_write(uint16_t addr, const void *src, size_t n) {
    const uint8_t *s = (const uint8_t *)src;
    for (size_t i = 0; i < n && addr + i < EE_SIZE; i++) {
        uint16_t a = (uint16_t)(addr + i);
        if (ee_shadow[a] != s[i]) {
            ee_shadow[a] = s[i];
            ee_dirty[a >> 3] |= (uint8_t)(1u << (a & 7));
        }
    }
}

void AvrHal::keep_read(void *dst, size_t n) { memcpy(dst, keep_area, n < KEEP_SIZE ? n : KEEP_SIZE); }
void AvrHal::keep_write(const void *src, size_t n) { memcpy(keep_area, src, n < KEEP_SIZE ? n : KEEP_SIZE); }
