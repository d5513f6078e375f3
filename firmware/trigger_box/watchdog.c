/*
 * watchdog.c — the host watchdog (see watchdog.h).
 */
#include <avr/io.h>
#include <util/atomic.h>

#include "clock.h"
#include "watchdog.h"
#include "wave.h"

#define US_PER_TICK 125UL

static volatile uint32_t limit;      /* the watchdog time in ticks; 0 = off */
static volatile uint32_t left;       /* ticks until the cut; 0 = not counting */
static volatile uint8_t tripped;     /* the last run was cut (until a new start or *RST) */
static volatile uint8_t trip_news;   /* not yet queued as an error */
static volatile uint64_t trip_ticks; /* the tick count and ... */
static volatile uint8_t trip_t2;     /* ... TCNT2 at the cut */

void watchdog_set_us(uint32_t us)
{
	uint32_t ticks = (us + US_PER_TICK / 2) / US_PER_TICK;
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		limit = ticks;
		left = ticks;
	}
}

uint32_t watchdog_us(void)
{
	uint32_t t;
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		t = limit;
	}
	return t * US_PER_TICK;
}

void watchdog_feed(void)
{
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		left = limit;
	}
}

void watchdog_forget_trip(void)
{
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		tripped = 0;
		trip_news = 0;
	}
}

uint8_t watchdog_state(uint64_t *cycles)
{
	uint8_t t, t2;
	uint32_t l;
	uint64_t ticks;
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		t = tripped;
		l = limit;
		ticks = trip_ticks;
		t2 = trip_t2;
	}
	*cycles = t ? clock_cycles_of_tick(ticks, t2) : 0;
	if (t)
		return WDOG_TRIPPED;
	if (!l)
		return WDOG_OFF;
	return wave_is_on() ? WDOG_ARMED : WDOG_IDLE;
}

uint8_t watchdog_take_trip(void)
{
	uint8_t news;
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		news = trip_news;
		trip_news = 0;
	}
	return news;
}

/* In the tick interrupt: count down; at zero with the wave on, cut it. Counting goes on while
 * the output is off (a start is always a command, so it begins with a full count). */
void watchdog_tick(void)
{
	uint32_t l = left;
	if (!l)
		return;
	left = --l;
	if (l || !wave_is_on())
		return;
	trip_t2 = TCNT2;
	wave_cut();
	trip_ticks = clock_ticks_in_tick_isr();
	tripped = 1;
	trip_news = 1;
}
