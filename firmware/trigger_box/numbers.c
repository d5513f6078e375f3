/*
 * numbers.c — decimal numbers in and out, without floating point.
 */
#include <stdlib.h>

#include "errors.h"
#include "numbers.h"

static uint8_t is_digit(char c)
{
	return c >= '0' && c <= '9';
}

int16_t num_parse_micro(const char *s, uint64_t *micro)
{
	uint8_t neg = 0, dot = 0, any = 0;
	uint64_t mant = 0;
	int16_t exp10 = 0;

	if (*s == '+' || *s == '-')
		neg = *s++ == '-';
	for (;; s++) {
		if (is_digit(*s)) {
			any = 1;
			if (mant < 100000000000000000ULL) {  /* room for one more digit */
				mant = mant * 10 + (uint8_t)(*s - '0');
				if (dot)
					exp10--;
			} else if (!dot) {
				exp10++;                          /* keep the magnitude */
			}
		} else if (*s == '.' && !dot) {
			dot = 1;
		} else {
			break;
		}
	}
	if (!any)
		return E_DATA_TYPE;
	if (*s == 'e' || *s == 'E') {
		uint8_t eneg = 0;
		int16_t e = 0;
		s++;
		if (*s == '+' || *s == '-')
			eneg = *s++ == '-';
		if (!is_digit(*s))
			return E_DATA_TYPE;
		for (; is_digit(*s); s++)
			if (e < 1000)
				e = e * 10 + (*s - '0');
		exp10 += eneg ? -e : e;
	}
	if (*s)
		return E_DATA_TYPE;
	if (mant == 0) {
		*micro = 0;
		return 0;
	}
	if (neg)
		return E_OUT_OF_RANGE;

	int16_t scale = exp10 + 6;  /* to micro-units */
	if (scale >= 0) {
		while (scale--) {
			if (mant > UINT64_MAX / 10)
				return E_OUT_OF_RANGE;
			mant *= 10;
		}
	} else if (scale < -19) {
		mant = 0;
	} else {
		uint64_t div = 1;
		while (scale++)
			div *= 10;
		mant = mant / div + (mant % div >= (div + 1) / 2);  /* round half up */
	}
	*micro = mant;
	return 0;
}

int16_t num_parse_uint(const char *s, uint32_t *value)
{
	uint64_t m;
	int16_t err = num_parse_micro(s, &m);
	if (err)
		return err;
	if (m % 1000000u)
		return E_DATA_TYPE;
	m /= 1000000u;
	if (m > UINT32_MAX)
		return E_OUT_OF_RANGE;
	*value = (uint32_t)m;
	return 0;
}

static char *put_u32(char *p, uint32_t v, uint8_t width)
{
	char t[11];
	ultoa(v, t, 10);
	uint8_t n = 0;
	while (t[n])
		n++;
	while (width > n) {
		*p++ = '0';
		width--;
	}
	for (uint8_t i = 0; i < n; i++)
		*p++ = t[i];
	return p;
}

char *fmt_u64(char *p, uint64_t v)
{
	if (v < 1000000000UL)
		return put_u32(p, (uint32_t)v, 0);
	p = fmt_u64(p, v / 1000000000UL);
	return put_u32(p, (uint32_t)(v % 1000000000UL), 9);
}

char *fmt_fixed(char *p, uint64_t v, uint8_t decimals)
{
	uint32_t unit = 1;
	for (uint8_t i = 0; i < decimals; i++)
		unit *= 10;
	p = fmt_u64(p, v / unit);
	if (decimals) {
		*p++ = '.';
		p = put_u32(p, (uint32_t)(v % unit), decimals);
	}
	return p;
}
