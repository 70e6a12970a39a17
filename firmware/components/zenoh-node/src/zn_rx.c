/* zn_rx.c - CAN -> Zenoh for one bus: a reader thread feeding a bounded
 * queue and a publisher thread draining it (one sample per frame, or one
 * batch per publish period).
 *
 * The queue decouples the CAN reader from Zenoh: a slow network can cost
 * queued frames (counted as rx_queue_drops) but never blocks CAN reception.
 * Sequence numbers are assigned on reception, before the queue, so any loss
 * after that point shows as a gap to subscribers. */
#include <assert.h>
#include <inttypes.h>
#include <stdlib.h>

#include "zn_internal.h"

#define CAN_RECEIVE_TIMEOUT_MS 200 /* how soon a reader notices shutdown */
#define CAN_REOPEN_MIN_MS 100
#define CAN_REOPEN_MAX_MS 2000
static_assert(ZN_BATCH_MAX_FRAMES <= UINT16_MAX, "the attachment counts frames in a u16");
static_assert(sizeof(struct rx_entry) <= 40, "a queued CAN frame (rx_queue_frames of them per bus)");

#define PUBLISH_CHUNK 64 /* frames taken from the queue per lock in immediate mode */

esp_err_t zn_node_submit(size_t bus_index, const can_message_t *msg, int64_t rx_time_ns)
{
	if (bus_index >= zn_node.cfg.bus_count || !zn_node.running)
		return ESP_ERR_INVALID_STATE;
	struct bus *b = &zn_node.buses[bus_index];
	COUNT(b->n.can_rx_frames);
	uint8_t wire[ZN_WIRE_FRAME_SIZE];
	if (zn_wire_encode(msg, wire, sizeof(wire)) < 0) {
		/* not a CAN 2.0 frame (dlc > 8, id out of range): refused here, so no batch ever holds one */
		if (COUNT(b->n.invalid_frames) == 0)
			zn_log("W", "%s: skipped a frame the wire format cannot carry (id 0x%" PRIX32 ", dlc %u); further ones only counted",
			       b->name, msg->identifier, msg->data_length_code);
		return ESP_ERR_INVALID_ARG;
	}
	if (!zn_node_id_allowed(&zn_node.cfg, msg)) {
		COUNT(b->n.filtered);
		return ESP_OK;
	}
	zn_mutex_lock(b->lock);
	uint64_t seq = b->next_seq++;
	if (b->len == b->cap) {
		zn_mutex_unlock(b->lock);
		COUNT(b->n.rx_queue_drops);
		return ESP_ERR_NO_MEM;
	}
	struct rx_entry *e = &b->queue[(b->head + b->len++) % b->cap];
	e->msg = *msg;
	e->rx_time_ns = rx_time_ns;
	e->seq = seq;
	/* Wake the publisher only when it has something to do: it sleeps on an empty queue
	 * (immediate mode) or until its period ends or a batch is full (batching mode).
	 * A wakeup per frame would cost two context switches per frame for nothing. */
	size_t wake_at = zn_node.cfg.publish_period_ms ? zn_node.cfg.batch_max_frames : 1;
	if (b->len == wake_at)
		zn_cond_signal(b->nonempty);
	zn_mutex_unlock(b->lock);
	return ESP_OK;
}

static void publish(struct bus *b, const struct rx_entry *frames, size_t n)
{
	uint8_t *payload = b->payload, *attachment = b->attachment; /* sized for the largest sample (init_bus) */
	size_t len = 0;
	zn_attachment_header(attachment, (uint16_t)n, frames[0].seq);
	for (size_t i = 0; i < n; i++) {
		zn_wire_encode(&frames[i].msg, payload + len, ZN_WIRE_FRAME_SIZE); /* valid: zn_node_submit */
		len += ZN_WIRE_FRAME_SIZE;
		zn_attachment_set_time(attachment, i, frames[i].rx_time_ns);
	}
	if (zn_put(b->pub, payload, len, attachment, ZN_ATTACHMENT_SIZE(n)) == 0) {
		COUNT(b->n.published_samples);
		COUNT_N(b->n.published_frames, n);
	} else {
		COUNT(b->n.publish_errors);
	}
	if (b->ros_pub)
		zn_ros2_publish(b, frames, n);
}

/* Publishes taken[0..n) as samples of consecutive sequence numbers, at most max frames each. */
static void publish_runs(struct bus *b, const struct rx_entry *taken, size_t n, size_t max)
{
	size_t start = 0;
	for (size_t i = 1; i <= n; i++)
		if (i == n || taken[i].seq != taken[i - 1].seq + 1 || i - start == max) {
			publish(b, taken + start, i - start);
			start = i;
		}
}

static size_t take(struct bus *b, struct rx_entry *out, size_t max)
{
	size_t n = b->len < max ? b->len : max;
	for (size_t i = 0; i < n; i++)
		out[i] = b->queue[(b->head + i) % b->cap];
	b->head = (b->head + (uint32_t)n) % b->cap;
	b->len -= (uint32_t)n;
	return n;
}

void zn_rx_publisher_thread(void *arg)
{
	struct bus *b = arg;
	uint32_t period_ms = zn_node.cfg.publish_period_ms;
	size_t batch_max = period_ms ? zn_node.cfg.batch_max_frames : 1;
	size_t take_max = period_ms ? batch_max : PUBLISH_CHUNK;
	struct rx_entry *taken = malloc(take_max * sizeof(*taken));
	if (!taken) {
		zn_log("E", "%s: out of memory for the publisher", b->name);
		return;
	}
	int64_t next_flush = zn_monotonic_ns() + (int64_t)period_ms * 1000000;
	for (;;) {
		zn_mutex_lock(b->lock);
		if (period_ms == 0) {
			while (b->len == 0 && !zn_node.stopping)
				zn_cond_wait(b->nonempty, b->lock, -1);
		} else {
			/* wait for the period to end, unless a full batch is already there */
			while (!zn_node.stopping && b->len < batch_max) {
				int64_t left_ms = (next_flush - zn_monotonic_ns()) / 1000000;
				if (left_ms <= 0)
					break;
				zn_cond_wait(b->nonempty, b->lock, (int)left_ms);
			}
			if (zn_monotonic_ns() >= next_flush)
				next_flush += (int64_t)period_ms * 1000000 *
					      (1 + (zn_monotonic_ns() - next_flush) / ((int64_t)period_ms * 1000000));
		}
		int stopping = zn_node.stopping;
		size_t n = take(b, taken, take_max);
		zn_mutex_unlock(b->lock);
		if (n)
			publish_runs(b, taken, n, batch_max);
		if (stopping && n == 0)
			break; /* queue flushed */
	}
	free(taken);
}

void zn_rx_reader_thread(void *arg)
{
	struct bus *b = arg;
	int backoff_ms = CAN_REOPEN_MIN_MS;
	while (!zn_node.stopping) {
		can_message_t msg;
		int64_t rx_time_ns;
		esp_err_t rc = zn_can_receive(b->can, &msg, &rx_time_ns, CAN_RECEIVE_TIMEOUT_MS);
		if (rc == ESP_OK) {
			zn_node_submit(b->index, &msg, rx_time_ns);
			backoff_ms = CAN_REOPEN_MIN_MS;
			continue;
		}
		if (rc == ESP_ERR_TIMEOUT)
			continue;
		/* bus gone (interface down, userspace hub restarted): reopen with backoff */
		zn_log("W", "%s: CAN bus lost, reopening in %d ms", b->name, backoff_ms);
		if (zn_stop_wait(backoff_ms))
			break;
		zn_can_t *fresh = NULL;
		if (zn_can_open(b->name, &fresh) == ESP_OK) {
			zn_mutex_lock(b->can_lock);
			zn_can_t *old = b->can;
			b->can = fresh;
			zn_mutex_unlock(b->can_lock);
			zn_can_close(old);
			COUNT(b->n.can_reopens);
			zn_log("I", "%s: CAN bus reopened", b->name);
		} else if (backoff_ms < CAN_REOPEN_MAX_MS) {
			backoff_ms *= 2;
		}
	}
}
