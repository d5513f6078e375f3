/*
 * wave.h — the square wave on OC1A (PB1), made by Timer1 hardware.
 *
 * The period is always the whole number of CPU cycles nearest to 16 MHz / f. Two ways
 * to drive Timer1 make it, chosen by wave_plan():
 *   fast PWM  (mode 14, TOP = ICR1, non-inverting OC1A) when a prescaler divides the
 *             period into at most 65536 counts: no software in the loop at all;
 *   CTC laps  (mode 4, TOP = OCR1A, clk/1) otherwise, in particular for periods over
 *             65536 * 1024 cycles (4.19 s, f < 0.2384 Hz, down to 0.1 Hz): each high or
 *             low phase is a run of "laps" of at most 65536 cycles; the compare match at
 *             the end of a lap sets or clears OC1A in hardware, and the compare interrupt
 *             (which runs at the start of the next lap, at least 4096 cycles before its
 *             end) only loads the next lap's length and compare action.
 * (If a phase is too short for laps, the nearest fast PWM prescaler and TOP are used.)
 * See docs/decisions/0009-trigger-box-firmware.md.
 */
#ifndef TB_WAVE_H
#define TB_WAVE_H

#include <stdint.h>

struct wave_plan {
	uint8_t laps;       /* 0: fast PWM; 1: CTC laps */
	uint8_t cs;         /* TCCR1B clock select bits */
	uint16_t top;       /* fast PWM: ICR1 */
	uint16_t ocr;       /* fast PWM: OCR1A */
	uint32_t period;    /* cycles per period (exact) */
	uint32_t high;      /* cycles high per period (exact) */
};

/* the settings that give freq_uhz (micro-hertz) and duty_ppm most closely */
void wave_plan(uint32_t freq_uhz, uint32_t duty_ppm, struct wave_plan *p);
/* what a plan really gives: frequency in nano-hertz, duty in ppm */
uint64_t wave_plan_freq_nhz(const struct wave_plan *p);
uint32_t wave_plan_duty_ppm(const struct wave_plan *p);

void wave_init(void);
void wave_set_plan(const struct wave_plan *p);  /* only while off */
const struct wave_plan *wave_get_plan(void);

uint8_t wave_is_on(void);        /* running, starting or finishing its last period */
void wave_prepare_start(void);   /* set Timer1 up for a start (while off) ... */
void wave_arm_start(void);       /* ... and start on the next tick (caller: cli) */
uint8_t wave_start_pending(void);
void wave_request_stop(void);    /* stop after the current period's falling edge */
uint8_t wave_cancel_stop(void);  /* still finishing? then keep running (returns 1) */
void wave_cut(void);             /* stop now, mid-period if need be: output low (caller: cli) */

/* rising edges since the last start, and the device times (cycles) of the first and last */
void wave_edges(uint32_t *count, uint64_t *first, uint64_t *last);
void wave_clear_edges(void);     /* only while off */

/* for the tick interrupt: start the wave now, closing the pulse pins `close` with it */
void wave_fire(uint8_t close);

#endif
