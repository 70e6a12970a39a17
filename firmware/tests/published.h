/* published.h - the unit tests' check that a run's frames were each published once, in
 * order, with their own sequence number and receive stamp (first_stamp + i), read from the
 * mock port's recorded puts. payload_is_seq: each frame's first data byte is also its index
 * (tests whose loads number their frames so). Needs check.h, le64.h and zn_mock.h first. */
#ifndef ZN_TEST_PUBLISHED_H
#define ZN_TEST_PUBLISHED_H

#include <stdio.h>

static void check_published_frames(size_t frames, int64_t first_stamp, int payload_is_seq, int wait_ms)
{
	size_t seen = 0, puts = 0;
	while (seen < frames && mock_zenoh_wait_puts(puts + 1, wait_ms) > puts) {
		const struct mock_put *p = mock_zenoh_put(puts++);
		size_t n = p->len / 16;
		CHECK(le64(p->attachment + 4) == seen);
		for (size_t k = 0; k < n; k++) {
			CHECK(le64(p->attachment + 12 + 8 * k) == (uint64_t)(first_stamp + (int64_t)(seen + k)));
			if (payload_is_seq)
				CHECK(p->payload[16 * k + 8] == (uint8_t)(seen + k));
		}
		seen += n;
	}
	CHECK(seen == frames);
	if (seen != frames)
		fprintf(stderr, "published %zu of %zu frames in %zu puts\n", seen, frames, puts);
}

#endif
