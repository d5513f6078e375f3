/*
 * serial.h — USART0 at 115200 baud 8N1, interrupt driven, with ring buffers both ways.
 *
 * Receiving never waits for the main loop: the RX interrupt stores each byte in a
 * 256-byte ring, so commands that arrive while the wave runs are not lost. A byte that
 * finds the ring full is dropped and counted (serial_take_overrun()).
 */
#ifndef TB_SERIAL_H
#define TB_SERIAL_H

#include <stdint.h>

void serial_init(void);
int16_t serial_getc(void);            /* next received byte, or -1 */
uint8_t serial_rx_ready(void);        /* a byte is waiting */
uint8_t serial_take_overrun(void);    /* bytes dropped since the last call (sticky flag) */
void serial_putc(char c);             /* waits while the TX ring is full */
void serial_puts(const char *s);
void serial_puts_P(const char *s);    /* string in flash */

#endif
