/* zn_tx.c - Zenoh -> CAN for one bus: commands on the tx key are decoded
 * and validated whole, then transmitted. A command is applied completely or
 * refused whole, counted by reason. */
#include "zn_internal.h"

#define CAN_TRANSMIT_TIMEOUT_MS 100 /* a command that cannot be sent by then is counted as failed */

void zn_tx_on_command(const uint8_t *payload, size_t len, const uint8_t *attachment, size_t attachment_len, void *ctx)
{
	struct bus *b = ctx;
	can_message_t msgs[ZN_BATCH_MAX_FRAMES];
	size_t count = 0;
	COUNT(b->n.tx_samples);
	zn_wire_result_t rc = zn_wire_decode(payload, len, msgs, ZN_BATCH_MAX_FRAMES, &count);
	if (rc == ZN_WIRE_OK)
		rc = zn_attachment_check(attachment, attachment_len, count);
	if (rc != ZN_WIRE_OK) {
		/* refused whole: a command is applied completely or not at all */
		if (COUNT(b->n.tx_rejected[-rc]) == 0)
			zn_log("W", "%s: refused a command on %s (%s, %zu bytes); further refusals only counted", b->name,
			       b->tx_key, zn_wire_reason(rc), len);
		return;
	}
	zn_mutex_lock(b->can_lock);
	for (size_t i = 0; i < count; i++) {
		if (zn_can_transmit(b->can, &msgs[i], CAN_TRANSMIT_TIMEOUT_MS) == ESP_OK)
			COUNT(b->n.tx_frames);
		else
			COUNT(b->n.can_tx_errors);
	}
	zn_mutex_unlock(b->can_lock);
}
