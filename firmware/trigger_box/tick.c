/*
 * tick.c — the 125 us tick's interrupt (Timer2 compare match, see clock.h): the work that
 * must happen on a tick, across the clock, the wave, the pulses and the host watchdog. It
 * lives here, above clock.c, wave.c, pulse.c and watchdog.c, so that none of them calls
 * another back (clock.c knew the wave only to run this interrupt).
 */
#include <avr/io.h>
#include <avr/interrupt.h>

#include "clock.h"
#include "pulse.h"
#include "watchdog.h"
#include "wave.h"

/*
 * The tick. Work that starts outputs comes first, so that it runs at a fixed, short
 * delay after the tick; ending pulses and counting come after.
 */
ISR(TIMER2_COMPA_vect)
{
	uint8_t close = pulse_take_pending();   /* channels to close on this tick */
	if (wave_start_pending())
		wave_fire(close);                    /* square wave (+ pulses) on this tick */
	else if (close)
		PULSE_PORT |= close;                 /* start pulses alone */
	pulse_tick();                            /* count down and open finished pulses */
	pulse_arm(close);                        /* widths count from this tick */
	watchdog_tick();                         /* the host silent too long: cut the wave */
	clock_tick_counted();                    /* last: the tick is counted after its work */
}
