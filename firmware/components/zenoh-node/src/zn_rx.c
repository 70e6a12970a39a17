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
 * across the classes, in order within a class, not across classes.
 *
 * Direct puts (immediate mode): while the session is healthy and nothing is
 * queued or being published, the reader puts a burst itself, one wakeup of
 * the publisher fewer per frame. A put can block (congestion control block, a
 * frozen router), so the publisher watches while the reader puts: a reader
 * away from its port for DIRECT_STALL_NS makes it read the CAN port in the
 * reader's place into the queue (the rescue), and the queue is the path again
 * (degraded) until the publisher has emptied it with puts that no longer
 * stall. Order is kept: the reader puts only when the queue is empty, and
 * frames of its burst not yet put when a put stalled go back to the queue's
 * front, ahead of what the rescue read after them. */
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

#define HOLD_FIRST_NS 1000000 /* batching: the first sleep of a stretch, before its rate is known */

/* Direct puts: a reader away from its port putting for longer than this has stalled and the
 * publisher reads in its place; the publisher looks this often while the reader puts; in a rescue it looks this
 * often whether the reader is back. Together they bound how long the CAN port goes unread
 * (about 20 ms: 180 frames of a saturated bus, against the port's capacity of 256) */
#define DIRECT_STALL_NS 10000000
#define WATCH_MS 10
#define RESCUE_POLL_MS 10

static int flush_due[ZN_MAX_BUSES]; /* batching: the reader's drain at a period's end is queued (b->lock) */

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

/* Counts a received frame and says whether it goes to a queue (invalid and filtered ones are counted). */
static esp_err_t admit(struct bus *b, const can_message_t *msg)
{
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
		return ESP_ERR_NOT_FOUND;
	}
	return ESP_OK;
}

/* Numbers an admitted frame and queues it in its class (b->lock held). */
static esp_err_t enqueue_locked(struct bus *b, const can_message_t *msg, int64_t rx_time_ns)
{
	struct rx_ring *r = &b->ring[zn_qos_class_of(&b->qos, msg)];
	uint64_t seq = b->next_seq++;
	if (r->len == r->cap) {
		COUNT(b->n.rx_queue_drops);
		COUNT(r->drops);
		return ESP_ERR_NO_MEM;
	}
	struct rx_entry *e = &r->queue[(r->head + r->len++) % r->cap];
	b->queued++;
	e->msg = *msg;
	e->rx_time_ns = rx_time_ns;
	e->seq = seq;
	return ESP_OK;
}

esp_err_t zn_node_submit(size_t bus_index, const can_message_t *msg, int64_t rx_time_ns)
{
	if (bus_index >= zn_node.cfg.bus_count || !zn_node.running)
		return ESP_ERR_INVALID_STATE;
	struct bus *b = &zn_node.buses[bus_index];
	esp_err_t rc = admit(b, msg);
	if (rc != ESP_OK)
		return rc == ESP_ERR_NOT_FOUND ? ESP_OK : rc;
	zn_mutex_lock(b->lock);
	rc = enqueue_locked(b, msg, rx_time_ns);
	/* Wake the publisher only when it has something to do: it sleeps on an empty queue
	 * (immediate mode) or until its period ends or a batch is full (batching mode).
	 * A wakeup per frame would cost two context switches per frame for nothing. */
	size_t wake_at = zn_node.cfg.publish_period_ms ? zn_node.cfg.batch_max_frames : 1;
	if (rc == ESP_OK && b->queued == wake_at)
		zn_cond_signal(b->nonempty);
	zn_mutex_unlock(b->lock);
	return rc;
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

/* Queues admitted frames of a burst (b->lock held); returns how many were admitted. */
static size_t queue_burst_locked(struct bus *b, const zn_can_rx_t *rx, size_t n)
{
	size_t admitted = 0;
	for (size_t i = 0; i < n; i++)
		if (admit(b, &rx[i].msg) == ESP_OK) {
			enqueue_locked(b, &rx[i].msg, rx[i].rx_time_ns);
			admitted++;
		}
	return admitted;
}

/* The reader's put stalled: read the CAN port in its place into the queue until the reader is
 * back (b->lock held on entry and return). The reader is inside a put, so the port is not
 * read twice; it reopens a lost port itself once back. */
static void rescue(struct bus *b, zn_can_rx_t *rx)
{
	b->rescuing = b->degraded = 1;
	if (COUNT(b->n.direct_stalls) == 0)
		zn_log("W", "%s: a put stalled (Zenoh session blocked): the publisher reads the bus meanwhile and "
			    "publishes from the queue until it caught up (direct_stalls counts these)", b->name);
	while (!b->reader_back && !zn_node.stopping) {
		zn_mutex_unlock(b->lock);
		size_t n = 0;
		esp_err_t rc = zn_can_receive_burst(b->can, rx, ZN_CAN_BURST_MAX, &n, RESCUE_POLL_MS);
		if (rc == ESP_FAIL)
			zn_stop_wait(RESCUE_POLL_MS); /* bus gone: the reader reopens it when back */
		zn_mutex_lock(b->lock);
		if (rc == ESP_OK)
			queue_burst_locked(b, rx, n);
	}
	if (!b->reader_back) /* stopping: said, so a stop during a stall can be told from one after it */
		zn_log("I", "%s: stopping while a put is stalled: the publisher stops reading for it and waits "
			    "for the put to return", b->name);
	b->rescuing = b->reader_back = 0;
	zn_cond_signal(b->handback);
}

/* Immediate mode: waits until frames are queued and the reader is not putting, watching
 * the reader's puts meanwhile (b->lock held). */
static void wait_immediate(struct bus *b, zn_can_rx_t *rx)
{
	uint64_t seen = b->direct_puts;
	for (;;) {
		if (!b->direct && (b->queued || zn_node.stopping))
			return;
		/* stopping: the port is no longer read for a stuck reader (the rescue would end at
		 * once and start again, never releasing the lock the reader needs to come back) */
		if (b->direct && !zn_node.stopping && zn_monotonic_ns() - b->direct_since >= DIRECT_STALL_NS) {
			rescue(b, rx);
			continue;
		}
		int timeout_ms = -1;
		if (b->watching) {
			if (!b->direct && b->direct_puts == seen)
				b->watching = 0; /* no put since the last look: sleep until the reader puts again */
			else
				timeout_ms = WATCH_MS;
			seen = b->direct_puts;
		}
		zn_cond_wait(b->nonempty, b->lock, timeout_ms);
	}
}

void zn_rx_publisher_thread(void *arg)
{
	struct bus *b = arg;
	uint32_t period_ms = zn_node.cfg.publish_period_ms;
	size_t batch_max = period_ms ? zn_node.cfg.batch_max_frames : 1;
	size_t take_max = period_ms ? batch_max : b->qos.class_count > 1 ? CLASS_CHUNK : PUBLISH_CHUNK;
	struct rx_entry *taken = malloc(take_max * sizeof(*taken));
	zn_can_rx_t *rx = period_ms ? NULL : malloc(ZN_CAN_BURST_MAX * sizeof(*rx)); /* a rescue's reads */
	if (!taken || (!period_ms && !rx)) {
		zn_log("E", "%s: out of memory for the publisher", b->name);
		free(taken);
		return;
	}
	int64_t next_flush = zn_monotonic_ns() + (int64_t)period_ms * 1000000;
	for (;;) {
		zn_mutex_lock(b->lock);
		if (period_ms == 0) {
			wait_immediate(b, rx);
			b->publishing = 1;
		} else {
			/* wait for the period to end, unless a full batch is already there */
			while (!zn_node.stopping && b->queued < batch_max && !flush_due[b->index]) {
				int64_t left_ms = (next_flush - zn_monotonic_ns()) / 1000000;
				if (left_ms <= 0)
					break;
				zn_cond_wait(b->nonempty, b->lock, (int)left_ms);
			}
			if (flush_due[b->index]) {
				/* the reader ends the periods while frames come: this timer only catches
				 * frames submitted otherwise (zn_node_submit); cleared once all is taken */
				if (b->queued <= take_max)
					flush_due[b->index] = 0;
				next_flush = zn_monotonic_ns() + 2 * (int64_t)period_ms * 1000000;
			} else if (zn_monotonic_ns() >= next_flush)
				next_flush += (int64_t)period_ms * 1000000 *
					      (1 + (zn_monotonic_ns() - next_flush) / ((int64_t)period_ms * 1000000));
		}
		int stopping = zn_node.stopping;
		/* a round: highest class first; immediate mode starts over after the first class
		 * that had frames (a higher one may have some by now), batching mode takes a batch of each */
		size_t round = 0;
		int64_t round_start = zn_monotonic_ns();
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
		if (!period_ms) {
			int64_t took = zn_monotonic_ns() - round_start;
			zn_mutex_lock(b->lock);
			b->publishing = 0;
			/* caught up with puts that no longer stall: the reader may put again */
			if (b->degraded && !b->queued && !b->rescuing && took < DIRECT_STALL_NS)
				b->degraded = 0;
			zn_mutex_unlock(b->lock);
		}
		if (stopping && round == 0)
			break; /* queues flushed */
	}
	free(taken);
	free(rx);
}

/* ---- the reader: bursts from the CAN port ----
 *
 * Immediate mode: each wakeup reads everything queued (one zn_can_receive_burst
 * per ZN_CAN_BURST_MAX frames) and queues it under one lock, waking the
 * publisher once if it was idle, or puts it itself (Direct puts, above). Batching mode (publish_period_ms > 0): the
 * port keeps the frames and their stamps; after the first frame of an active
 * stretch the reader sleeps until the period ends, reads all, and asks the
 * publisher to flush: one reader and one publisher wakeup per period. It wakes
 * sooner when the port would otherwise fill: the rate measured over the last
 * sleep and zn_can_rx_capacity bound the next sleep to half the capacity's
 * worth of frames; a stretch starts with a 1 ms sleep, each next one at most
 * twice the last, so a rate is known before a sleep is long. A period without
 * frames ends the stretch (the reader then blocks until the next frame). The
 * CAN port never waits for Zenoh: a reader stuck in a put is read for. */


/* May the reader put a burst of n itself? (b->lock held) Immediate mode, connected, no stall
 * since the publisher last caught up, nothing queued or being published (order), and the
 * burst not full: a full one means more waits in the port, and a reader that also put would
 * fall behind the bus where the publisher in parallel keeps up (and a flood beyond both is
 * then lost in the queue, counted, not in the port). */
static int direct_ok(const struct bus *b, size_t n)
{
	return !zn_node.cfg.publish_period_ms && n < ZN_CAN_BURST_MAX && !b->queued && !b->publishing &&
	       !b->degraded && !b->rescuing && READ(zn_node.connected) && !zn_node.stopping;
}

/* Puts frames [i, n) of f back at the front of their queues, ahead of what came after them (b->lock held). */
static void requeue_front_locked(struct bus *b, const struct rx_entry *f, size_t n)
{
	for (size_t i = n; i-- > 0;) {
		struct rx_ring *r = &b->ring[zn_qos_class_of(&b->qos, &f[i].msg)];
		if (r->len == r->cap) { /* the rescue filled the queue: these are lost as a full queue loses */
			COUNT(b->n.rx_queue_drops);
			COUNT(r->drops);
			continue;
		}
		r->head = (r->head + r->cap - 1) % r->cap;
		r->queue[r->head] = f[i];
		r->len++;
		b->queued++;
	}
}

/* The reader puts a burst itself, one sample per frame (b->lock held on entry, released on
 * return). When a put stalls (the publisher's rescue, or the reader sees it took too long),
 * the rest goes to the queue, and the reader back to its port. */
static void put_direct(struct bus *b, const zn_can_rx_t *rx, size_t n, struct rx_entry *own)
{
	size_t k = 0;
	for (size_t i = 0; i < n; i++)
		if (admit(b, &rx[i].msg) == ESP_OK)
			own[k++] = (struct rx_entry){ .msg = rx[i].msg, .rx_time_ns = rx[i].rx_time_ns, .seq = b->next_seq++ };
	size_t done = 0;
	if (k) {
		b->direct = 1;
		b->direct_puts++;
		if (!b->watching) { /* the publisher sleeps for good: from now on it watches */
			b->watching = 1;
			zn_cond_signal(b->nonempty);
		}
	}
	/* the port goes unread from now on: what counts is the whole burst's time, not one put's */
	b->direct_since = zn_monotonic_ns();
	while (done < k && !b->degraded && !b->rescuing) {
		zn_mutex_unlock(b->lock);
		publish(b, zn_qos_class_of(&b->qos, &own[done].msg), &own[done], 1);
		int64_t away = zn_monotonic_ns() - b->direct_since; /* only the reader writes it */
		COUNT(b->n.direct_frames);
		zn_mutex_lock(b->lock);
		done++;
		if (away >= DIRECT_STALL_NS)
			b->degraded = 1; /* slow even without a rescue: the queue takes the rest */
	}
	b->direct = 0;
	/* before the rescue ends: the publisher takes from the queue as soon as it does, and
	 * these are older than all it read */
	requeue_front_locked(b, own + done, k - done);
	if (b->rescuing) { /* the publisher reads in our place: it stops within RESCUE_POLL_MS */
		b->reader_back = 1;
		while (b->rescuing)
			zn_cond_wait(b->handback, b->lock, -1);
	}
	if (b->queued)
		zn_cond_signal(b->nonempty);
	zn_mutex_unlock(b->lock);
}

/* Queues one burst: one lock; the publisher woken once at most. In immediate mode the
 * reader puts it itself when it may (own: room for ZN_CAN_BURST_MAX frames). */
static void submit_burst(struct bus *b, const zn_can_rx_t *rx, size_t n, int flush, struct rx_entry *own)
{
	size_t wake_at = zn_node.cfg.publish_period_ms ? zn_node.cfg.batch_max_frames : 1;
	zn_mutex_lock(b->lock);
	if (n && own && direct_ok(b, n)) {
		put_direct(b, rx, n, own);
		return;
	}
	size_t before = b->queued;
	queue_burst_locked(b, rx, n);
	if (flush)
		flush_due[b->index] = 1;
	if (flush || (before < wake_at && b->queued >= wake_at))
		zn_cond_signal(b->nonempty);
	zn_mutex_unlock(b->lock);
}

/* Reads what the port holds, a burst at a time until one comes back short; queues each. */
static esp_err_t drain(struct bus *b, zn_can_rx_t *rx, struct rx_entry *own, int timeout_ms, size_t *total)
{
	*total = 0;
	for (;;) {
		size_t n = 0;
		esp_err_t rc = zn_can_receive_burst(b->can, rx, ZN_CAN_BURST_MAX, &n, timeout_ms);
		if (rc != ESP_OK)
			return *total ? ESP_OK : rc; /* a lost bus shows on the next call */
		submit_burst(b, rx, n, 0, own);
		*total += n;
		if (n < ZN_CAN_BURST_MAX)
			return ESP_OK;
		timeout_ms = 0;
	}
}

static void request_flush(struct bus *b)
{
	submit_burst(b, NULL, 0, 1, NULL);
}

void zn_rx_reader_thread(void *arg)
{
	struct bus *b = arg;
	int backoff_ms = CAN_REOPEN_MIN_MS;
	int64_t period_ns = (int64_t)zn_node.cfg.publish_period_ms * 1000000;
	zn_can_rx_t *rx = malloc(ZN_CAN_BURST_MAX * sizeof(*rx)); /* off the stack: a small task's budget */
	/* immediate mode: the frames of a burst the reader puts itself */
	struct rx_entry *own = period_ns ? NULL : malloc(ZN_CAN_BURST_MAX * sizeof(*own));
	if (!rx || (!period_ns && !own)) {
		zn_log("E", "%s: out of memory for the reader", b->name);
		free(rx);
		return;
	}
	int64_t flush_at = 0;	       /* batching: end of the current period; 0 = idle */
	int64_t last_drain = 0, hold = 0; /* when the port was last drained; how long it may keep frames now */
	size_t period_frames = 0;
	while (!zn_node.stopping) {
		int timeout_ms = CAN_RECEIVE_TIMEOUT_MS;
		if (flush_at) {
			int64_t now = zn_monotonic_ns();
			int64_t wake = flush_at < last_drain + hold ? flush_at : last_drain + hold;
			if (wake > now && zn_stop_wait((int)((wake - now + 999999) / 1000000)))
				break;
			timeout_ms = 0;
		}
		size_t n = 0;
		esp_err_t rc = drain(b, rx, own, timeout_ms, &n);
		if (rc == ESP_OK || rc == ESP_ERR_TIMEOUT) {
			backoff_ms = CAN_REOPEN_MIN_MS;
			if (!period_ns)
				continue;
			int64_t now = zn_monotonic_ns();
			if (!flush_at) {
				if (n) { /* a stretch starts: the period's clock runs from its first frame */
					flush_at = now + period_ns;
					hold = HOLD_FIRST_NS < period_ns ? HOLD_FIRST_NS : period_ns;
					period_frames = n;
					last_drain = now;
				}
				continue;
			}
			/* half the port's capacity at the rate of the last sleep, at most twice the
			 * last hold (the rate is only known for sleeps that short) and the period */
			int64_t half = (int64_t)zn_can_rx_capacity(b->can) / 2;
			int64_t fits = n ? half * (now - last_drain) / (int64_t)n : period_ns;
			hold = fits < 2 * hold ? fits : 2 * hold;
			if (hold > period_ns)
				hold = period_ns;
			last_drain = now;
			period_frames += n;
			if (now >= flush_at) {
				request_flush(b);
				flush_at = period_frames ? flush_at + period_ns : 0;
				if (flush_at && flush_at <= now)
					flush_at = now + period_ns; /* behind (a stall): a full period from now */
				period_frames = 0;
			}
			continue;
		}
		/* bus gone (interface down, userspace hub restarted): reopen with backoff */
		if (flush_at)
			request_flush(b); /* what was read before it went goes out now */
		flush_at = 0;
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
	/* stopping: what the port still holds goes out with the publisher's last flush */
	size_t n = 0;
	drain(b, rx, NULL, 0, &n);
	free(rx);
	free(own);
}
