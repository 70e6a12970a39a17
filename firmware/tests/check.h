/* check.h - the one assertion macro of the unit tests: prints file:line and
 * the failed expression, counts failures, lets the test continue. */
#ifndef ZN_CHECK_H
#define ZN_CHECK_H

#include <stdio.h>

static int check_failures;

#define CHECK(cond)                                                                                                    \
	do {                                                                                                           \
		if (!(cond)) {                                                                                         \
			fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond);                      \
			check_failures++;                                                                              \
		}                                                                                                      \
	} while (0)

#define CHECK_DONE(name)                                                                                               \
	do {                                                                                                           \
		if (check_failures) {                                                                                  \
			fprintf(stderr, "%s: %d check(s) failed\n", name, check_failures);                             \
			return 1;                                                                                      \
		}                                                                                                      \
		printf("%s: all checks passed\n", name);                                                       \
		return 0;                                                                                              \
	} while (0)

#endif
