/*
 * pulse.c — the two contact-closure start pulses.
 */
#include <avr/io.h>
#include <util/atomic.h>

#include "clock.h"
#include "pulse.h"

static volatile uint8_t pending_bits;       /* close these on the next tick */
static volatile uint32_t pending_ticks[2];  /* their widths in ticks */
static volatile uint32_t remaining[2];      /* ticks until open; 0 = open */

static const uint8_t bits[2] = {PULSE_CH1, PULSE_CH2};

void pulse_init(void)
{
	/* PORTD6/7 = 0 first (open), then DDRD6/7 = 1: driven outputs, low = open */
	PULSE_PORT &= (uint8_t)~PULSE_BOTH;
	PULSE_DDR |= PULSE_BOTH;
}

uint8_t pulse_bit(uint8_t channel)
{
	return channel == 1 ? PULSE_CH1 : channel == 2 ? PULSE_CH2 : 0;
}

uint8_t pulse_busy(uint8_t b)
{
	uint8_t busy = 0;
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		busy = pending_bits & b;
		for (uint8_t i = 0; i < 2; i++)
			if ((b & bits[i]) && remaining[i])
				busy |= bits[i];
	}
	return busy;
}

void pulse_request(uint8_t b, uint16_t ms)
{
	for (uint8_t i = 0; i < 2; i++)
		if (b & bits[i])
			pending_ticks[i] = (uint32_t)ms * CLOCK_TICKS_PER_MS;
	pending_bits |= b;
}

uint8_t pulse_pending(void)
{
	return pending_bits;
}

void pulse_open_all(void)
{
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		pending_bits = 0;
		remaining[0] = remaining[1] = 0;
		PULSE_PORT &= (uint8_t)~PULSE_BOTH;   /* both contacts open */
	}
}

uint8_t pulse_take_pending(void)
{
	uint8_t b = pending_bits;
	pending_bits = 0;
	return b;
}

void pulse_tick(void)
{
	for (uint8_t i = 0; i < 2; i++) {
		uint32_t r = remaining[i];
		if (r && --r == 0)
			PULSE_PORT &= (uint8_t)~bits[i];  /* width reached: open the contact */
		remaining[i] = r;
	}
}

void pulse_arm(uint8_t b)
{
	for (uint8_t i = 0; i < 2; i++)
		if (b & bits[i])
			remaining[i] = pending_ticks[i];
}
