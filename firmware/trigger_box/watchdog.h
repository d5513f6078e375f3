/*
 * watchdog.h — the host watchdog: the square wave stops when the host falls silent.
 *
 * (Not the AVR's hardware watchdog, which stays off: main.c.)
 *
 * Every line naming a command of the protocol (commands.c), whatever its reply, is the host's
 * heartbeat; blank lines, garbage and unknown headers are not. While the square wave is on and
 * the watchdog is set (WDOG <s>: 0.1 .. 3600 s, 0 = off; 10 s at power-up and after *RST), the
 * 125 us tick counts down from the last heartbeat, and when T has passed without one it cuts
 * the wave: the output low at once (mid-period if need be) and Timer1 stopped. The trip is
 * kept, with its device time, until the output is switched on again or *RST, and error -310
 * is queued once.
 *
 * The bound: a heartbeat taken at device time h (the end of its line) and none after it: the
 * wave is cut on the first tick at or after h + T - 125 us, so within (h + T - 125 us, h + T];
 * the pin falls a few cycles after that tick.
 */
#ifndef TB_WATCHDOG_H
#define TB_WATCHDOG_H

#include <stdint.h>

enum { WDOG_OFF, WDOG_IDLE, WDOG_ARMED, WDOG_TRIPPED };

void watchdog_set_us(uint32_t us);   /* 0 = off, else rounded to whole ticks; also a heartbeat */
uint32_t watchdog_us(void);          /* the watchdog time in effect (0 = off) */
void watchdog_feed(void);            /* a heartbeat */
void watchdog_forget_trip(void);     /* the output is switched on again, or *RST */
/* WDOG_OFF / IDLE (set, output off) / ARMED (set, output on) / TRIPPED (the last run was cut;
 * `cycles`: the device time of the cut) */
uint8_t watchdog_state(uint64_t *cycles);
uint8_t watchdog_take_trip(void);    /* 1 once per trip (the main loop queues the error) */

void watchdog_tick(void);            /* the tick interrupt, after its other work */

#endif
