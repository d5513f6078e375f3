/*
 * errors.c — the error queue.
 */
#include <avr/pgmspace.h>

#include "errors.h"

#define QUEUE_LEN 8

static int16_t queue[QUEUE_LEN];
static uint8_t head, count;

void error_push(int16_t code)
{
	if (count == QUEUE_LEN) {
		/* SCPI: keep the oldest, and make the newest say that errors were lost */
		queue[(head + QUEUE_LEN - 1) % QUEUE_LEN] = E_QUEUE_OVERFLOW;
		return;
	}
	queue[(head + count) % QUEUE_LEN] = code;
	count++;
}

int16_t error_pop(void)
{
	if (!count)
		return 0;
	int16_t code = queue[head];
	head = (head + 1) % QUEUE_LEN;
	count--;
	return code;
}

void error_clear(void)
{
	head = count = 0;
}

static const char m0[] PROGMEM = "No error";
static const char m101[] PROGMEM = "Invalid character";
static const char m102[] PROGMEM = "Syntax error";
static const char m104[] PROGMEM = "Data type error";
static const char m108[] PROGMEM = "Parameter not allowed";
static const char m109[] PROGMEM = "Missing parameter";
static const char m113[] PROGMEM = "Undefined header";
static const char m221[] PROGMEM = "Settings conflict";
static const char m222[] PROGMEM = "Data out of range";
static const char m224[] PROGMEM = "Illegal parameter value";
static const char m310[] PROGMEM = "Watchdog: host silent, output off";
static const char m350[] PROGMEM = "Queue overflow";
static const char m363[] PROGMEM = "Input buffer overrun";
static const char mx[] PROGMEM = "Error";

const char *error_message_P(int16_t code)
{
	switch (code) {
	case 0: return m0;
	case E_INVALID_CHAR: return m101;
	case E_SYNTAX: return m102;
	case E_DATA_TYPE: return m104;
	case E_PARAM_NOT_ALLOWED: return m108;
	case E_MISSING_PARAM: return m109;
	case E_UNDEFINED_HEADER: return m113;
	case E_SETTINGS_CONFLICT: return m221;
	case E_OUT_OF_RANGE: return m222;
	case E_ILLEGAL_VALUE: return m224;
	case E_WATCHDOG: return m310;
	case E_QUEUE_OVERFLOW: return m350;
	case E_INPUT_OVERRUN: return m363;
	default: return mx;
	}
}
