/*
 * errors.h — the SCPI-style error queue read by SYST:ERR?.
 *
 * Codes (SCPI numbers; the message text is fixed per code):
 *   -101 Invalid character      a byte outside printable ASCII in a line
 *   -102 Syntax error           malformed parameter list
 *   -104 Data type error        a parameter that is not a number (or not a whole one)
 *   -108 Parameter not allowed  too many parameters, or any on a query
 *   -109 Missing parameter
 *   -113 Undefined header       unknown command
 *   -221 Settings conflict      not allowed now (the wave is on, a pulse is running)
 *   -222 Data out of range
 *   -224 Illegal parameter value  a word parameter that is not one of the choices
 *   -310 Watchdog: host silent, output off   the host watchdog cut the wave (watchdog.h)
 *   -350 Queue overflow         errors were lost (the queue holds 8)
 *   -363 Input buffer overrun   a line longer than 64 characters, or received bytes lost
 */
#ifndef TB_ERRORS_H
#define TB_ERRORS_H

#include <stdint.h>

enum {
	E_INVALID_CHAR = -101,
	E_SYNTAX = -102,
	E_DATA_TYPE = -104,
	E_PARAM_NOT_ALLOWED = -108,
	E_MISSING_PARAM = -109,
	E_UNDEFINED_HEADER = -113,
	E_SETTINGS_CONFLICT = -221,
	E_OUT_OF_RANGE = -222,
	E_ILLEGAL_VALUE = -224,
	E_WATCHDOG = -310,
	E_QUEUE_OVERFLOW = -350,
	E_INPUT_OVERRUN = -363,
};

void error_push(int16_t code);          /* queue it (the oldest are kept on overflow) */
int16_t error_pop(void);                /* the oldest, or 0 when none */
void error_clear(void);
const char *error_message_P(int16_t code); /* message in flash, "No error" for 0 */

#endif
