/*
 * numbers.h — decimal numbers in and out, without floating point.
 *
 * Parameters are read as fixed point in micro-units (1e-6): "7.5" -> 7500000,
 * "0.1" -> 100000, "1e3" -> 1000000000. Accepted: [+|-]digits[.digits][(e|E)[+|-]digits]
 * (at least one digit; SCPI's NR1/NR2/NR3 forms). More than 18 significant digits are
 * rounded away; anything else in the token makes it "not a number".
 */
#ifndef TB_NUMBERS_H
#define TB_NUMBERS_H

#include <stdint.h>

/* 0 on success, else E_DATA_TYPE (not a number) or E_OUT_OF_RANGE (negative, huge) */
int16_t num_parse_micro(const char *s, uint64_t *micro);
/* a whole number: as above, and E_DATA_TYPE if it has a fraction */
int16_t num_parse_uint(const char *s, uint32_t *value);

/* write decimal text at p (no terminator), return the end */
char *fmt_u64(char *p, uint64_t v);
/* v / 10^decimals with exactly `decimals` digits after the point */
char *fmt_fixed(char *p, uint64_t v, uint8_t decimals);

#endif
