/* zn_tx.c - Zenoh -> CAN for one bus. The subscriber callback runs on
 * Zenoh's thread and must never wait for the bus: it validates a command
 * whole and queues all of its frames, or refuses it whole (an invalid frame or
 * attachment: tx_rejected.<reason>; no room for every frame: tx_queue_full).
 * The transmitter thread drains the bounded queue onto the CAN port. When a
 * frame cannot be written (bus stalled past CAN_TRANSMIT_TIMEOUT_MS) it counts
 * can_tx_errors and abandons the rest of that command (tx_abandoned), so one
 * stalled command costs one timeout, not one per frame.
 *
 * Shutdown: zn_tx_close shuts a gate the callback passes on entry, then
 * undeclares the subscriber and waits until no callback is inside; a callback
 * Zenoh still starts later sees the gate shut and touches nothing else. The
 * transmitter then writes what is queued while the bus takes it and abandons
 * the rest at the first failure. */
#include <assert.h>
#include <inttypes.h>

#include "zn_internal.h"

/* buffers sized for the target (docs/bridge.md, Limits): 24 bytes a queued frame on a
 * 32-bit core, and the largest command within what the Zenoh port lets in */
static_assert(sizeof(struct tx_entry) <= 24, "a queued command frame");
static_assert(ZN_BATCH_MAX_FRAMES * ZN_WIRE_FRAME_SIZE + ZN_ATTACHMENT_SIZE(ZN_BATCH_MAX_FRAMES) + 1024 <=
		      ZN_RX_MESSAGE_MAX,
	      "a largest command and its key fit the Zenoh message cap");

#define CAN_TRANSMIT_TIMEOUT_MS 100 /* a frame that cannot be sent by then is counted as failed */
#define CLOSE_RECHECK_MS 10	    /* zn_tx_close re-reads the gate's count at least this often */

static void refuse(struct bus *b, uint64_t *counter, const char *why, size_t len, size_t frames)
{
	if (COUNT(*counter) == 0)
		zn_log("W", "%s: refused a command on %s (%s, %zu bytes, %zu frames); further refusals only counted",
		       b->name, b->tx_key, why, len, frames);
}

static void accept(struct bus *b, const uint8_t *payload, size_t len, const uint8_t *attachment, size_t att_len)
{
	size_t count = 0;
	COUNT(b->n.tx_samples);
	zn_wire_result_t rc = len > ZN_BATCH_MAX_FRAMES * ZN_WIRE_FRAME_SIZE
				      ? ZN_WIRE_ERR_LENGTH
				      : zn_wire_decode(payload, len, NULL, 0, &count); /* validate only */
	if (rc == ZN_WIRE_OK)
		rc = zn_attachment_check(attachment, att_len, count);
	if (rc != ZN_WIRE_OK) {
		refuse(b, &b->n.tx_rejected[-rc], zn_wire_reason(rc), len, len / ZN_WIRE_FRAME_SIZE);
		return;
	}
	zn_mutex_lock(b->tx_lock);
	if (b->tx_cap - b->tx_len < count) {
		uint32_t queued = b->tx_len;
		zn_mutex_unlock(b->tx_lock);
		if (COUNT(b->n.tx_queue_full) == 0)
			zn_log("W",
			       "%s: tx queue full (%" PRIu32 " of %" PRIu32
			       " frames queued): refused a command of %zu frames; further refusals only counted",
			       b->name, queued, b->tx_cap, count);
		return;
	}
	uint32_t cmd = ++b->tx_cmd;
	for (size_t i = 0; i < count; i++) {
		struct tx_entry *e = &b->txq[(b->tx_head + b->tx_len + i) % b->tx_cap];
		size_t one;
		zn_wire_decode(payload + i * ZN_WIRE_FRAME_SIZE, ZN_WIRE_FRAME_SIZE, &e->msg, 1, &one); /* valid: above */
		e->cmd = cmd;
	}
	b->tx_len += (uint32_t)count;
	zn_cond_signal(b->tx_ready);
	zn_mutex_unlock(b->tx_lock);
}

void zn_tx_on_command(const uint8_t *payload, size_t len, const uint8_t *attachment, size_t attachment_len,
		      uint64_t source_time_ns, void *ctx)
{
	struct bus *b = ctx;
	(void)source_time_ns; /* freshness is judged from it (docs/bridge.md) */
	/* the gate: b lives in static storage, the queue and its lock only until zn_tx_close returns */
	__atomic_add_fetch(&b->cb_inflight, 1, __ATOMIC_SEQ_CST);
	if (__atomic_load_n(&b->cb_closed, __ATOMIC_SEQ_CST)) {
		__atomic_sub_fetch(&b->cb_inflight, 1, __ATOMIC_SEQ_CST);
		return;
	}
	accept(b, payload, len, attachment, attachment_len);
	zn_mutex_lock(b->tx_lock);
	__atomic_sub_fetch(&b->cb_inflight, 1, __ATOMIC_SEQ_CST);
	zn_cond_signal(b->tx_idle);
	zn_mutex_unlock(b->tx_lock);
}

void zn_tx_close(struct bus *b)
{
	__atomic_store_n(&b->cb_closed, 1, __ATOMIC_SEQ_CST);
	if (b->sub) {
		zn_undeclare_subscriber(b->sub);
		b->sub = NULL;
	}
	if (!b->tx_lock)
		return;
	zn_mutex_lock(b->tx_lock);
	/* a callback turned away at the gate does not signal: re-read the count meanwhile */
	while (__atomic_load_n(&b->cb_inflight, __ATOMIC_SEQ_CST) > 0)
		zn_cond_wait(b->tx_idle, b->tx_lock, CLOSE_RECHECK_MS);
	zn_mutex_unlock(b->tx_lock);
}

void zn_tx_transmitter_thread(void *arg)
{
	struct bus *b = arg;
	uint32_t failed_cmd = 0; /* 0: none (commands are numbered from 1) */
	for (;;) {
		zn_mutex_lock(b->tx_lock);
		while (b->tx_len == 0 && !b->tx_stop)
			zn_cond_wait(b->tx_ready, b->tx_lock, -1);
		if (b->tx_len == 0 || (b->tx_stop && failed_cmd)) {
			uint32_t left = b->tx_len; /* stopping: the bus does not take them */
			b->tx_len = 0;
			zn_mutex_unlock(b->tx_lock);
			COUNT_N(b->n.tx_abandoned, left);
			return;
		}
		struct tx_entry e = b->txq[b->tx_head];
		b->tx_head = (b->tx_head + 1) % b->tx_cap;
		b->tx_len--;
		zn_mutex_unlock(b->tx_lock);
		if (e.cmd == failed_cmd) {
			COUNT(b->n.tx_abandoned);
			continue;
		}
		zn_mutex_lock(b->can_lock);
		esp_err_t rc = zn_can_transmit(b->can, &e.msg, CAN_TRANSMIT_TIMEOUT_MS);
		zn_mutex_unlock(b->can_lock);
		if (rc == ESP_OK) {
			COUNT(b->n.tx_frames);
			failed_cmd = 0;
			continue;
		}
		failed_cmd = e.cmd;
		if (COUNT(b->n.can_tx_errors) == 0)
			zn_log("W",
			       "%s: CAN transmit failed (bus stalled or gone): the rest of that command is abandoned "
			       "(tx_abandoned); further failures only counted",
			       b->name);
	}
}
