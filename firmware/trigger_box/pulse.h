/*
 * pulse.h — the two contact-closure start pulses (CH1 = VTS, CH2 = SPECT).
 *
 * A pulse closes on a Timer2 tick and opens exactly ms * 8 ticks later, both edges made
 * by the tick interrupt, so the width is exact to the tick and jitters only by the
 * interrupt latency (a few cycles).
 */
#ifndef TB_PULSE_H
#define TB_PULSE_H

#include <stdint.h>
#include <avr/io.h>
#include "config.h"

#define PULSE_CH1 _BV(PULSE1_BIT)
#define PULSE_CH2 _BV(PULSE2_BIT)
#define PULSE_BOTH (PULSE_CH1 | PULSE_CH2)

void pulse_init(void);
uint8_t pulse_bit(uint8_t channel);          /* 1 -> PULSE_CH1, 2 -> PULSE_CH2, else 0 */
uint8_t pulse_busy(uint8_t bits);            /* any of these closed or about to close */
void pulse_request(uint8_t bits, uint16_t ms); /* close on the next tick (caller: cli) */
uint8_t pulse_pending(void);                 /* requests the tick has not taken yet */
void pulse_open_all(void);                   /* open both now (*RST) */

/* for the tick interrupt */
uint8_t pulse_take_pending(void);
void pulse_tick(void);
void pulse_arm(uint8_t bits);

#endif
