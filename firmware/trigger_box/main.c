/*
 * main.c — the trigger box: square wave, start pulses and a device clock for the VTS/SPECT
 * rig, controlled over a serial line (see commands.h for the protocol).
 *
 * Everything with timing is done by timer hardware and interrupts (wave.c, clock.c,
 * pulse.c); the main loop only reads command lines and sleeps (idle mode: timers and the
 * UART keep running) until the next interrupt.
 */
#include <avr/io.h>
#include <avr/interrupt.h>
#include <avr/sleep.h>
#include <avr/wdt.h>

#include "clock.h"
#include "commands.h"
#include "pulse.h"
#include "serial.h"
#include "wave.h"

/* Before the C runtime starts: clear the reset flags and switch the watchdog off, which a
 * bootloader may have left running (a watchdog reset would cut a running wave). */
void early_init(void) __attribute__((naked, used, section(".init3")));
void early_init(void)
{
	MCUSR = 0;       /* clear WDRF, or the watchdog cannot be disabled */
	wdt_disable();   /* WDTCSR: WDCE|WDE timed sequence, then 0 */
}

int main(void)
{
	wave_init();      /* PB1 low, an output, Timer1 stopped */
	pulse_init();     /* PD6/PD7 low (open), outputs */
	clock_init();     /* tick interrupt on (Timer2 has run since reset) ... */
	sei();            /* ... and counting, before anything slow */
	serial_init();    /* 115200 8N1 */
	commands_init();  /* defaults: 1 Hz, duty 0.5, *TRG pulses 100 ms (64-bit math) */
	set_sleep_mode(SLEEP_MODE_IDLE);  /* SMCR: idle; timers and UART keep running */

	for (;;) {
		commands_poll();
		cli();
		if (!serial_rx_ready()) {
			sleep_enable();
			sei();        /* the instruction after sei runs first: no lost wake-up */
			sleep_cpu();
			sleep_disable();
		}
		sei();
	}
}
