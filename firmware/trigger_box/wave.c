/*
 * wave.c — the square wave on OC1A (PB1), made by Timer1 hardware.
 *
 * Every edge of a running wave is made by the Timer1 compare unit at the exact match;
 * no interrupt ever writes the OC1A pin. The start edge is forced by FOC1A (the compare
 * unit's own strobe) inside the start sequence, and a stop disconnects OC1A only while
 * it is low, after the last falling edge, so a stopped wave always ends on a whole period.
 */
#include <avr/io.h>
#include <avr/interrupt.h>
#include <util/atomic.h>

#include "config.h"
#include "clock.h"
#include "wave.h"

enum { WAVE_OFF, WAVE_STARTING, WAVE_RUNNING, WAVE_STOPPING };

#define COM_SET   (_BV(COM1A1) | _BV(COM1A0))  /* OC1A set on compare match */
#define COM_CLEAR (_BV(COM1A1))                /* OC1A cleared on compare match */
#define TIFR1_ALL (_BV(ICF1) | _BV(OCF1B) | _BV(OCF1A) | _BV(TOV1))

/* Cycles from the TCNT2 sample in wave_fire() to the write that starts Timer1 (the edge
 * the emulator shows; on silicon FOC1A raises the pin 5 cycles earlier), plus half of
 * TCNT2's 8-cycle resolution. */
#define FIRE_EDGE_DELTA (10 + 4)

static struct wave_plan cfg;          /* what FREQ and DUTY set */
static struct wave_plan run;          /* what Timer1 is doing (copied at the start) */
static volatile uint8_t state;
static volatile uint32_t edges;       /* rising edges since the start */
static volatile uint64_t fire_ticks;  /* the tick count and ... */
static volatile uint8_t fire_t2;      /* ... TCNT2 sampled by the start sequence */
static uint16_t stop_limit;           /* fast PWM: stop only while TCNT1 is below this */

/* CTC laps, owned by the compare interrupt once running */
static volatile uint8_t lap_level;    /* OC1A level during the current lap */
static volatile uint8_t lap_edge;     /* the current lap ends with an edge */
static volatile uint32_t lap_left;    /* cycles of the current phase after this lap */

/* the start, prepared by wave_prepare_start() for wave_fire() */
static uint8_t fire_tccr1a, fire_tccr1b, fire_portb, fire_timsk1;

static const uint16_t prescale[5] = {1, 8, 64, 256, 1024};
/* TCCR1B CS12:0 for clk/1, /8, /64, /256, /1024 */
static const uint8_t prescale_cs[5] = {
	_BV(CS10), _BV(CS11), _BV(CS11) | _BV(CS10), _BV(CS12), _BV(CS12) | _BV(CS10)};

/* ------------------------------------------------------------------ planning */

static uint32_t scale_ppm(uint32_t n, uint32_t ppm)
{
	return (uint32_t)(((uint64_t)n * ppm + 500000u) / 1000000u);
}

static uint32_t clamp_high(uint32_t high, uint32_t total)
{
	return high < 1 ? 1 : high > total - 1 ? total - 1 : high;
}

/* CTC laps only when both phases give the lap interrupt this many cycles (256 us) to
 * load the next lap: far more than its worst latency behind the other interrupts */
#define LAP_MIN_PHASE 4096UL

static void plan_fast(struct wave_plan *p, int8_t i, uint32_t counts, uint32_t duty_ppm)
{
	uint32_t high = clamp_high(scale_ppm(counts, duty_ppm), counts);
	p->laps = 0;
	p->cs = prescale_cs[i];
	p->top = (uint16_t)(counts - 1);
	p->ocr = (uint16_t)(high - 1);
	p->period = counts * prescale[i];
	p->high = high * prescale[i];
}

/*
 * The period is the whole number of CPU cycles nearest to 16 MHz / f (nothing clocked at
 * 16 MHz can do better), made by, in order of preference:
 *   1. fast PWM, when a prescaler divides it into at most 65536 counts (the smallest
 *      such prescaler: finest duty);
 *   2. CTC laps at clk/1, exact to the cycle for any longer period, when both phases
 *      are at least LAP_MIN_PHASE cycles;
 *   3. otherwise fast PWM with the prescaler and TOP nearest to the period (at least
 *      1000 counts so the duty resolves to 0.05 %; ties go to the smaller prescaler).
 */
void wave_plan(uint32_t freq_uhz, uint32_t duty_ppm, struct wave_plan *p)
{
	/* the exact period in milli-cycles: F_CPU [Hz] * 1e6 [uHz/Hz] * 1e3 / f [uHz] */
	const uint64_t pm = (16000000000000000ULL + freq_uhz / 2) / freq_uhz;
	const uint32_t period = (uint32_t)((pm + 500) / 1000);

	for (int8_t i = 0; i < 5; i++) {
		if (period % prescale[i] == 0 && period / prescale[i] <= 65536UL) {
			plan_fast(p, i, period / prescale[i], duty_ppm);
			return;
		}
	}

	uint32_t high = clamp_high(scale_ppm(period, duty_ppm), period);
	if (high >= LAP_MIN_PHASE && period - high >= LAP_MIN_PHASE) {
		p->laps = 1;
		p->cs = _BV(CS10);
		p->top = 0;
		p->ocr = 0;
		p->period = period;
		p->high = high;
		return;
	}

	uint64_t best_err = UINT64_MAX;
	uint32_t best_counts = 0;
	int8_t best = 0;
	for (int8_t i = 0; i < 5; i++) {
		uint64_t unit = 1000ULL * prescale[i];
		uint64_t counts = (pm + unit / 2) / unit;
		if (counts < 1000 || counts > 65536)
			continue;
		uint64_t exact = counts * unit;
		uint64_t err = exact > pm ? exact - pm : pm - exact;
		if (err < best_err) {
			best_err = err;
			best = i;
			best_counts = (uint32_t)counts;
		}
	}
	plan_fast(p, best, best_counts, duty_ppm);
}

uint64_t wave_plan_freq_nhz(const struct wave_plan *p)
{
	/* F_CPU * 1e9 / period, rounded */
	return (16000000000000000ULL + p->period / 2) / p->period;
}

uint32_t wave_plan_duty_ppm(const struct wave_plan *p)
{
	return (uint32_t)(((uint64_t)p->high * 1000000u + p->period / 2) / p->period);
}

/* ------------------------------------------------------------------ state */

void wave_init(void)
{
	TCCR1B = 0;                       /* Timer1 stopped */
	TCCR1A = 0;                       /* OC1A disconnected: PB1 follows PORTB1 */
	WAVE_PORT &= (uint8_t)~_BV(WAVE_BIT); /* PORTB1 = 0: low while disconnected */
	WAVE_DDR |= _BV(WAVE_BIT);        /* DDRB1 = 1: PB1 is an output (required for OC1A) */
	state = WAVE_OFF;
}

void wave_set_plan(const struct wave_plan *p)
{
	cfg = *p;
}

const struct wave_plan *wave_get_plan(void)
{
	return &cfg;
}

uint8_t wave_is_on(void)
{
	return state != WAVE_OFF;
}

uint8_t wave_start_pending(void)
{
	return state == WAVE_STARTING;
}

void wave_clear_edges(void)
{
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		edges = 0;
	}
}

void wave_edges(uint32_t *count, uint64_t *first, uint64_t *last)
{
	uint32_t n;
	uint64_t t;
	uint8_t t2;
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		n = edges;
		t = fire_ticks;
		t2 = fire_t2;
	}
	uint64_t f = n ? clock_cycles_of_tick(t, t2) + FIRE_EDGE_DELTA : 0;
	*count = n;
	*first = f;
	/* the hardware makes every period exactly run.period cycles long */
	*last = n ? f + (uint64_t)(n - 1) * run.period : 0;
}

/* ------------------------------------------------------------------ CTC laps */

/* Take the next lap (at most 65536 cycles, and never shorter than 32768 unless the
 * whole rest of the phase is) from the current phase; return its OCR1A (length - 1). */
static uint16_t next_lap(void)
{
	uint32_t left = lap_left, lap;
	if (left <= 65536UL)
		lap = left;
	else if (left <= 131072UL)
		lap = left / 2;
	else
		lap = 65536UL;
	lap_left = left - lap;
	lap_edge = lap_left == 0;
	return (uint16_t)(lap - 1);
}

/* The compare action at the end of the current lap: the opposite level at the end of a
 * phase (the edge), the same level otherwise (a no-op that keeps OC1A where it is). */
static uint8_t lap_com(void)
{
	return (lap_edge ^ lap_level) ? COM_SET : COM_CLEAR;
}

/* ------------------------------------------------------------------ start */

void wave_prepare_start(void)
{
	run = cfg;
	edges = 0;
	TCCR1B = 0;                  /* clock select 0: Timer1 stopped while we set it up */
	TCCR1A = 0;                  /* OC1A disconnected, WGM11:10 = 0 */
	TIMSK1 = 0;                  /* no Timer1 interrupts yet */
	TCNT1 = 0;                   /* count from BOTTOM */
	TIFR1 = TIFR1_ALL;           /* forget old flags (write one to clear) */
	if (!run.laps) {
		ICR1 = run.top;          /* TOP of mode 14: period = (ICR1 + 1) * N cycles */
		OCR1A = run.ocr;         /* OC1A high for OCR1A + 1 counts after BOTTOM */
		/* non-inverting fast PWM: clear OC1A on match, set at BOTTOM; WGM11 of mode 14 */
		fire_tccr1a = COM_CLEAR | _BV(WGM11);
		/* WGM13:12 of mode 14 (fast PWM, TOP = ICR1) and the prescaler */
		fire_tccr1b = _BV(WGM13) | _BV(WGM12) | run.cs;
		fire_portb = 0;
		fire_timsk1 = _BV(TOIE1);        /* one overflow per period: count edges */
		uint16_t n = 1;
		for (int8_t i = 0; i < 5; i++)
			if (prescale_cs[i] == run.cs)
				n = prescale[i];
		stop_limit = run.top - (uint16_t)(64 / n) - 2;
	} else {
		lap_level = 1;
		lap_left = run.high;
		OCR1A = next_lap();      /* TOP of mode 4 = the first lap's length - 1 */
		fire_tccr1a = lap_com(); /* its compare action; WGM11:10 = 0 for mode 4 */
		fire_tccr1b = _BV(WGM12) | _BV(CS10); /* mode 4 (CTC, TOP = OCR1A), clk/1 */
		/* PORTB1 = 1: ignored by silicon while OC1A is connected; the emulator (no
		 * FOC1A, no set-at-start in CTC) shows the start edge from it */
		fire_portb = _BV(WAVE_BIT);
		fire_timsk1 = _BV(OCIE1A);       /* the lap interrupt */
	}
}

void wave_arm_start(void)
{
	state = WAVE_STARTING;       /* the tick interrupt takes it from here */
}

/*
 * The start, on a Timer2 tick (interrupts are off in the ISR). One fixed sequence of
 * single-cycle I/O and two-cycle sts writes, so the wave's first rising edge and the
 * start pulses come within a few cycles of each other:
 */
void wave_fire(uint8_t close)
{
	uint8_t t2;
	uint8_t pb = PORTB | fire_portb;
	uint8_t pd = PORTD | close;
	__asm__ __volatile__(
		"lds %[t2], %[tcnt2]\n\t"         /* sample the device clock */
		"out %[gtccr], %[halt]\n\t"       /* GTCCR = TSM|PSRSYNC: hold the Timer0/1 prescaler in reset */
		"sts %[tccr1a], %[set]\n\t"       /* TCCR1A = COM1A1:0 = 11 (set on match), normal mode */
		"sts %[tccr1c], %[foc]\n\t"       /* TCCR1C = FOC1A: force a match: OC1A goes high */
		"sts %[tccr1a], %[a1]\n\t"        /* TCCR1A = the run's compare action and WGM11:10 */
		"out %[portb], %[pb]\n\t"         /* PORTB1 (CTC laps only, see above) */
		"sts %[tccr1b], %[b1]\n\t"        /* TCCR1B = WGM13:12 + clock select: Timer1 runs */
		"out %[portd], %[pd]\n\t"         /* PORTD6/7 = 1: start pulses close */
		"out %[gtccr], __zero_reg__\n\t"  /* GTCCR = 0: prescaler released, TCNT1 counts */
		: [t2] "=&r"(t2)
		: [tcnt2] "n"(_SFR_MEM_ADDR(TCNT2)), [gtccr] "I"(_SFR_IO_ADDR(GTCCR)),
		  [tccr1a] "n"(_SFR_MEM_ADDR(TCCR1A)), [tccr1b] "n"(_SFR_MEM_ADDR(TCCR1B)),
		  [tccr1c] "n"(_SFR_MEM_ADDR(TCCR1C)), [portb] "I"(_SFR_IO_ADDR(PORTB)),
		  [portd] "I"(_SFR_IO_ADDR(PORTD)),
		  [halt] "r"((uint8_t)(_BV(TSM) | _BV(PSRSYNC))), [set] "r"((uint8_t)COM_SET),
		  [foc] "r"((uint8_t)_BV(FOC1A)), [a1] "r"(fire_tccr1a), [b1] "r"(fire_tccr1b),
		  [pb] "r"(pb), [pd] "r"(pd)
		: "memory");
	fire_ticks = clock_ticks_in_tick_isr();   /* the first edge's time, computed later */
	fire_t2 = t2;
	edges = 1;
	TIMSK1 = fire_timsk1;        /* Timer1 interrupts for this mode */
	state = WAVE_RUNNING;
}

/* ------------------------------------------------------------------ stop */

/* OC1A is low and stays low: disconnect it and stop Timer1. */
static void stop_now(void)
{
	WAVE_PORT &= (uint8_t)~_BV(WAVE_BIT); /* PORTB1 = 0: the level once disconnected */
	TCCR1B = 0;                  /* clock select 0: Timer1 stops */
	TCCR1A = 0;                  /* COM1A = 00: PB1 is a port pin again, low */
	TIMSK1 = 0;                  /* no Timer1 interrupts */
	TIFR1 = TIFR1_ALL;           /* and none pending */
	state = WAVE_OFF;
}

/* fast PWM: OC1A is low from the match (TCNT1 > OCR1A) to TOP; stop only with room to
 * spare before TOP, so BOTTOM cannot set it again while we disconnect it */
static uint8_t fast_can_stop_now(void)
{
	uint16_t t = TCNT1;
	return t > run.ocr && t < stop_limit;
}

void wave_request_stop(void)
{
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		if (state == WAVE_STARTING) {
			state = WAVE_OFF;    /* not started yet: nothing to finish */
		} else if (state == WAVE_RUNNING) {
			state = WAVE_STOPPING;
			if (!run.laps) {
				if (fast_can_stop_now()) {
					stop_now();
				} else {
					TIFR1 = _BV(OCF1A);      /* forget earlier matches ... */
					TIMSK1 |= _BV(OCIE1A);   /* ... and stop after the next falling edge */
				}
			}
			/* CTC laps: the lap interrupt stops at the next lap end in a low phase */
		}
	}
}

/*
 * The host watchdog's cut (watchdog.c, in the tick interrupt): the output low now, mid-period if
 * need be, and Timer1 stopped. While OC1A is connected the pin ignores PORTB1; so a high pin is
 * first handed over to PORTB1 = 1 (no change on the pin), then PORTB1 = 0 makes the one falling
 * edge. A rising edge the overflow or lap interrupt has not counted yet (it is pending behind
 * this one) is counted here, so EDGES? stays exact.
 */
void wave_cut(void)
{
	if (state == WAVE_OFF)
		return;
	TCCR1B = 0;                  /* clock select 0: Timer1 stops, no compare match from here */
	if (state != WAVE_STARTING) {
		if (!run.laps) {
			/* fast PWM: TOV1 rose at TOP; the rising edge came at BOTTOM, in the high phase */
			if ((TIFR1 & _BV(TOV1)) && TCNT1 <= run.ocr)
				edges++;
		} else if ((TIFR1 & _BV(OCF1A)) && lap_edge && !lap_level) {
			edges++;             /* a low phase's last lap ended: the pin rose */
		}
		if (PINB & _BV(WAVE_BIT)) {
			WAVE_PORT |= _BV(WAVE_BIT);  /* PORTB1 = 1 while still connected: no change */
			TCCR1A = 0;                  /* disconnected: PB1 follows PORTB1, still high */
		}
	}
	stop_now();                  /* PORTB1 = 0: the pin falls; Timer1 off, state OFF */
}

uint8_t wave_cancel_stop(void)
{
	uint8_t resumed = 0;
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		if (state == WAVE_STOPPING) {
			state = WAVE_RUNNING;
			if (!run.laps)
				TIMSK1 &= (uint8_t)~_BV(OCIE1A);  /* no stop at the next falling edge */
			resumed = 1;
		}
	}
	return resumed;
}

/* ------------------------------------------------------------------ interrupts */

/* fast PWM: one overflow (TOV1, at TOP) per period, i.e. per rising edge */
ISR(TIMER1_OVF_vect)
{
	edges++;
}

ISR(TIMER1_COMPA_vect)
{
	if (!run.laps) {
		/* fast PWM, stopping: this match was a falling edge */
		if (fast_can_stop_now())
			stop_now();
		return;
	}
	/* CTC laps: a lap just ended (its compare action has happened) and the next began */
	if (lap_edge) {
		lap_level ^= 1;
		if (lap_level)
			edges++;
		lap_left = lap_level ? run.high : run.period - run.high;
	}
	if (!lap_level && state == WAVE_STOPPING) {
		stop_now();
		return;
	}
	OCR1A = next_lap();          /* the length of the lap that just began ... */
	TCCR1A = lap_com();          /* ... and the action at its end */
}
