/*
 * clock.h — the device clock and the 125 us tick (Timer2).
 *
 * Timer2 runs from the first instructions after reset (see clock.c) in CTC mode at
 * clk/8 with TOP 249: one tick every 2000 cycles (125 us). The tick interrupt counts
 * ticks in 64 bits and runs the work that must happen on a tick: starting the square
 * wave and the start pulses, and ending the pulses.
 *
 * Device time is counted in CPU cycles since reset:
 *     cycles = CLOCK_BOOT_CYCLES + ticks * 2000 + TCNT2 * 8
 * (resolution 8 cycles = 0.5 us), and reported in microseconds (cycles / 16).
 */
#ifndef TB_CLOCK_H
#define TB_CLOCK_H

#include <stdint.h>

#define CLOCK_TICK_CYCLES 2000u   /* (OCR2A + 1) * 8 */
#define CLOCK_TICKS_PER_MS 8u
#define CLOCK_CYCLES_PER_US 16u

/* Cycles from reset to the instruction that starts Timer2, counted from the listing
 * (a jmp to the startup code, then ldi/sts pairs) and checked in the emulator by
 * tests/integration/test_firmware.py: device time 0 is the first instruction after reset. */
#define CLOCK_BOOT_CYCLES 10u

void clock_init(void);                 /* enable the tick interrupt */
uint64_t clock_cycles(void);           /* device time in cycles (interrupt safe) */
uint64_t clock_us(void);               /* device time in microseconds */

/* Inside the tick ISR: the number of ticks counted so far (this tick's not included). */
uint64_t clock_ticks_in_tick_isr(void);
/* The device time, in cycles, of a TCNT2 value read in the tick ISR when
 * clock_ticks_in_tick_isr() was `ticks`. */
uint64_t clock_cycles_of_tick(uint64_t ticks, uint8_t tcnt2);
/* The tick ISR (tick.c), after its work: this tick is counted. */
void clock_tick_counted(void);

#endif
