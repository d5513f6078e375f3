/*
 * config.h — the trigger box's fixed facts: clock, pins, identity.
 *
 * Board: ATmega328P at 16 MHz (Arduino Uno/Nano class).
 *
 *   PB1 (Arduino D9)  OC1A  square wave (Timer1 compare output A, hardware only)
 *   PD6 (Arduino D6)  CH1   start pulse channel 1, VTS recorder start  (active high)
 *   PD7 (Arduino D7)  CH2   start pulse channel 2, SPECT start          (active high)
 *   PD0/PD1           RXD/TXD, 115200 baud 8N1 to the USB serial bridge
 *
 * Timers:
 *   Timer1  the square wave (fast PWM, or CTC laps for periods over 4.19 s)
 *   Timer2  the device clock and the 125 us tick that times the start pulses
 *   Timer0  unused (shares the prescaler that *TRG halts and releases)
 */
#ifndef TB_CONFIG_H
#define TB_CONFIG_H

#ifndef F_CPU
#define F_CPU 16000000UL
#endif

#define FW_VERSION "1.1.0"   /* 1.1.0: the host watchdog (WDOG, docs/decisions/0083) */

/* Used by *IDN? when the EEPROM holds no serial number (see commands.c). */
#ifndef TB_SERIAL
#define TB_SERIAL "0000"
#endif

/* output pins */
#define WAVE_PORT   PORTB
#define WAVE_DDR    DDRB
#define WAVE_BIT    PB1
#define PULSE_PORT  PORTD
#define PULSE_DDR   DDRD
#define PULSE1_BIT  PD6
#define PULSE2_BIT  PD7

/* limits of the protocol (DESIGN.md), in the fixed-point units the parser yields */
#define FREQ_MIN_UHZ    100000UL       /* 0.1 Hz in micro-hertz */
#define FREQ_MAX_UHZ    1000000000UL   /* 1000 Hz */
#define DUTY_MIN_PPM    10000UL        /* 0.01 in parts per million */
#define DUTY_MAX_PPM    990000UL       /* 0.99 */
#define PULSE_MIN_MS    1UL
#define PULSE_MAX_MS    10000UL
#define WDOG_MIN_US     100000UL       /* the host watchdog: 0 (off) or 0.1 .. 3600 s */
#define WDOG_MAX_US     3600000000UL

/* defaults restored by *RST */
#define DEFAULT_FREQ_UHZ      1000000UL  /* 1 Hz */
#define DEFAULT_DUTY_PPM      500000UL   /* 0.5 */
#define DEFAULT_TRG_WIDTH_MS  100UL      /* the start pulses *TRG sends */
#define DEFAULT_WDOG_US       10000000UL /* the host watchdog: on, 10 s (also at power-up) */

#endif
