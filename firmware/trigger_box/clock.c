/*
 * clock.c — the device clock and the 125 us tick (Timer2).
 */
#include <avr/io.h>
#include <avr/interrupt.h>
#include <util/atomic.h>

#include "clock.h"

/* Ticks (125 us each) since Timer2 started: 64 bits, so it never wraps (2^64 ticks is
 * millions of years); a 32-bit microsecond counter would wrap after 71 minutes.
 * CLOCK_BOOT_TICKS is 0 except in the test build trigger_box_late.elf, which starts the
 * clock 0.3 ms before 2^32 microseconds to prove that nothing is 32 bits on the way. */
#ifndef CLOCK_BOOT_TICKS
#define CLOCK_BOOT_TICKS 0
#endif
static volatile uint64_t ticks = CLOCK_BOOT_TICKS;

/*
 * Start Timer2 in the very first instructions after reset, before the C runtime copies
 * .data and clears .bss, so that device time 0 is (within CLOCK_BOOT_CYCLES) the first
 * instruction. Written in assembly so that its cycle count is fixed:
 *     jmp __init (3) | ldi (1) sts (2) | ldi (1) sts (2) | ldi (1) [sts TCCR2B at cycle 10]
 * r24 is free here (nothing runs before us) and r1 is not yet zero, so no C.
 */
void clock_boot(void) __attribute__((naked, used, section(".init1")));
void clock_boot(void)
{
	__asm__ __volatile__(
		/* OCR2A = 249: TOP of CTC mode, 250 counts per tick */
		"ldi r24, 249\n\t"
		"sts %[ocr2a], r24\n\t"
		/* TCCR2A = WGM21: CTC mode (WGM22:0 = 010), OC2A/OC2B disconnected */
		"ldi r24, %[wgm]\n\t"
		"sts %[tccr2a], r24\n\t"
		/* TCCR2B = CS21: clk/8, 2 MHz count, 2000 cycles per tick; the clock starts here */
		"ldi r24, %[cs]\n\t"
		"sts %[tccr2b], r24\n\t"
		/* TIMSK2 = OCIE2A: the tick interrupt on compare match A (= TOP). Enabled now
		 * (interrupts stay off globally until main() says sei), so that a tick that
		 * comes before sei is held pending and counted: silicon would keep the flag
		 * either way, but simavr only queues a flag that rises while enabled. */
		"ldi r24, %[ie]\n\t"
		"sts %[timsk2], r24\n\t"
		:
		: [ocr2a] "n"(_SFR_MEM_ADDR(OCR2A)), [tccr2a] "n"(_SFR_MEM_ADDR(TCCR2A)),
		  [tccr2b] "n"(_SFR_MEM_ADDR(TCCR2B)), [timsk2] "n"(_SFR_MEM_ADDR(TIMSK2)),
		  [wgm] "M"(_BV(WGM21)), [cs] "M"(_BV(CS21)), [ie] "M"(_BV(OCIE2A))
		: "r24");
}

void clock_init(void)
{
	/* The tick interrupt has been enabled since boot (clock_boot); a tick that came
	 * before main() enabled interrupts is pending and counted now. main() does sei
	 * first thing, well within the second tick (4000 cycles), so no tick is lost. */
}

static uint64_t to_cycles(uint64_t t, uint8_t tcnt2)
{
	return CLOCK_BOOT_CYCLES + t * CLOCK_TICK_CYCLES + (uint16_t)tcnt2 * 8u;
}

uint64_t clock_cycles(void)
{
	uint64_t t;
	uint8_t c;
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		t = ticks;
		c = TCNT2;
		/* the counter wrapped but the tick interrupt has not run yet: count that tick
		 * and re-read the counter (it is past the wrap now, whenever the flag rose) */
		if (TIFR2 & _BV(OCF2A)) {
			c = TCNT2;
			t++;
		}
	}
	return to_cycles(t, c);
}

uint64_t clock_us(void)
{
	return clock_cycles() / CLOCK_CYCLES_PER_US;
}

uint64_t clock_ticks_in_tick_isr(void)
{
	return ticks;
}

uint64_t clock_cycles_of_tick(uint64_t t, uint8_t tcnt2)
{
	/* the wrap that raised the interrupt was not counted in `ticks` yet */
	return to_cycles(t + 1, tcnt2);
}

void clock_tick_counted(void)
{
	ticks++;
}
