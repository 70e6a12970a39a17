/* fuzz_decode.c - libFuzzer harness for the bridge's decoders: any payload is
 * either a valid batch whose every frame re-encodes to the same bytes, or is
 * refused with a named reason; the same bytes as a command's attachment are
 * accepted only when they describe exactly the frames they count. */
#include <stdlib.h>
#include <string.h>

#include "zn_wire.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	static can_message_t msgs[64];
	uint8_t *copy = malloc(size ? size : 1); /* exact size: ASan catches overreads */
	if (!copy)
		return 0;
	memcpy(copy, data, size);
	size_t count = 0;
	zn_wire_result_t rc = zn_wire_decode(copy, size, msgs, 64, &count);
	if (rc == ZN_WIRE_OK) {
		for (size_t i = 0; i < count; i++) {
			uint8_t again[16];
			if (zn_wire_encode(&msgs[i], again, sizeof(again)) != 16 ||
			    memcmp(again, copy + 16 * i, 16) != 0)
				abort(); /* accepted bytes must be the canonical encoding */
		}
	} else if (count != 0 || strcmp(zn_wire_reason(rc), "unknown") == 0) {
		abort();
	}
	size_t frames = size >= 4 ? (size_t)(copy[2] | copy[3] << 8) : 0;
	rc = zn_attachment_check(copy, size, frames);
	if (rc == ZN_WIRE_OK ? size != ZN_ATTACHMENT_SIZE(frames) || copy[0] != ZN_ATTACHMENT_VERSION
			     : rc != ZN_WIRE_ERR_ATTACHMENT)
		abort();
	free(copy);
	return 0;
}
