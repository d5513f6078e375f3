/*
 * serial.c — USART0 at 115200 baud 8N1, interrupt driven.
 */
#include <avr/io.h>
#include <avr/interrupt.h>
#include <avr/pgmspace.h>
#include <util/atomic.h>

#include "config.h"
#include "serial.h"

#define BAUD 115200UL
/* U2X: UBRR = F_CPU / (8 * BAUD) - 1 = 16.36 -> 16: 117647 baud, +2.1 %
 * (without U2X it would be 8: 111111 baud, -3.5 %, too far for a 115200 host) */
#define UBRR_VALUE ((F_CPU + 4UL * BAUD) / (8UL * BAUD) - 1UL)

#define RX_SIZE 256u   /* powers of two up to 256: the uint8_t index wraps with a mask */
#define TX_SIZE 128u

/* The rings need no zeroing: they live in .noinit, which keeps the C runtime's .bss
 * clearing short, so main() enables interrupts long before the second clock tick
 * (see clock.c: a tick may wait, pending, for at most one tick). */
#define NOINIT __attribute__((section(".noinit")))
static volatile uint8_t rx_buf[RX_SIZE] NOINIT;
static volatile uint8_t rx_head, rx_tail;   /* head: ISR writes; tail: main reads */
static volatile uint8_t rx_overrun;
static volatile uint8_t tx_buf[TX_SIZE] NOINIT;
static volatile uint8_t tx_head, tx_tail;   /* head: main writes; tail: ISR reads */

void serial_init(void)
{
	/* UCSR0A = U2X0: double speed (8 samples per bit); set before UBRR0 */
	UCSR0A = _BV(U2X0);
	/* UCSR0C = UCSZ01|UCSZ00: asynchronous, 8 data bits, no parity, 1 stop bit */
	UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
	/* UBRR0 = 16: 117647 baud with U2X (high byte first; the low byte write commits) */
	UBRR0H = (uint8_t)(UBRR_VALUE >> 8);
	UBRR0L = (uint8_t)UBRR_VALUE;
	/* UCSR0B = RXCIE0|RXEN0|TXEN0: receiver with its interrupt, transmitter; the
	 * data-register-empty interrupt (UDRIE0) is enabled only while there is output */
	UCSR0B = _BV(RXCIE0) | _BV(RXEN0) | _BV(TXEN0);
}

ISR(USART_RX_vect)
{
	uint8_t status = UCSR0A;   /* read before UDR0: FE0 and DOR0 belong to this byte */
	uint8_t c = UDR0;
	uint8_t next = (rx_head + 1) & (RX_SIZE - 1);
	if (status & _BV(DOR0))
		rx_overrun = 1;        /* the hardware lost a byte before this one */
	if (next == rx_tail) {
		rx_overrun = 1;        /* ring full: drop it */
		return;
	}
	rx_buf[rx_head] = c;
	rx_head = next;
}

ISR(USART_UDRE_vect)
{
	if (tx_head == tx_tail) {
		UCSR0B &= (uint8_t)~_BV(UDRIE0);  /* nothing more: UDRE interrupt off */
		return;
	}
	UDR0 = tx_buf[tx_tail];
	tx_tail = (tx_tail + 1) & (TX_SIZE - 1);
}

uint8_t serial_rx_ready(void)
{
	return rx_head != rx_tail;
}

int16_t serial_getc(void)
{
	if (rx_head == rx_tail)
		return -1;
	uint8_t c = rx_buf[rx_tail];
	rx_tail = (rx_tail + 1) & (RX_SIZE - 1);
	return c;
}

uint8_t serial_take_overrun(void)
{
	uint8_t o;
	ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
		o = rx_overrun;
		rx_overrun = 0;
	}
	return o;
}

void serial_putc(char c)
{
	uint8_t next = (tx_head + 1) & (TX_SIZE - 1);
	while (next == tx_tail)
		;                      /* ring full: the UDRE interrupt is draining it */
	tx_buf[tx_head] = (uint8_t)c;
	tx_head = next;
	UCSR0B |= _BV(UDRIE0);     /* UDRE interrupt on: send from the ring */
}

void serial_puts(const char *s)
{
	while (*s)
		serial_putc(*s++);
}

void serial_puts_P(const char *s)
{
	char c;
	while ((c = (char)pgm_read_byte(s++)))
		serial_putc(c);
}
