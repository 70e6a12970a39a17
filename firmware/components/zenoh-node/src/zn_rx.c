/* zn_rx.c - CAN -> Zenoh for one bus: a reader thread feeding a bounded
 * queue and a publisher thread draining it (one sample per frame, or one
 * batch per publish period).
 *
 * The queue decouples the CAN reader from Zenoh: a slow network can cost
 * queued frames (counted as rx_queue_drops) but never blocks CAN reception.
 * Sequence numbers are assigned on reception, before the queue, so any loss
 * after that point shows as a gap to subscribers.
 *
 * QoS table (cfg.rx_qos_table, zn_qos.h): each class has its own queue and
 * publisher on the same key, and the publisher serves the highest priority
 * first, so a flood in one class never holds back, nor takes queue room from,
 * another. Sequence numbers stay per bus: a subscriber sees them without gaps
 * across the classes, in order within a class, not across classes. */
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
/* ... with several classes: a lower class's chunk is what a higher class's frame may wait for */
#define CLASS_CHUNK 4

esp_err_t zn_rx_queue_init(struct bus *b)
{
	char err[160];
	if (zn_qos_parse(zn_node.cfg.rx_qos_table, &zn_node.cfg.rx_qos, &b->qos, err, sizeof(err)) != 0) {
		zn_log("E", "%s", err); /* zn_node_check_config refused it already */
		return ESP_ERR_INVALID_ARG;
	}
	for (size_t c = 0; c < b->qos.class_count; c++) {
		b->ring[c].cap = zn_node.cfg.rx_queue_frames;
		b->ring[c].queue = calloc(b->ring[c].cap, sizeof(struct rx_entry));
		if (!b->ring[c].queue)
			return ESP_ERR_NO_MEM;
	}
	return ESP_OK;
}

int zn_rx_declare(struct bus *b)
{
	for (size_t c = 0; c < b->qos.class_count; c++) {
		if (zn_declare_publisher(zn_node.session, b->rx_key, &b->qos.classes[c], &b->pub[c]) != 0)
			return -1;
		if (b->qos.class_count > 1) {
			char what[64];
			zn_qos_describe(&b->qos.classes[c], what, sizeof(what));
			zn_log("I", "%s: QoS class %zu: %s%s", b->rx_key, c, what, c == b->qos.default_class ? " (default)" : "");
		}
	}
	return 0;
}

void zn_rx_undeclare(struct bus *b)
{
	for (size_t c = 0; c < ZN_MAX_QOS_CLASSES; c++) {
		if (b->pub[c])
			zn_undeclare_publisher(b->pub[c]);
		b->pub[c] = NULL;
	}
}

void zn_rx_queue_free(struct bus *b)
{
	for (size_t c = 0; c < ZN_MAX_QOS_CLASSES; c++) {
		free(b->ring[c].queue);
		b->ring[c].queue = NULL;
	}
}

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
	struct rx_ring *r = &b->ring[zn_qos_class_of(&b->qos, msg)];
	zn_mutex_lock(b->lock);
	uint64_t seq = b->next_seq++;
	if (r->len == r->cap) {
		zn_mutex_unlock(b->lock);
		COUNT(b->n.rx_queue_drops);
		COUNT(r->drops);
		return ESP_ERR_NO_MEM;
	}
	struct rx_entry *e = &r->queue[(r->head + r->len++) % r->cap];
	b->queued++;
	e->msg = *msg;
	e->rx_time_ns = rx_time_ns;
	e->seq = seq;
	/* Wake the publisher only when it has something to do: it sleeps on an empty queue
	 * (immediate mode) or until its period ends or a batch is full (batching mode).
	 * A wakeup per frame would cost two context switches per frame for nothing. */
	size_t wake_at = zn_node.cfg.publish_period_ms ? zn_node.cfg.batch_max_frames : 1;
	if (b->queued == wake_at)
		zn_cond_signal(b->nonempty);
	zn_mutex_unlock(b->lock);
	return ESP_OK;
}

static void publish(struct bus *b, size_t cls, const struct rx_entry *frames, size_t n)
{
	uint8_t *payload = b->payload, *attachment = b->attachment; /* sized for the largest sample (init_bus) */
	size_t len = 0;
	zn_attachment_header(attachment, (uint16_t)n, frames[0].seq);
	for (size_t i = 0; i < n; i++) {
		zn_wire_encode(&frames[i].msg, payload + len, ZN_WIRE_FRAME_SIZE); /* valid: zn_node_submit */
		len += ZN_WIRE_FRAME_SIZE;
		zn_attachment_set_time(attachment, i, frames[i].rx_time_ns);
	}
	if (zn_put(b->pub[cls], payload, len, attachment, ZN_ATTACHMENT_SIZE(n)) == 0) {
		COUNT(b->n.published_samples);
		COUNT_N(b->n.published_frames, n);
		COUNT_N(b->ring[cls].published_frames, n);
	} else {
		COUNT(b->n.publish_errors);
	}
	if (b->ros_pub)
		zn_ros2_publish(b, frames, n);
}

/* Publishes taken[0..n) of class cls as samples of consecutive sequence numbers (the
 * attachment numbers consecutive frames: frames of other classes in between split a batch),
 * at most max frames each. */
static void publish_runs(struct bus *b, size_t cls, const struct rx_entry *taken, size_t n, size_t max)
{
	size_t start = 0;
	for (size_t i = 1; i <= n; i++)
		if (i == n || taken[i].seq != taken[i - 1].seq + 1 || i - start == max) {
			publish(b, cls, taken + start, i - start);
			start = i;
		}
}

static size_t take(struct bus *b, size_t cls, struct rx_entry *out, size_t max)
{
	struct rx_ring *r = &b->ring[cls];
	size_t n = r->len < max ? r->len : max;
	for (size_t i = 0; i < n; i++)
		out[i] = r->queue[(r->head + i) % r->cap];
	r->head = (r->head + (uint32_t)n) % r->cap;
	r->len -= (uint32_t)n;
	b->queued -= (uint32_t)n;
	return n;
}

void zn_rx_publisher_thread(void *arg)
{
	struct bus *b = arg;
	uint32_t period_ms = zn_node.cfg.publish_period_ms;
	size_t batch_max = period_ms ? zn_node.cfg.batch_max_frames : 1;
	size_t take_max = period_ms ? batch_max : b->qos.class_count > 1 ? CLASS_CHUNK : PUBLISH_CHUNK;
	struct rx_entry *taken = malloc(take_max * sizeof(*taken));
	if (!taken) {
		zn_log("E", "%s: out of memory for the publisher", b->name);
		return;
	}
	int64_t next_flush = zn_monotonic_ns() + (int64_t)period_ms * 1000000;
	for (;;) {
		zn_mutex_lock(b->lock);
		if (period_ms == 0) {
			while (b->queued == 0 && !zn_node.stopping)
				zn_cond_wait(b->nonempty, b->lock, -1);
		} else {
			/* wait for the period to end, unless a full batch is already there */
			while (!zn_node.stopping && b->queued < batch_max) {
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
		/* a round: highest class first; immediate mode starts over after the first class
		 * that had frames (a higher one may have some by now), batching mode takes a batch of each */
		size_t round = 0;
		for (size_t c = 0; c < b->qos.class_count; c++) {
			if (c)
				zn_mutex_lock(b->lock);
			size_t n = take(b, c, taken, take_max);
			zn_mutex_unlock(b->lock);
			if (n)
				publish_runs(b, c, taken, n, batch_max);
			round += n;
			if (n && !period_ms)
				break;
		}
		if (stopping && round == 0)
			break; /* queues flushed */
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
