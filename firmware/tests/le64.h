/* le64.h - reads a little-endian u64 of a recorded attachment (sequence numbers and
 * receive stamps, docs/bridge.md's wire format), for the unit tests that check them. */
#ifndef ZN_TEST_LE64_H
#define ZN_TEST_LE64_H

#include <stdint.h>

static inline uint64_t le64(const uint8_t *p)
{
	uint64_t v = 0;
	for (int i = 7; i >= 0; i--)
		v = v << 8 | p[i];
	return v;
}

#endif
