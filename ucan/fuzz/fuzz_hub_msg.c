/* fuzz_hub_msg.c - libFuzzer harness for the hub's message validator: any
 * byte string either validates to a known type or is refused with a reason. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "ucan_msg.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	static const struct ucan_ifinfo ifs[2] = { { "vcan0", UCAN_IFINDEX_BASE, CANFD_MTU, 0, 0 },
						   { "vcan1", UCAN_IFINDEX_BASE + 1, CAN_MTU, 500000, 0 } };
	/* exact-size heap copy so ASan sees any read past the message */
	uint8_t *msg = malloc(size ? size : 1);
	if (!msg)
		return 0;
	memcpy(msg, data, size);
	int type = ucan_msg_validate(msg, size, ifs, 2);
	if (type < 0 && strcmp(ucan_msg_strerror(type), "unknown error") == 0)
		abort(); /* every refusal has a named reason */
	free(msg);
	return 0;
}
