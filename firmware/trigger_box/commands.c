/*
 * commands.c — the serial protocol: line assembly, parsing, replies.
 */
#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <avr/pgmspace.h>
#include <stdlib.h>
#include <string.h>

#include "config.h"
#include "clock.h"
#include "commands.h"
#include "errors.h"
#include "numbers.h"
#include "pulse.h"
#include "serial.h"
#include "watchdog.h"
#include "wave.h"

#define LINE_MAX 64
#define MAX_PARAMS 3

static char line[LINE_MAX + 1] __attribute__((section(".noinit")));  /* no zeroing needed */
static uint8_t line_len;
static uint8_t line_overlong;   /* more than LINE_MAX characters: the rest was dropped */
static uint8_t line_invalid;    /* a byte outside printable ASCII */
static uint8_t line_lost;       /* received bytes were lost (RX ring or UART overrun) */

/* the settings FREQ and DUTY asked for (the plan in wave.c is what they give) */
static uint32_t freq_uhz, duty_ppm;
static uint16_t trg_width_ms;

static char *params[MAX_PARAMS];
static uint8_t nparams;

/* ------------------------------------------------------------------ replies */

static void reply_P(const char *s)
{
	serial_puts_P(s);
	serial_putc('\n');
}

static void reply_ok(void)
{
	reply_P(PSTR("OK"));
}

static void reply_buf(char *start, char *end)
{
	*end = 0;
	serial_puts(start);
	serial_putc('\n');
}

static void reply_error(int16_t code)
{
	char buf[8];
	error_push(code);
	serial_puts_P(PSTR("ERR "));
	itoa(code, buf, 10);
	serial_puts(buf);
	serial_putc(' ');
	reply_P(error_message_P(code));
}

/* ------------------------------------------------------------------ identity */

/* The serial number: up to 16 printable characters at EEPROM address 0 (programmed
 * per box, e.g. with avrdude -U eeprom:w:...), else the build-time TB_SERIAL. */
static void put_serial(void)
{
	char s[17];
	uint8_t n = 0;
	for (; n < 16; n++) {
		uint8_t c = eeprom_read_byte((const uint8_t *)(uintptr_t)n);
		if (c < 0x21 || c > 0x7e || c == ',')
			break;
		s[n] = (char)c;
	}
	s[n] = 0;
	if (n)
		serial_puts(s);
	else
		serial_puts_P(PSTR(TB_SERIAL));
}

/* ------------------------------------------------------------------ settings */

static void apply_plan(void)
{
	struct wave_plan p;
	wave_plan(freq_uhz, duty_ppm, &p);
	wave_set_plan(&p);
}

void commands_init(void)
{
	freq_uhz = DEFAULT_FREQ_UHZ;
	duty_ppm = DEFAULT_DUTY_PPM;
	trg_width_ms = DEFAULT_TRG_WIDTH_MS;
	apply_plan();
	watchdog_set_us(DEFAULT_WDOG_US);
	watchdog_forget_trip();
}

/* wait for the tick interrupt to carry out a start (at most one tick, 125 us), so
 * that the reply comes after the edges */
static void wait_for_tick_start(void)
{
	while (wave_start_pending() || pulse_pending())
		;
}

/* ------------------------------------------------------------------ handlers */

/* each returns 0 (and has replied) or an error code */
typedef int16_t (*handler_t)(void);

static int16_t cmd_idn(void)
{
	serial_puts_P(PSTR("VTS,TRIGGERBOX,"));
	put_serial();
	reply_P(PSTR("," FW_VERSION));
	return 0;
}

static int16_t cmd_rst(void)
{
	wave_request_stop();   /* finishes the current period, as OUTP OFF */
	pulse_open_all();
	commands_init();
	reply_ok();
	return 0;
}

static int16_t cmd_cls(void)
{
	error_clear();
	reply_ok();
	return 0;
}

static int16_t parse_range(const char *s, uint32_t lo, uint32_t hi, uint32_t *out)
{
	uint64_t v;
	int16_t err = num_parse_micro(s, &v);
	if (err)
		return err;
	if (v < lo || v > hi)
		return E_OUT_OF_RANGE;
	*out = (uint32_t)v;
	return 0;
}

static int16_t cmd_freq(void)
{
	uint32_t v = 0;
	int16_t err = parse_range(params[0], FREQ_MIN_UHZ, FREQ_MAX_UHZ, &v);
	if (err)
		return err;
	if (wave_is_on())
		return E_SETTINGS_CONFLICT;
	freq_uhz = v;
	apply_plan();
	reply_ok();
	return 0;
}

static int16_t cmd_freq_q(void)
{
	char buf[24];
	reply_buf(buf, fmt_fixed(buf, wave_plan_freq_nhz(wave_get_plan()), 9));
	return 0;
}

static int16_t cmd_duty(void)
{
	uint32_t v = 0;
	int16_t err = parse_range(params[0], DUTY_MIN_PPM, DUTY_MAX_PPM, &v);
	if (err)
		return err;
	if (wave_is_on())
		return E_SETTINGS_CONFLICT;
	duty_ppm = v;
	apply_plan();
	reply_ok();
	return 0;
}

static int16_t cmd_duty_q(void)
{
	char buf[16];
	reply_buf(buf, fmt_fixed(buf, wave_plan_duty_ppm(wave_get_plan()), 6));
	return 0;
}

static int16_t cmd_outp(void)
{
	const char *p = params[0];
	if (!strcmp_P(p, PSTR("ON")) || !strcmp_P(p, PSTR("1"))) {
		if (!wave_is_on()) {
			watchdog_forget_trip();   /* a new run */
			wave_prepare_start();
			cli();
			wave_arm_start();
			sei();
			wait_for_tick_start();
		} else {
			wave_cancel_stop();  /* ON while finishing the last period: keep going */
		}
	} else if (!strcmp_P(p, PSTR("OFF")) || !strcmp_P(p, PSTR("0"))) {
		wave_request_stop();
	} else {
		return E_ILLEGAL_VALUE;
	}
	reply_ok();
	return 0;
}

static int16_t cmd_outp_q(void)
{
	reply_P(wave_is_on() ? PSTR("ON") : PSTR("OFF"));
	return 0;
}

static int16_t parse_ms(const char *s, uint32_t *ms)
{
	int16_t err = num_parse_uint(s, ms);
	if (err)
		return err;
	if (*ms < PULSE_MIN_MS || *ms > PULSE_MAX_MS)
		return E_OUT_OF_RANGE;
	return 0;
}

static int16_t cmd_pulse(void)
{
	uint32_t ch = 0, ms = 0;
	int16_t err = num_parse_uint(params[0], &ch);
	if (err)
		return err;
	uint8_t bit = ch <= 2 ? pulse_bit((uint8_t)ch) : 0;
	if (!bit)
		return E_OUT_OF_RANGE;
	err = parse_ms(params[1], &ms);
	if (err)
		return err;
	if (pulse_busy(bit))
		return E_SETTINGS_CONFLICT;
	cli();
	pulse_request(bit, (uint16_t)ms);
	sei();
	wait_for_tick_start();
	reply_ok();
	return 0;
}

static int16_t cmd_pulse_width(void)
{
	uint32_t ms = 0;
	int16_t err = parse_ms(params[0], &ms);
	if (err)
		return err;
	trg_width_ms = (uint16_t)ms;
	reply_ok();
	return 0;
}

static int16_t cmd_pulse_width_q(void)
{
	char buf[8];
	reply_buf(buf, fmt_u64(buf, trg_width_ms));
	return 0;
}

static int16_t cmd_trg(void)
{
	if (wave_is_on() || pulse_busy(PULSE_BOTH))
		return E_SETTINGS_CONFLICT;
	watchdog_forget_trip();   /* a new run */
	wave_prepare_start();
	cli();                 /* both requests for the same tick */
	wave_arm_start();
	pulse_request(PULSE_BOTH, trg_width_ms);
	sei();
	wait_for_tick_start();
	reply_ok();
	return 0;
}

static int16_t cmd_time_q(void)
{
	char buf[24];
	reply_buf(buf, fmt_u64(buf, clock_us()));
	return 0;
}

static int16_t cmd_edges_q(void)
{
	char buf[48], *p = buf;
	uint32_t n;
	uint64_t first, last;
	wave_edges(&n, &first, &last);
	p = fmt_u64(p, n);
	*p++ = ',';
	p = fmt_u64(p, first / CLOCK_CYCLES_PER_US);
	*p++ = ',';
	p = fmt_u64(p, last / CLOCK_CYCLES_PER_US);
	reply_buf(buf, p);
	return 0;
}

static int16_t cmd_wdog(void)
{
	uint32_t us = 0;
	int16_t err = parse_range(params[0], 0, WDOG_MAX_US, &us);
	if (err)
		return err;
	if (us && us < WDOG_MIN_US)
		return E_OUT_OF_RANGE;
	watchdog_set_us(us);
	reply_ok();
	return 0;
}

static int16_t cmd_wdog_q(void)
{
	static const char s_off[] PROGMEM = "OFF";
	static const char s_idle[] PROGMEM = "IDLE";
	static const char s_armed[] PROGMEM = "ARMED";
	static const char s_tripped[] PROGMEM = "TRIPPED";
	static const char *const names[] PROGMEM = {s_off, s_idle, s_armed, s_tripped};
	char buf[48], *p = buf;
	uint64_t cut;
	uint8_t st = watchdog_state(&cut);
	p = fmt_fixed(p, watchdog_us(), 6);
	*p++ = ',';
	strcpy_P(p, (const char *)pgm_read_word(&names[st]));
	p += strlen(p);
	*p++ = ',';
	p = fmt_u64(p, cut / CLOCK_CYCLES_PER_US);
	reply_buf(buf, p);
	return 0;
}

static int16_t cmd_err_q(void)
{
	char buf[8];
	int16_t code = error_pop();
	itoa(code, buf, 10);
	serial_puts(buf);
	serial_puts_P(PSTR(",\""));
	serial_puts_P(error_message_P(code));
	reply_P(PSTR("\""));
	return 0;
}

/* ------------------------------------------------------------------ dispatch */

struct command {
	const char *name;   /* in flash, upper case */
	uint8_t nparams;
	handler_t run;
};

static const char n_idn[] PROGMEM = "*IDN?";
static const char n_rst[] PROGMEM = "*RST";
static const char n_cls[] PROGMEM = "*CLS";
static const char n_trg[] PROGMEM = "*TRG";
static const char n_freq[] PROGMEM = "FREQ";
static const char n_frequency[] PROGMEM = "FREQUENCY";
static const char n_freq_q[] PROGMEM = "FREQ?";
static const char n_frequency_q[] PROGMEM = "FREQUENCY?";
static const char n_duty[] PROGMEM = "DUTY";
static const char n_duty_q[] PROGMEM = "DUTY?";
static const char n_outp[] PROGMEM = "OUTP";
static const char n_output[] PROGMEM = "OUTPUT";
static const char n_outp_q[] PROGMEM = "OUTP?";
static const char n_output_q[] PROGMEM = "OUTPUT?";
static const char n_pulse[] PROGMEM = "PULSE";
static const char n_pulse_w[] PROGMEM = "PULSE:WIDTH";
static const char n_pulse_w_q[] PROGMEM = "PULSE:WIDTH?";
static const char n_time_q[] PROGMEM = "TIME?";
static const char n_edges_q[] PROGMEM = "EDGES?";
static const char n_wdog[] PROGMEM = "WDOG";
static const char n_watchdog[] PROGMEM = "WATCHDOG";
static const char n_wdog_q[] PROGMEM = "WDOG?";
static const char n_watchdog_q[] PROGMEM = "WATCHDOG?";
static const char n_err1[] PROGMEM = "SYST:ERR?";
static const char n_err2[] PROGMEM = "SYSTEM:ERROR?";
static const char n_err3[] PROGMEM = "SYST:ERR:NEXT?";
static const char n_err4[] PROGMEM = "SYSTEM:ERROR:NEXT?";

static const struct command commands[] PROGMEM = {
	{n_idn, 0, cmd_idn},
	{n_rst, 0, cmd_rst},
	{n_cls, 0, cmd_cls},
	{n_trg, 0, cmd_trg},
	{n_freq, 1, cmd_freq},
	{n_frequency, 1, cmd_freq},
	{n_freq_q, 0, cmd_freq_q},
	{n_frequency_q, 0, cmd_freq_q},
	{n_duty, 1, cmd_duty},
	{n_duty_q, 0, cmd_duty_q},
	{n_outp, 1, cmd_outp},
	{n_output, 1, cmd_outp},
	{n_outp_q, 0, cmd_outp_q},
	{n_output_q, 0, cmd_outp_q},
	{n_pulse, 2, cmd_pulse},
	{n_pulse_w, 1, cmd_pulse_width},
	{n_pulse_w_q, 0, cmd_pulse_width_q},
	{n_time_q, 0, cmd_time_q},
	{n_edges_q, 0, cmd_edges_q},
	{n_wdog, 1, cmd_wdog},
	{n_watchdog, 1, cmd_wdog},
	{n_wdog_q, 0, cmd_wdog_q},
	{n_watchdog_q, 0, cmd_wdog_q},
	{n_err1, 0, cmd_err_q},
	{n_err2, 0, cmd_err_q},
	{n_err3, 0, cmd_err_q},
	{n_err4, 0, cmd_err_q},
};

static uint8_t is_space(char c)
{
	return c == ' ' || c == '\t';
}

/* Split "HEADER p1,p2" or "HEADER p1 p2" in place; upper-case everything (numbers do
 * not mind). Returns the header, or 0 on a malformed parameter list. */
static char *split(char *s)
{
	for (char *q = s; *q; q++)
		if (*q >= 'a' && *q <= 'z')
			*q -= 'a' - 'A';
	while (is_space(*s))
		s++;
	char *header = s;
	while (*s && !is_space(*s))
		s++;
	nparams = 0;
	uint8_t commas = 1;  /* a comma may not come before the first parameter */
	while (*s) {
		if (is_space(*s)) {
			*s++ = 0;
			continue;
		}
		if (*s == ',') {
			if (commas)
				return 0;          /* ",," or a leading comma */
			commas = 1;
			*s++ = 0;
			continue;
		}
		if (nparams == MAX_PARAMS)
			return header;         /* too many: counted as one more below */
		params[nparams++] = s;
		commas = 0;
		while (*s && !is_space(*s) && *s != ',')
			s++;
	}
	if (commas && nparams)
		return 0;                  /* a trailing comma */
	return header;
}

static void execute(char *text)
{
	char *header = split(text);
	if (!header) {
		reply_error(E_SYNTAX);
		return;
	}
	for (uint8_t i = 0; i < sizeof commands / sizeof commands[0]; i++) {
		struct command c;
		memcpy_P(&c, &commands[i], sizeof c);
		if (strcmp_P(header, c.name))
			continue;
		watchdog_feed();   /* a line naming a command: the host's heartbeat, whatever follows */
		int16_t err;
		if (nparams > c.nparams)
			err = E_PARAM_NOT_ALLOWED;
		else if (nparams < c.nparams)
			err = E_MISSING_PARAM;
		else
			err = c.run();
		if (err)
			reply_error(err);
		return;
	}
	reply_error(E_UNDEFINED_HEADER);
}

/* ------------------------------------------------------------------ lines */

static void end_line(void)
{
	line[line_len] = 0;
	uint8_t blank = 1;
	for (uint8_t i = 0; i < line_len; i++)
		if (!is_space(line[i]))
			blank = 0;
	if (line_overlong || line_lost)
		reply_error(E_INPUT_OVERRUN);
	else if (line_invalid)
		reply_error(E_INVALID_CHAR);
	else if (!blank)
		execute(line);
	/* a blank line is not a command: no reply */
	line_len = 0;
	line_overlong = line_invalid = line_lost = 0;
}

void commands_poll(void)
{
	int16_t c;
	if (watchdog_take_trip())
		error_push(E_WATCHDOG);   /* queued here, not in the interrupt that cut the wave */
	while ((c = serial_getc()) >= 0) {
		if (serial_take_overrun())
			line_lost = 1;
		if (c == '\n') {
			end_line();
			continue;
		}
		if (c == '\r')
			continue;          /* "\r\n" line ends */
		if (line_len >= LINE_MAX) {
			line_overlong = 1;
			continue;
		}
		if ((c < 0x20 && c != '\t') || c > 0x7e)
			line_invalid = 1;
		line[line_len++] = (char)c;
	}
}
