/*
 * armbridge simavr harness: one AVR .elf, driven in lockstep by a parent
 * process over stdin/stdout (host/armbridge/emulator/simavr_runner.py).
 *
 * The parent owns time: every RUN request says "run until this cycle, feeding
 * these UART0 bytes at their cycles, with these ADC inputs and pin levels",
 * and the answer says what the chip did meanwhile: the UART0 bytes it sent
 * (with the cycle of each UDR0 write), every change of the watched data
 * bytes (timer/port registers: the parent decodes PWM duty from OCRnx and
 * COMnx1, as simavr's mega2560 model fires no PWM IRQs for phase-correct
 * PWM), the entries/durations of probed code addresses, the lowest stack
 * pointer and whether the EEPROM changed. Nothing here runs on its own.
 *
 * Usage: harness [-m MCU] [-f HZ] [-e EEPROM_FILE] FIRMWARE.elf
 *
 * Protocol: text lines, one request, one answer, numbers in decimal, bytes in
 * hex; an empty list is "-". First the harness says
 *     READY <mcu> <hz> <ramend> <e2end> <cycle>
 * then answers:
 *     WATCH a1 a2 ...        data-space addresses to watch (<= 64)      -> OK <n>
 *     PROBE p1 p2 ...        flash byte addresses to time (<= 16)       -> OK <n>
 *     ADCSTART csra bit mux  log ADC conversion starts: the store that sets bit
 *                            `bit` of the byte at `csra`, with the channel (low
 *                            five bits) of the byte at `mux`             -> OK
 *     RUN <until> <uart> <adc> <pins>
 *         uart  c:hh,c:hh,...  a byte for UART0 at cycle c (given in order)
 *         adc   ch:mv,...      ADC channel ch at mv millivolts (held)
 *         pins  Pb:l,...       pin b of port P (A..L) driven at level l (held)
 *       -> DONE <cycle> <state> <tx> <watch> <probes> <minsp> <ee> <lost> <txbyte> <adc>
 *         tx     c:hh,...      UART0 output bytes, cycle of the UDR0 write
 *         watch  c:v.v.v;...   after a change: the cycle and every watched byte
 *                              (the first record of a slice is its start state)
 *         probes i:c:d,...     probe i entered at cycle c, returned d cycles later
 *         minsp  lowest SP seen in the slice
 *         ee     1 when the EEPROM changed in the slice (then written to the file)
 *         lost   UART0 input bytes the full receive FIFO refused in the slice
 *         txbyte cycles one UART0 frame takes at the end of the slice (from
 *                UBRR, U2X and the frame format the firmware programmed, as
 *                fix_uart_timing sets it), 0 while the transmitter is off
 *         adc    c:ch,...      ADC conversions started (ADCSTART), cycle and channel
 *         state  simavr's cpu state: 2 running, 3 sleeping, 7 done, 8 crashed
 *     RESET                  the chip's reset pin: registers and I/O reset,
 *                            SRAM, EEPROM and flash kept                -> OK <cycle>
 *     EEPROM                 -> OK <hex of the whole EEPROM>
 *     QUIT                   writes the EEPROM file and exits           -> OK
 *
 * Boot mode (harness -B FLASH_FILE -b BOOTLOADER.hex [-e EEPROM_FILE]): no
 * lockstep and no ELF. The chip boots the bootloader (every chunk of the hex:
 * the Mega's stk500v2 one is a single chunk at byte 0x3E000) with its flash
 * kept in FLASH_FILE (mmap'd, created erased), so what avrdude writes through
 * the bootloader survives the process and the next boot runs it. UART0 is a
 * pty (simavr's uart_pty); the harness prints "PTY <path>" on stdout, runs
 * paced to real time, and resets the chip whenever the pty is opened (inotify
 * IN_OPEN on the slave) by nobody else, as DTR does on a real Mega (raised by
 * the first open, dropped by the last close), so avrdude catches the
 * bootloader's window. SIGTERM/SIGINT sync the flash and the EEPROM and exit.
 *
 * Cost: the watch is compared after store instructions only (every watched byte is
 * one the CPU writes) and a probe's entry is one bitmap load, so the slice's work is
 * simavr's own plus little; a conversion start is one record, not three watch
 * records (ADSC set, ADSC cleared, ADMUX changed).
 *
 * What the harness fixes in simavr 1.6 (docs/emulator.md, toolchain notes):
 * vcc/avcc/aref 5000 mV; external interrupts not strictly level triggered
 * (a LOW level would poll every cycle); no UART poll-sleep and no usleep when
 * the CPU sleeps (the parent paces); no UART stdio echo (simavr's own prints
 * go to stderr: fd 1 is redirected there, the protocol keeps a private copy);
 * UART byte time from the real frame (start + data + parity if enabled +
 * stop bits: simavr counts a parity bit always, which made 115200 baud
 * 8N1 a byte per 93.5 us instead of 85 us); the EEPROM's programming time
 * (simavr stores a byte and clears EEPE at once; the chip keeps EEPE set for
 * 3.4 ms a byte, so a write-behind record takes its real time: the harness
 * holds EEPE set for EE_WRITE_US after each write it sees start).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <fcntl.h>
#include <signal.h>
#include <time.h>
#include <sys/inotify.h>
#include <sys/mman.h>
#include <sys/stat.h>

#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_core.h"
#include "sim_irq.h"
#include "sim_io.h"
#include "sim_regbit.h"
#include "sim_cycle_timers.h"
#include "avr_uart.h"
#include "avr_adc.h"
#include "avr_ioport.h"
#include "avr_extint.h"
#include "avr_eeprom.h"
#include "sim_hex.h"
#include "parts/uart_pty.h"

DEFINE_FIFO(uint16_t, uart_fifo);   /* the accessors of simavr's UART input FIFO */

#define MAX_WATCH 64
#define MAX_PROBE 16
#define MAX_FEED 4096
#define PROBE_DEPTH 4
#define N_PORTS 12          /* A..L */
#define EE_WRITE_US 3400    /* a byte's programming time (datasheet: 3.4 ms, erase and write) */

static avr_t *avr;
static FILE *proto;         /* the protocol's stdout */
static const char *ee_file;
static uint8_t *ee_mem;
static uint32_t ee_size;
static uint8_t *ee_shadow;
static avr_uart_t *uart0;
static avr_eeprom_t *ee_io;
static avr_cycle_count_t ee_mpe_at;     /* cycle EEMPE was last set */
static int ee_busy;                     /* a byte is being programmed: EEPE reads 1 */

static uint16_t watch_addr[MAX_WATCH];
static uint8_t watch_val[MAX_WATCH];
static int n_watch;

static uint32_t probe_pc[MAX_PROBE];
static int n_probe;
static int probe_open;                  /* probed calls not yet returned */
#define PROBE_MAP_WORDS (1u << 17)      /* 256 KiB of flash, in words */
static uint8_t probe_map[PROBE_MAP_WORDS / 8];
static uint16_t adc_csra, adc_mux;      /* ADCSTART: ADCSRA and ADMUX addresses (0: off) */
static uint8_t adc_start_bit;
static struct { avr_cycle_count_t at; uint16_t sp; } probe_stack[MAX_PROBE][PROBE_DEPTH];
static int probe_depth[MAX_PROBE];

static int adc_mv[16];
static int adc_set[16];
static uint8_t pin_mask[N_PORTS], pin_value[N_PORTS];   /* pins the parent drives */

/* output of one slice, grown as needed */
static char *out;
static size_t out_len, out_cap;
static char *tx_buf, *watch_buf, *probe_buf, *adc_buf;
static size_t tx_len, tx_cap, watch_len, watch_cap, probe_len, probe_cap, adc_len, adc_cap;
static unsigned long lost;

static void die(const char *msg)
{
	fprintf(stderr, "harness: %s\n", msg);
	exit(2);
}

static void append(char **buf, size_t *len, size_t *cap, const char *fmt, ...)
	__attribute__((format(printf, 4, 5)));

#include <stdarg.h>
static void append(char **buf, size_t *len, size_t *cap, const char *fmt, ...)
{
	for (;;) {
		va_list ap;
		va_start(ap, fmt);
		size_t room = *cap - *len;
		int n = vsnprintf(*buf ? *buf + *len : NULL, *buf ? room : 0, fmt, ap);
		va_end(ap);
		if (n < 0)
			die("format error");
		if (*buf && (size_t)n < room) {
			*len += (size_t)n;
			return;
		}
		size_t want = *cap ? *cap * 2 : 4096;
		while (want < *len + (size_t)n + 1)
			want *= 2;
		*buf = realloc(*buf, want);
		if (!*buf)
			die("out of memory");
		*cap = want;
	}
}

/* ------------------------------------------------------------- the chip */

static void no_sleep(avr_t *a, avr_cycle_count_t how_long)
{
	(void)a; (void)how_long;    /* the parent paces simulated time */
}

static avr_cycle_count_t wake(avr_t *a, avr_cycle_count_t when, void *param)
{
	(void)a; (void)when; (void)param;
	return 0;                   /* only bounds a sleep: feed/until times are exact */
}

static void uart_out(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq; (void)param;
	append(&tx_buf, &tx_len, &tx_cap, "%s%llu:%02x", tx_len ? "," : "",
	       (unsigned long long)avr->cycle, value & 0xff);
}

static void uart_xoff(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq; (void)value; (void)param;
}

static uint16_t sp_now(void)
{
	return (uint16_t)(avr->data[R_SPL] | (avr->data[R_SPH] << 8));
}

/* simavr counts a parity bit in every frame; the real frame has one only
 * when UPM0n is set. */
static void fix_uart_timing(void)
{
	avr_uart_t *p = uart0;
	if (!p || !p->ubrrl.reg)
		return;
	uint32_t ubrr = avr_regbit_get(avr, p->ubrrl) | ((uint32_t)avr_regbit_get(avr, p->ubrrh) << 8);
	static const int databits[] = { 5, 6, 7, 8, 8, 8, 8, 9 };
	int db = databits[avr_regbit_get(avr, p->ucsz) | (avr_regbit_get(avr, p->ucsz2) << 2)];
	int sb = 1 + avr_regbit_get(avr, p->usbs);
	int parity = (p->r_ucsrc && (avr->data[p->r_ucsrc] & 0x30)) ? 1 : 0;
	avr_cycle_count_t bit = (ubrr + 1) * 8 * (avr_regbit_get(avr, p->u2x) ? 1 : 2);
	avr_cycle_count_t want = bit * (avr_cycle_count_t)(1 + db + parity + sb);
	if (p->cycles_per_byte != want)
		p->cycles_per_byte = want;
}

/* The byte time the chip transmits at (cycles), 0 while TXEN0 is clear. */
static avr_cycle_count_t uart_tx_cycles(void)
{
	if (!uart0 || !uart0->ubrrl.reg || !avr_regbit_get(avr, uart0->txen))
		return 0;
	fix_uart_timing();
	return uart0->cycles_per_byte;
}

static void raise_pins(int force)
{
	for (int i = 0; i < N_PORTS; i++) {
		if (!pin_mask[i])
			continue;
		char name = (char)('A' + i);
		avr_ioport_external_t ext = { .name = name, .mask = pin_mask[i], .value = pin_value[i] };
		if (avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL(name), &ext) < 0)
			continue;   /* no such port on this chip (checked when the pin was set) */
		for (int b = 0; b < 8; b++) {
			if (!(pin_mask[i] & (1 << b)))
				continue;
			avr_irq_t *irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(name), b);
			int level = (pin_value[i] >> b) & 1;
			if (force)  /* the IRQ keeps its last value across a reset (filtered) */
				avr_raise_irq(irq, !level);
			avr_raise_irq(irq, level);
		}
	}
}

static void raise_adc(int ch, int force)
{
	avr_irq_t *irq = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + ch);
	if (!irq)
		return;
	if (force)
		avr_raise_irq(irq, (uint32_t)adc_mv[ch] + 1);
	avr_raise_irq(irq, (uint32_t)adc_mv[ch]);
}

static avr_cycle_count_t ee_ready(avr_t *a, avr_cycle_count_t when, void *param);

/* The reset pin as the chip has it: registers and I/O to their reset values, the
 * SRAM kept (it is only undefined at power on; the firmware keeps its link record
 * in .noinit there across a reset). simavr's avr_reset may clear the data space,
 * so the SRAM above the I/O area is put back after it. */
static void chip_reset(void)
{
	size_t lo = avr->ioend ? (size_t)avr->ioend + 1 : 0x200, n = (size_t)avr->ramend + 1 - lo;
	uint8_t *keep = malloc(n);
	if (keep)
		memcpy(keep, avr->data + lo, n);
	avr_reset(avr);
	if (keep) {
		memcpy(avr->data + lo, keep, n);
		free(keep);
	}
}

/* after avr_init and after every reset */
static void setup_chip(void)
{
	avr->vcc = avr->avcc = avr->aref = 5000;
	avr->sleep = no_sleep;
	for (int i = 0; i < 8; i++)
		avr_extint_set_strict_lvl_trig(avr, (uint8_t)i, 0);
	for (char u = '0'; u <= '3'; u++) {
		uint32_t flags = 0;
		if (avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS(u), &flags) == 0) {
			flags &= ~(uint32_t)(AVR_UART_FLAG_POLL_SLEEP | AVR_UART_FLAG_STDIO);
			avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS(u), &flags);
		}
	}
	raise_pins(1);
	for (int ch = 0; ch < 16; ch++)
		if (adc_set[ch])
			raise_adc(ch, 1);
	for (int i = 0; i < n_probe; i++)
		probe_depth[i] = 0;
	probe_open = 0;
	ee_busy = 0;    /* a reset clears EECR */
	avr_cycle_timer_cancel(avr, ee_ready, NULL);
	ee_mpe_at = 0;
}

/* ---- EEPROM programming time. Our write hook on EECR runs after simavr's own
 * (simavr chains writers of one address): EEMPE then EEPE within 4 cycles starts a
 * write; from then EEPE reads 1 until EE_WRITE_US of simulated time have passed. */
static avr_cycle_count_t ee_ready(avr_t *a, avr_cycle_count_t when, void *param)
{
	(void)when; (void)param;
	ee_busy = 0;
	a->data[ee_io->r_eecr] &= (uint8_t)~(1u << ee_io->eepe.bit);
	return 0;
}

static void ee_eecr_write(avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
	(void)addr; (void)param;
	int mpe = (v >> ee_io->eempe.bit) & 1, pe = (v >> ee_io->eepe.bit) & 1;
	if (mpe && !pe) {
		ee_mpe_at = a->cycle;
	} else if (pe && !ee_busy && a->cycle - ee_mpe_at <= 4) {
		ee_busy = 1;
		avr_cycle_timer_register(a, (avr_cycle_count_t)a->frequency / 1000000 * EE_WRITE_US, ee_ready, NULL);
	}
	if (ee_busy)
		a->data[ee_io->r_eecr] |= (uint8_t)(1u << ee_io->eepe.bit);
}

static void ee_timing_init(void)
{
	for (avr_io_t *io = avr->io_port; io; io = io->next)
		if (io->kind && !strcmp(io->kind, "eeprom"))
			ee_io = (avr_eeprom_t *)io;
	if (ee_io && ee_io->r_eecr)
		avr_register_io_write(avr, ee_io->r_eecr, ee_eecr_write, NULL);
	else
		ee_io = NULL;
}

static avr_uart_t *find_uart0(void)
{
	for (avr_io_t *io = avr->io_port; io; io = io->next)
		if (io->kind && !strcmp(io->kind, "uart") && ((avr_uart_t *)io)->name == '0')
			return (avr_uart_t *)io;
	return NULL;
}

static void ee_save(void)
{
	if (!ee_file || !ee_mem)
		return;
	char tmp[4096];
	snprintf(tmp, sizeof tmp, "%s.tmp", ee_file);
	FILE *f = fopen(tmp, "wb");
	if (!f || fwrite(ee_mem, 1, ee_size, f) != ee_size || fclose(f) != 0) {
		fprintf(stderr, "harness: cannot write %s: %s\n", tmp, strerror(errno));
		return;
	}
	if (rename(tmp, ee_file) != 0)
		fprintf(stderr, "harness: cannot rename %s: %s\n", tmp, strerror(errno));
}

static int ee_changed(void)
{
	if (!ee_mem || !memcmp(ee_mem, ee_shadow, ee_size))
		return 0;
	memcpy(ee_shadow, ee_mem, ee_size);
	ee_save();
	return 1;
}

static void ee_open(void)
{
	avr_eeprom_desc_t d = { .ee = NULL, .offset = 0, .size = 0 };
	if (avr_ioctl(avr, AVR_IOCTL_EEPROM_GET, &d) != 0 && !d.ee)
		return;
	ee_mem = d.ee;
	ee_size = avr->e2end + 1;
	ee_shadow = malloc(ee_size);
	if (!ee_mem || !ee_shadow)
		return;
	if (ee_file) {
		FILE *f = fopen(ee_file, "rb");
		if (f) {
			size_t n = fread(ee_mem, 1, ee_size, f);
			fclose(f);
			if (n != ee_size)
				fprintf(stderr, "harness: %s holds %zu bytes, the EEPROM %u: the rest erased\n",
				        ee_file, n, ee_size);
			if (n < ee_size)
				memset(ee_mem + n, 0xff, ee_size - n);
		}
	}
	memcpy(ee_shadow, ee_mem, ee_size);
}

/* ------------------------------------------------------------- sampling */

static void record_watch(void)
{
	append(&watch_buf, &watch_len, &watch_cap, "%s%llu:", watch_len ? ";" : "",
	       (unsigned long long)avr->cycle);
	for (int i = 0; i < n_watch; i++)
		append(&watch_buf, &watch_len, &watch_cap, i ? ".%x" : "%x", watch_val[i]);
}

/* Whether the instruction word `op` stores to the data space: OUT, SBI/CBI, STS, ST
 * X/Y/Z (with PUSH and the rest of 1001 001x), ST/STD Y+q/Z+q. Only such an instruction
 * can change a watched register (they are all written by the CPU alone: ports, DDRs,
 * timer set-up and compare registers), so the watch is scanned after these only. */
static inline int is_store(uint16_t op)
{
	return (op & 0xF800) == 0xB800 || (op & 0xFD00) == 0x9800 || (op & 0xFE00) == 0x9200
	       || (op & 0xD200) == 0x8200;
}

static inline void scan_watch(void)
{
	int changed = 0;
	for (int i = 0; i < n_watch; i++) {
		uint8_t v = avr->data[watch_addr[i]];
		if (v != watch_val[i]) {
			watch_val[i] = v;
			changed = 1;
		}
	}
	if (changed)
		record_watch();
}

/* Probes: a bitmap of the probed entry addresses (one bit a flash word) keeps the
 * per-instruction test to one load while no probed call is open. */
static inline void probe_step(uint16_t sp)
{
	if (probe_open) {
		for (int i = 0; i < n_probe; i++) {
			int d = probe_depth[i];
			if (d && sp > probe_stack[i][d - 1].sp) {     /* returned */
				d = --probe_depth[i];
				probe_open--;
				append(&probe_buf, &probe_len, &probe_cap, "%s%d:%llu:%llu", probe_len ? "," : "", i,
				       (unsigned long long)probe_stack[i][d].at,
				       (unsigned long long)(avr->cycle - probe_stack[i][d].at));
			}
		}
	}
	uint32_t w = avr->pc >> 1;
	if (w < PROBE_MAP_WORDS && (probe_map[w >> 3] >> (w & 7)) & 1) {
		for (int i = 0; i < n_probe; i++) {
			if (avr->pc == probe_pc[i] && probe_depth[i] < PROBE_DEPTH) {
				probe_stack[i][probe_depth[i]].at = avr->cycle;
				probe_stack[i][probe_depth[i]].sp = sp;
				probe_depth[i]++;
				probe_open++;
			}
		}
	}
}

/* One instruction (or a sleeping stretch up to the next event) and what it did to
 * the watched state: outputs after a store, an ADC conversion it started (ADSC
 * rising by this store), probe entries and returns, the lowest SP. */
static inline int step(uint16_t *minsp)
{
	uint32_t pc = avr->pc;
	uint16_t op = pc + 1 < avr->flashend ? (uint16_t)(avr->flash[pc] | (avr->flash[pc + 1] << 8)) : 0;
	int store = avr->state == cpu_Running && is_store(op);
	uint8_t adsc = store && adc_csra ? avr->data[adc_csra] & adc_start_bit : 0;
	int state = avr_run(avr);
	uint16_t sp = sp_now();
	if (sp < *minsp)
		*minsp = sp;
	if (store) {
		scan_watch();
		if (adc_csra && !adsc && (avr->data[adc_csra] & adc_start_bit))
			append(&adc_buf, &adc_len, &adc_cap, "%s%llu:%u", adc_len ? "," : "",
			       (unsigned long long)avr->cycle, (unsigned)(avr->data[adc_mux] & 0x1F));
	}
	if (n_probe)
		probe_step(sp);
	return state;
}

/* ------------------------------------------------------------- requests */

static struct { avr_cycle_count_t at; uint8_t b; } feed[MAX_FEED];
static int n_feed;
static int wake_until, wake_feed;

static int parse_run(char *args, avr_cycle_count_t *until)
{
	char *save = NULL;
	char *tok = strtok_r(args, " \n", &save);
	if (!tok)
		return -1;
	*until = strtoull(tok, NULL, 10);
	char *uart = strtok_r(NULL, " \n", &save);
	char *adc = strtok_r(NULL, " \n", &save);
	char *pins = strtok_r(NULL, " \n", &save);
	if (!uart || !adc || !pins)
		return -1;
	n_feed = 0;
	if (strcmp(uart, "-")) {
		for (char *s = uart; s && *s;) {
			char *end;
			unsigned long long at = strtoull(s, &end, 10);
			if (*end != ':' || n_feed >= MAX_FEED)
				return -1;
			feed[n_feed].at = at;
			feed[n_feed].b = (uint8_t)strtoul(end + 1, &end, 16);
			n_feed++;
			s = *end == ',' ? end + 1 : NULL;
		}
	}
	if (strcmp(adc, "-")) {
		for (char *s = adc; s && *s;) {
			char *end;
			long ch = strtol(s, &end, 10);
			if (*end != ':' || ch < 0 || ch > 15)
				return -1;
			long mv = strtol(end + 1, &end, 10);
			if (!adc_set[ch] || adc_mv[ch] != mv) {
				adc_mv[ch] = (int)mv;
				adc_set[ch] = 1;
				raise_adc((int)ch, 0);
			}
			s = *end == ',' ? end + 1 : NULL;
		}
	}
	if (strcmp(pins, "-")) {
		for (char *s = pins; s && *s;) {
			int port = s[0] - 'A';
			char *end;
			long bit = strtol(s + 1, &end, 10);
			if (port < 0 || port >= N_PORTS || bit < 0 || bit > 7 || *end != ':')
				return -1;
			long level = strtol(end + 1, &end, 10);
			pin_mask[port] |= (uint8_t)(1 << bit);
			if (level)
				pin_value[port] |= (uint8_t)(1 << bit);
			else
				pin_value[port] &= (uint8_t)~(1 << bit);
			s = *end == ',' ? end + 1 : NULL;
		}
	}
	raise_pins(0);
	return 0;
}

static void do_run(char *args)
{
	avr_cycle_count_t until;
	if (parse_run(args, &until) < 0) {
		fprintf(proto, "ERR bad RUN request\n");
		return;
	}
	tx_len = watch_len = probe_len = adc_len = 0;
	lost = 0;
	uint16_t minsp = sp_now();
	fix_uart_timing();
	record_watch();   /* the state the slice starts from */
	avr_irq_t *in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
	if (until > avr->cycle)
		avr_cycle_timer_register(avr, until - avr->cycle, wake, &wake_until);
	int fi = 0;
	int state = avr->state;
	while (avr->cycle < until && state != cpu_Done && state != cpu_Crashed) {
		while (fi < n_feed && feed[fi].at <= avr->cycle) {
			fix_uart_timing();
			if (uart0 && uart_fifo_isfull(&uart0->input))
				lost++;
			avr_raise_irq(in, feed[fi].b);
			fi++;
			if (fi < n_feed && feed[fi].at > avr->cycle)
				avr_cycle_timer_register(avr, feed[fi].at - avr->cycle, wake, &wake_feed);
		}
		if (fi == 0 && n_feed && feed[0].at > avr->cycle)
			avr_cycle_timer_register(avr, feed[0].at - avr->cycle, wake, &wake_feed);
		state = step(&minsp);
	}
	for (; fi < n_feed; fi++)   /* a chip that stopped still "receives" them */
		avr_raise_irq(in, feed[fi].b);
	int ee = ee_changed();
	out_len = 0;
	append(&out, &out_len, &out_cap, "DONE %llu %d %s %s %s %u %d %lu %llu %s\n",
	       (unsigned long long)avr->cycle, state,
	       tx_len ? tx_buf : "-", watch_len ? watch_buf : "-", probe_len ? probe_buf : "-",
	       minsp, ee, lost, (unsigned long long)uart_tx_cycles(), adc_len ? adc_buf : "-");
	fwrite(out, 1, out_len, proto);
}

static void do_list(char *args, int probe)
{
	int n = 0;
	char *save = NULL;
	for (char *tok = strtok_r(args, " \n", &save); tok; tok = strtok_r(NULL, " \n", &save)) {
		unsigned long v = strtoul(tok, NULL, 0);
		if (probe) {
			if (n >= MAX_PROBE) { fprintf(proto, "ERR at most %d probes\n", MAX_PROBE); return; }
			probe_pc[n] = (uint32_t)v;
			probe_depth[n] = 0;
		} else {
			if (n >= MAX_WATCH || v > avr->ramend) {
				fprintf(proto, "ERR watch address %lu: at most %d, below %u\n", v, MAX_WATCH, avr->ramend);
				return;
			}
			watch_addr[n] = (uint16_t)v;
			watch_val[n] = avr->data[v];
		}
		n++;
	}
	if (probe) {
		n_probe = n;
		probe_open = 0;
		memset(probe_map, 0, sizeof probe_map);
		for (int i = 0; i < n; i++) {
			uint32_t w = probe_pc[i] >> 1;
			if (w < PROBE_MAP_WORDS)
				probe_map[w >> 3] |= (uint8_t)(1u << (w & 7));
		}
	} else {
		n_watch = n;
	}
	fprintf(proto, "OK %d\n", n);
}

/* ------------------------------------------------------------- boot mode */

static volatile sig_atomic_t boot_quit;

static void boot_signal(int sig)
{
	(void)sig;
	boot_quit = 1;
}

static double now_s(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

/* The chip with its bootloader, its flash in a file, UART0 on a pty that resets it when opened. */
static int boot_main(const char *mcu, unsigned long hz, const char *flash_file, const char *boot_hex)
{
	avr = avr_make_mcu_by_name(mcu ? mcu : "atmega2560");
	if (!avr) {
		fprintf(stderr, "harness: unknown MCU %s\n", mcu);
		return 1;
	}
	avr_init(avr);
	uint32_t size = avr->flashend + 1;
	int ffd = open(flash_file, O_RDWR | O_CREAT, 0644);
	struct stat st;
	if (ffd < 0 || fstat(ffd, &st) != 0) {
		fprintf(stderr, "harness: cannot open %s: %s\n", flash_file, strerror(errno));
		return 1;
	}
	int fresh = st.st_size < (off_t)size;
	if (fresh && ftruncate(ffd, size) != 0) {
		fprintf(stderr, "harness: cannot size %s: %s\n", flash_file, strerror(errno));
		return 1;
	}
	uint8_t *flash = mmap(NULL, size, PROT_READ | PROT_WRITE, MAP_SHARED, ffd, 0);
	if (flash == MAP_FAILED) {
		fprintf(stderr, "harness: cannot map %s: %s\n", flash_file, strerror(errno));
		return 1;
	}
	if (fresh)
		memset(flash + st.st_size, 0xff, size - (uint32_t)st.st_size);   /* erased */
	free(avr->flash);
	avr->flash = flash;
	ihex_chunk_p chunks = NULL;
	int n = read_ihex_chunks(boot_hex, &chunks);
	if (n <= 0) {
		fprintf(stderr, "harness: cannot read the bootloader %s\n", boot_hex);
		return 1;
	}
	uint32_t start = 0xffffffff;
	for (int i = 0; i < n; i++) {
		if (chunks[i].baseaddr + chunks[i].size > size) {
			fprintf(stderr, "harness: %s: a chunk past the flash's end\n", boot_hex);
			return 1;
		}
		memcpy(flash + chunks[i].baseaddr, chunks[i].data, chunks[i].size);
		if (chunks[i].baseaddr < start)
			start = chunks[i].baseaddr;
	}
	free_ihex_chunks(chunks);
	/* avr_init reset the frequency and the pc: BOOTRST set, as the Mega's fuses have it */
	avr->frequency = hz ? (uint32_t)hz : 16000000;
	avr->reset_pc = avr->pc = start;
	uart0 = find_uart0();
	ee_timing_init();
	ee_open();
	setup_chip();

	static uart_pty_t pty;
	uart_pty_init(avr, &pty);
	uart_pty_connect(&pty, '0');
	int ino = inotify_init1(IN_NONBLOCK);
	if (ino < 0 || inotify_add_watch(ino, pty.port[0].slavename, IN_OPEN | IN_CLOSE) < 0) {
		fprintf(stderr, "harness: cannot watch %s: %s\n", pty.port[0].slavename, strerror(errno));
		return 1;
	}
	signal(SIGTERM, boot_signal);
	signal(SIGINT, boot_signal);
	fprintf(proto, "PTY %s\n", pty.port[0].slavename);
	fflush(proto);

	const avr_cycle_count_t slice = avr->frequency / 1000;     /* 1 ms, then pace and look at the pty */
	double t0 = now_s();
	avr_cycle_count_t c0 = avr->cycle;
	int opened = 0;     /* opens of the pty's slave not yet closed */
	while (!boot_quit) {
		avr_cycle_count_t until = avr->cycle + slice;
		while (avr->cycle < until) {
			int state = avr_run(avr);
			if (state == cpu_Done || state == cpu_Crashed) {
				fprintf(stderr, "harness: the chip stopped (state %d) at pc 0x%x\n", state, avr->pc);
				boot_quit = 1;
				break;
			}
		}
		char ev[4096] __attribute__((aligned(__alignof__(struct inotify_event))));
		ssize_t got = read(ino, ev, sizeof ev);
		int reset = 0;
		for (char *e = ev; got > 0 && e < ev + got; e += sizeof(struct inotify_event) + ((struct inotify_event *)e)->len) {
			uint32_t mask = ((struct inotify_event *)e)->mask;
			if (mask & IN_OPEN)      /* the first open raises DTR: its edge pulses the reset pin */
				reset |= opened++ == 0;
			if ((mask & (IN_CLOSE_WRITE | IN_CLOSE_NOWRITE)) && opened > 0)
				opened--;       /* the last close drops DTR (HUPCL) */
		}
		if (reset) {
			chip_reset();
			avr->state = cpu_Running;
			setup_chip();
			t0 = now_s();
			c0 = avr->cycle;
		}
		double ahead = (double)(avr->cycle - c0) / avr->frequency - (now_s() - t0);
		if (ahead > 0.001)
			usleep((useconds_t)(ahead * 1e6));
	}
	msync(flash, size, MS_SYNC);
	ee_save();
	uart_pty_stop(&pty);
	return 0;
}

int main(int argc, char **argv)
{
	const char *mcu = NULL;
	unsigned long hz = 0;
	const char *flash_file = NULL, *boot_hex = NULL;
	int opt;
	while ((opt = getopt(argc, argv, "m:f:e:B:b:")) != -1) {
		switch (opt) {
		case 'm': mcu = optarg; break;
		case 'f': hz = strtoul(optarg, NULL, 10); break;
		case 'e': ee_file = optarg; break;
		case 'B': flash_file = optarg; break;
		case 'b': boot_hex = optarg; break;
		default:
			fprintf(stderr, "usage: %s [-m MCU] [-f HZ] [-e EEPROM_FILE] FIRMWARE.elf\n", argv[0]);
			return 2;
		}
	}
	if (optind != argc - 1 && !flash_file && !boot_hex) {
		fprintf(stderr, "usage: %s [-m MCU] [-f HZ] [-e EEPROM_FILE] FIRMWARE.elf\n", argv[0]);
		return 2;
	}
	/* the protocol keeps the real stdout; simavr's printf chatter goes to stderr */
	int fd = dup(1);
	if (fd < 0 || dup2(2, 1) < 0)
		die("cannot set up stdout");
	proto = fdopen(fd, "w");
	if (!proto)
		die("cannot open the protocol stream");
	setvbuf(stdout, NULL, _IONBF, 0);
	if (flash_file || boot_hex) {
		if (!flash_file || !boot_hex || optind != argc) {
			fprintf(stderr, "usage: %s [-m MCU] [-f HZ] [-e EEPROM_FILE] -B FLASH_FILE -b BOOTLOADER.hex\n", argv[0]);
			return 2;
		}
		return boot_main(mcu, hz, flash_file, boot_hex);
	}

	elf_firmware_t f;
	memset(&f, 0, sizeof f);
	if (elf_read_firmware(argv[optind], &f) != 0) {
		fprintf(stderr, "harness: cannot read %s\n", argv[optind]);
		return 1;
	}
	if (mcu)
		snprintf(f.mmcu, sizeof f.mmcu, "%s", mcu);
	if (!f.mmcu[0])
		snprintf(f.mmcu, sizeof f.mmcu, "atmega2560");
	if (hz)
		f.frequency = (uint32_t)hz;
	if (!f.frequency)
		f.frequency = 16000000;
	avr = avr_make_mcu_by_name(f.mmcu);
	if (!avr) {
		fprintf(stderr, "harness: unknown MCU %s\n", f.mmcu);
		return 1;
	}
	avr_init(avr);
	avr_load_firmware(avr, &f);
	avr->frequency = f.frequency;
	uart0 = find_uart0();
	ee_timing_init();
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out, NULL);
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff, NULL);
	ee_open();
	setup_chip();
	fprintf(proto, "READY %s %lu %u %u %llu\n", f.mmcu, (unsigned long)avr->frequency, avr->ramend, avr->e2end,
	        (unsigned long long)avr->cycle);
	fflush(proto);

	char *line = NULL;
	size_t cap = 0;
	while (getline(&line, &cap, stdin) > 0) {
		if (!strncmp(line, "RUN ", 4)) {
			do_run(line + 4);
		} else if (!strncmp(line, "WATCH", 5)) {
			do_list(line + 5, 0);
		} else if (!strncmp(line, "PROBE", 5)) {
			do_list(line + 5, 1);
		} else if (!strncmp(line, "ADCSTART", 8)) {
			unsigned a = 0, b = 0, m = 0;
			if (sscanf(line + 8, "%u %u %u", &a, &b, &m) != 3 || a > avr->ramend || m > avr->ramend || b > 7) {
				fprintf(proto, "ERR ADCSTART wants the ADCSRA address, the ADSC bit and the ADMUX address\n");
			} else {
				adc_csra = (uint16_t)a;
				adc_start_bit = (uint8_t)(1u << b);
				adc_mux = (uint16_t)m;
				fprintf(proto, "OK\n");
			}
		} else if (!strncmp(line, "RESET", 5)) {
			chip_reset();
			avr->state = cpu_Running;
			setup_chip();
			for (int i = 0; i < n_watch; i++)
				watch_val[i] = avr->data[watch_addr[i]];
			fprintf(proto, "OK %llu\n", (unsigned long long)avr->cycle);
		} else if (!strncmp(line, "EEPROM", 6)) {
			fputs("OK ", proto);
			for (uint32_t i = 0; ee_mem && i < ee_size; i++)
				fprintf(proto, "%02x", ee_mem[i]);
			fputc('\n', proto);
		} else if (!strncmp(line, "QUIT", 4)) {
			ee_save();
			fprintf(proto, "OK\n");
			fflush(proto);
			return 0;
		} else {
			fprintf(proto, "ERR unknown request\n");
		}
		fflush(proto);
	}
	ee_save();
	return 0;
}
