/* memzenoh.c - what zenoh-node-memzenoh adds to the in-memory Zenoh port: the
 * real Linux CAN port and the real process, with Zenoh replaced by a recorder,
 * so bench/wakeups.py --can-side measures the CAN side's wakeups, syscalls and
 * CPU per frame without Zenoh's (the recorder keeps MOCK_MAX_PUTS puts and
 * counts the rest; its stats still say what was published). Never shipped. */
#include "zn_mock.h"

void mock_can_reset(void); /* zenoh_mock.c's reset calls it; no mock CAN bus here */
void mock_can_reset(void)
{
}

__attribute__((constructor)) static void memzenoh_init(void)
{
	mock_reset(); /* the recorder's buffers, which the unit tests allocate per test */
}
