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
 * Batching mode (publish period > 0): the reader and the publisher thread
 * take turns (Turns, below): whichever is due reads the port and, at a
 * period's end, puts the period's batch itself, so a period wakes one thread;
 * the other sleeps until the drain after, which is also its watch: a put still
 * running then has stalled, and the sleeper reads the port meanwhile.
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
#define TURN_SLACK_NS 1000000 /* batching: a sleeper due this much after the drain it is to make is not woken */

/* Direct puts: a reader away from its port putting for longer than this has stalled and the
 * publisher reads in its place; the publisher looks this often while the reader puts; in a rescue it looks this
 * often whether the reader is back. Together they bound how long the CAN port goes unread
 * (about 20 ms: 180 frames of a saturated bus, against the port's capacity of 256) */
#define DIRECT_STALL_NS 10000000
#define WATCH_MS 10
#define RESCUE_POLL_MS 10
#define STALL_LONG_NS 1000000000 /* a put stalled this long is the link's, not a scheduling hiccup: said once */

/* Batching mode's turns (zn_rx.c, Turns), one per bus, guarded by its b->lock. Threads: 0 the
 * reader, 1 the publisher. */
enum { NOBODY = -1 };
static struct turns {
	int port, putter; /* the thread reading the port; the one publishing from the queue (or NOBODY) */
	int idle_read;	  /* the port's reader waits for a stretch's first frame (due was 0) */
	int next;	  /* the thread to make the drain at due */
	int64_t due;	  /* the port's next drain (monotonic ns); 0: no stretch, the port is waited on */
	int64_t flush_at, last_drain, hold; /* the period's end (0: none); the last drain; how long the port may keep frames now */
	size_t period_frames;
	int flush_owed;	     /* a period ended during a put: its putter publishes all of the queue */
	int64_t sleeping[2]; /* a sleeping thread's wakeup (INT64_MAX: until signalled); 0: awake */
	int64_t put_since;   /* the putter's current put started then */
	uint64_t puts, stall_seen; /* puts so far; the one last counted as stalled */
	int reader_done, backoff_ms;
} turns[ZN_MAX_BUSES];

esp_err_t zn_rx_queue_init(struct bus *b)
{
	char err[160];
	if (zn_qos_parse(zn_node.cfg.rx_qos_table, &zn_node.cfg.rx_qos, &b->qos, err, sizeof(err)) != 0) {
		zn_log("E", "%s", err); /* zn_node_check_config refused it already */
		return ESP_ERR_INVALID_ARG;
	}
	turns[b->index] = (struct turns){ .port = NOBODY, .putter = NOBODY, .backoff_ms = CAN_REOPEN_MIN_MS };
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

void zn_rx_gauges(struct bus *b, uint32_t *queued, int64_t *put_running_ms)
{
	int64_t since = 0;
	*queued = 0;
	if (b->lock) { /* NULL: the bus was never set up */
		zn_mutex_lock(b->lock);
		const struct turns *t = &turns[b->index];
		if (zn_node.cfg.publish_period_ms)
			since = t->putter != NOBODY ? t->put_since : 0;
		else
			since = b->direct ? b->direct_since : b->publishing ? b->publish_since : 0;
		*queued = b->queued;
		zn_mutex_unlock(b->lock);
	}
	*put_running_ms = since ? (zn_monotonic_ns() - since) / 1000000 : 0;
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
	 * (immediate mode); in batching mode a period starts (if none runs: the threads sleep
	 * until its end) or a batch is full. A wakeup per frame would cost two context
	 * switches per frame for nothing. */
	struct turns *t = &turns[b->index];
	int64_t period_ns = (int64_t)zn_node.cfg.publish_period_ms * 1000000;
	if (rc == ESP_OK && period_ns && !t->flush_at) {
		int64_t now = zn_monotonic_ns();
		t->flush_at = now + period_ns;
		t->hold = HOLD_FIRST_NS < period_ns ? HOLD_FIRST_NS : period_ns;
		t->last_drain = now;
		t->period_frames = 0; /* only the port's frames continue a stretch */
		t->due = now + t->hold;
		zn_cond_signal(b->nonempty);
	} else if (rc == ESP_OK && b->queued == (period_ns ? zn_node.cfg.batch_max_frames : 1)) {
		zn_cond_signal(b->nonempty);
	}
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
	int rc = zn_put(b->pub[cls], payload, len, attachment, ZN_ATTACHMENT_SIZE(n));
	if (rc == 0) {
		COUNT(b->n.published_samples);
		COUNT_N(b->n.published_frames, n);
		COUNT_N(b->ring[cls].published_frames, n);
	} else if (rc == ZN_PORT_UNROUTED) {
		COUNT_N(b->n.unrouted_frames, n); /* went nowhere as surely as a failed put's, said apart */
	} else {
		COUNT_N(b->n.publish_errors, n); /* frames, as lost: read beside published_frames */
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
	int64_t since = zn_monotonic_ns();
	while (!b->reader_back && !zn_node.stopping) {
		zn_mutex_unlock(b->lock);
		size_t n = 0;
		esp_err_t rc = zn_can_receive_burst(b->can, rx, ZN_CAN_BURST_MAX, &n, RESCUE_POLL_MS);
		if (rc == ESP_FAIL)
			zn_stop_wait(RESCUE_POLL_MS); /* bus gone: the reader reopens it when back */
		zn_mutex_lock(b->lock);
		if (rc == ESP_OK)
			queue_burst_locked(b, rx, n);
		if (!b->long_stall_said && zn_monotonic_ns() - since >= STALL_LONG_NS) {
			b->long_stall_said = 1;
			zn_log("W", "%s: a put has been stalled for 1 s (the router or the link takes no samples); the "
				    "publisher keeps reading the bus for it (stats: put_running_ms)", b->name);
		}
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
		/* stopping: the reader's last reads still queue frames, so the queue is done only
		 * once the reader is gone (set by zn_node_stop after joining it) */
		if (!b->direct && (b->queued || b->reader_gone))
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

static void batch_thread(struct bus *b, int me);

void zn_rx_publisher_thread(void *arg)
{
	struct bus *b = arg;
	if (zn_node.cfg.publish_period_ms) {
		batch_thread(b, 1);
		return;
	}
	size_t take_max = b->qos.class_count > 1 ? CLASS_CHUNK : PUBLISH_CHUNK;
	struct rx_entry *taken = malloc(take_max * sizeof(*taken));
	zn_can_rx_t *rx = malloc(ZN_CAN_BURST_MAX * sizeof(*rx)); /* a rescue's reads */
	if (!taken || !rx) {
		zn_log("E", "%s: out of memory for the publisher", b->name);
		free(taken);
		free(rx);
		return;
	}
	for (;;) {
		zn_mutex_lock(b->lock);
		wait_immediate(b, rx);
		b->publishing = 1;
		int stopping = b->reader_gone;
		/* a round: highest class first, starting over after the first class that had
		 * frames (a higher one may have some by now) */
		size_t round = 0;
		int64_t round_start = zn_monotonic_ns();
		b->publish_since = round_start;
		for (size_t c = 0; c < b->qos.class_count; c++) {
			if (c)
				zn_mutex_lock(b->lock);
			size_t n = take(b, c, taken, take_max);
			zn_mutex_unlock(b->lock);
			if (n > 1) { /* what queued leaves as one write */
				zn_batch_start(zn_node.session);
				publish_runs(b, c, taken, n, 1);
				zn_batch_stop(zn_node.session);
			} else if (n) {
				publish_runs(b, c, taken, n, 1);
			}
			round += n;
			if (n)
				break;
		}
		int64_t took = zn_monotonic_ns() - round_start;
		zn_mutex_lock(b->lock);
		b->publishing = 0;
		/* caught up with puts that no longer stall: the reader may put again */
		if (b->degraded && !b->queued && !b->rescuing && took < DIRECT_STALL_NS)
			b->degraded = 0;
		zn_mutex_unlock(b->lock);
		if (stopping && round == 0)
			break; /* queues flushed */
	}
	free(taken);
	free(rx);
}

/* ---- the reader (immediate mode): bursts from the CAN port ----
 *
 * Each wakeup reads everything queued (one zn_can_receive_burst per
 * ZN_CAN_BURST_MAX frames) and queues it under one lock, waking the publisher
 * once if it was idle, or puts it itself (Direct puts, above). The CAN port
 * never waits for Zenoh: a reader stuck in a put is read for. */

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

/* Has the reader been away from its port, putting, for DIRECT_STALL_NS? Read without b->lock:
 * only the reader writes direct_since, and the time counted stops before it waits for the lock. */
static int away_too_long(const struct bus *b)
{
	return zn_monotonic_ns() - b->direct_since >= DIRECT_STALL_NS;
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
	int held = k > 1; /* a burst's samples leave as one write, not one each (zn_batch_start) */
	if (held)
		zn_batch_start(zn_node.session);
	while (done < k && !b->degraded && !b->rescuing) {
		zn_mutex_unlock(b->lock);
		publish(b, zn_qos_class_of(&b->qos, &own[done].msg), &own[done], 1);
		int stalled = away_too_long(b);
		COUNT(b->n.direct_frames);
		zn_mutex_lock(b->lock);
		done++;
		if (stalled)
			b->degraded = 1; /* slow even without a rescue: the queue takes the rest */
	}
	if (held) {
		zn_mutex_unlock(b->lock);
		zn_batch_stop(zn_node.session); /* a port that flushes here may take as long as a put */
		int stalled = away_too_long(b);
		zn_mutex_lock(b->lock);
		if (stalled)
			b->degraded = 1;
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

/* Queues one burst: one lock; the publisher woken once at most, or the reader puts it
 * itself when it may (own: room for ZN_CAN_BURST_MAX frames; NULL: queue only). */
static void submit_burst(struct bus *b, const zn_can_rx_t *rx, size_t n, struct rx_entry *own)
{
	zn_mutex_lock(b->lock);
	if (n && own && direct_ok(b, n)) {
		put_direct(b, rx, n, own);
		return;
	}
	size_t before = b->queued;
	queue_burst_locked(b, rx, n);
	if (!before && b->queued)
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
		submit_burst(b, rx, n, own);
		*total += n;
		if (n < ZN_CAN_BURST_MAX)
			return ESP_OK;
		timeout_ms = 0;
	}
}

/* The port went away (interface down, userspace hub restarted): reopens it after backoff_ms,
 * doubling that up to CAN_REOPEN_MAX_MS while it fails; returns whether the node stops.
 * Only the thread that reads the port calls this. */
static int reopen(struct bus *b, int *backoff_ms)
{
	zn_log("W", "%s: CAN bus lost, reopening in %d ms", b->name, *backoff_ms);
	if (zn_stop_wait(*backoff_ms))
		return 1;
	zn_can_t *fresh = NULL;
	if (zn_can_open(b->name, &fresh) == ESP_OK) {
		zn_mutex_lock(b->can_lock);
		zn_can_t *old = b->can;
		b->can = fresh;
		zn_mutex_unlock(b->can_lock);
		zn_can_close(old);
		COUNT(b->n.can_reopens);
		zn_log("I", "%s: CAN bus reopened", b->name);
	} else if (*backoff_ms < CAN_REOPEN_MAX_MS) {
		*backoff_ms *= 2;
	}
	return 0;
}

void zn_rx_reader_thread(void *arg)
{
	struct bus *b = arg;
	if (zn_node.cfg.publish_period_ms) {
		batch_thread(b, 0);
		return;
	}
	int backoff_ms = CAN_REOPEN_MIN_MS;
	zn_can_rx_t *rx = malloc(ZN_CAN_BURST_MAX * sizeof(*rx)); /* off the stack: a small task's budget */
	struct rx_entry *own = malloc(ZN_CAN_BURST_MAX * sizeof(*own)); /* the frames of a burst it puts itself */
	if (!rx || !own) {
		zn_log("E", "%s: out of memory for the reader", b->name);
		free(rx);
		free(own);
		return;
	}
	while (!zn_node.stopping) {
		size_t n = 0;
		esp_err_t rc = drain(b, rx, own, CAN_RECEIVE_TIMEOUT_MS, &n);
		if (rc == ESP_OK || rc == ESP_ERR_TIMEOUT)
			backoff_ms = CAN_REOPEN_MIN_MS;
		else if (reopen(b, &backoff_ms))
			break;
	}
	/* stopping: what the port still holds goes out with the publisher's last flush */
	size_t n = 0;
	drain(b, rx, NULL, 0, &n);
	free(rx);
	free(own);
}

/* ---- batching mode: turns ----
 *
 * The port keeps the frames and their stamps between drains: from a stretch's
 * first frame the port is drained when the period ends, or sooner when it would
 * otherwise fill (the rate measured over the last sleep and zn_can_rx_capacity
 * bound the next sleep to half the capacity's worth of frames; a stretch starts
 * with a 1 ms sleep, each next one at most twice the last, so a rate is known
 * before a sleep is long). Each drain goes to the queue; at a period's end (or
 * with a full batch queued) the thread that drained publishes the queue itself;
 * a period that ends while the other thread puts is owed (flush_owed), and that
 * thread publishes all of the queue once its put returns.
 * A period without frames ends the stretch, and a thread then blocks on the port
 * until the next frame.
 *
 * Both threads run this: the drains alternate between them (next), and the one
 * not draining sleeps until the drain after the next one. So a period costs one
 * wakeup of one thread (and Zenoh's transmit task's for the put), and the
 * sleeper's wakeup is the watch that costs nothing: if the other is still in a
 * put when the next drain is due (a frozen router, congestion control block),
 * the drain is the sleeper's, and every one after it until the put returns,
 * into the queue (rx_queue_drops once full), so the port is never left longer
 * than a drain's hold. A put that kept a drain waiting longer than
 * DIRECT_STALL_NS counts once in direct_stalls. Order: one thread reads the port
 * at a time and queues in reading order, one publishes at a time in queue order
 * (the batch a put took is published before anything queued after it). */

/* Reads the port (this thread's: t->port) into the queue, a burst at a time until one comes
 * back short (b->lock held on entry and return, released while reading). */
static esp_err_t drain_to_queue(struct bus *b, zn_can_rx_t *rx, int timeout_ms, size_t *total)
{
	*total = 0;
	for (;;) {
		size_t n = 0;
		zn_mutex_unlock(b->lock);
		esp_err_t rc = zn_can_receive_burst(b->can, rx, ZN_CAN_BURST_MAX, &n, timeout_ms);
		zn_mutex_lock(b->lock);
		if (rc != ESP_OK)
			return *total ? ESP_OK : rc; /* a lost bus shows on the next call */
		queue_burst_locked(b, rx, n);
		*total += n;
		if (n < ZN_CAN_BURST_MAX)
			return ESP_OK;
		timeout_ms = 0;
	}
}

/* After a drain of n frames at now (n = 0: none was made): the next drain (t->due) and whether
 * the period has ended (b->lock held). */
static int plan(struct turns *t, size_t n, int64_t now, int64_t period_ns, size_t capacity)
{
	if (!t->flush_at) {
		if (n) { /* a stretch starts: the period's clock runs from its first frame */
			t->flush_at = now + period_ns;
			t->hold = HOLD_FIRST_NS < period_ns ? HOLD_FIRST_NS : period_ns;
			t->period_frames = n;
			t->last_drain = now;
		}
		t->due = t->flush_at ? now + t->hold : 0;
		return 0;
	}
	/* half the port's capacity at the rate of the last sleep, at most twice the last hold
	 * (the rate is only known for sleeps that short) and the period */
	int64_t half = (int64_t)capacity / 2;
	int64_t fits = n ? half * (now - t->last_drain) / (int64_t)n : period_ns;
	t->hold = fits < 2 * t->hold ? fits : 2 * t->hold;
	if (t->hold > period_ns)
		t->hold = period_ns;
	t->last_drain = now;
	t->period_frames += n;
	int ended = now >= t->flush_at;
	if (ended) {
		t->flush_at = t->period_frames ? t->flush_at + period_ns : 0;
		if (t->flush_at && t->flush_at <= now)
			t->flush_at = now + period_ns; /* behind (a stall): a full period from now */
		t->period_frames = 0;
	}
	t->due = !t->flush_at ? 0 : t->flush_at < t->last_drain + t->hold ? t->flush_at : t->last_drain + t->hold;
	return ended;
}

/* Publishes the queue, all of it (a period ended) or its full batches, a batch of each class
 * per round, highest first (b->lock held; released during puts). */
static void publish_queue(struct bus *b, struct turns *t, int me, struct rx_entry *taken, int all)
{
	size_t batch_max = zn_node.cfg.batch_max_frames;
	t->putter = me;
	while (b->queued && (all || t->flush_owed || b->queued >= batch_max)) {
		for (size_t c = 0; c < b->qos.class_count; c++) {
			size_t n = take(b, c, taken, batch_max);
			if (!n)
				continue;
			t->put_since = zn_monotonic_ns();
			t->puts++;
			zn_mutex_unlock(b->lock);
			publish_runs(b, c, taken, n, batch_max);
			zn_mutex_lock(b->lock);
		}
	}
	if (!b->queued)
		t->flush_owed = 0;
	t->putter = NOBODY;
}

/* This thread reads the port: the drain due, or (due 0) a wait for a stretch's first frame;
 * then publishes if the period ended (b->lock held; released meanwhile). */
static void drain_turn(struct bus *b, struct turns *t, int me, zn_can_rx_t *rx, struct rx_entry *taken)
{
	int other = 1 - me, idle = !t->due;
	int64_t now = zn_monotonic_ns();
	if (t->putter == other && t->stall_seen != t->puts && now - t->put_since >= DIRECT_STALL_NS) {
		t->stall_seen = t->puts;
		if (COUNT(b->n.direct_stalls) == 0)
			zn_log("W", "%s: a put stalled (Zenoh session blocked): the other thread reads the bus meanwhile "
				    "(direct_stalls counts these)", b->name);
	}
	if (t->putter == other && !b->long_stall_said && now - t->put_since >= STALL_LONG_NS) {
		b->long_stall_said = 1;
		zn_log("W", "%s: a put has been stalled for 1 s (the router or the link takes no samples); the other "
			    "thread keeps reading the bus for it (stats: put_running_ms)", b->name);
	}
	t->port = me;
	t->idle_read = idle;
	size_t n = 0;
	esp_err_t rc = drain_to_queue(b, rx, idle ? CAN_RECEIVE_TIMEOUT_MS : 0, &n);
	t->idle_read = 0;
	if (rc == ESP_FAIL) { /* bus gone: what was read before it went goes out now */
		t->flush_at = t->due = 0;
		if (t->putter == NOBODY && b->queued)
			publish_queue(b, t, me, taken, 1);
		else if (t->putter == other)
			t->flush_owed = 1; /* an early full batch's put: the period that was to publish the rest is gone */
		zn_mutex_unlock(b->lock);
		reopen(b, &t->backoff_ms); /* still t->port: nobody reads the port meanwhile */
		zn_mutex_lock(b->lock);
		t->port = NOBODY;
		return;
	}
	t->port = NOBODY;
	t->backoff_ms = CAN_REOPEN_MIN_MS;
	if (idle && t->due == 0 && n == 0)
		return; /* nothing yet: wait again (stopping is seen in between) */
	int ended = plan(t, n, zn_monotonic_ns(), (int64_t)zn_node.cfg.publish_period_ms * 1000000,
			 zn_can_rx_capacity(b->can));
	/* the next drain is the other's unless it is putting; it sleeps until then at the latest
	 * (woken if not), so it is awake for the drain even if our put below stalls */
	t->next = t->putter == other ? me : other;
	if (t->next == other && t->due && t->sleeping[other] > t->due + TURN_SLACK_NS)
		zn_cond_signal(b->nonempty);
	if (t->putter == NOBODY && (ended || b->queued >= zn_node.cfg.batch_max_frames))
		publish_queue(b, t, me, taken, ended);
	else if (ended && t->putter == other)
		t->flush_owed = 1; /* a full batch's put may be running: the period's rest must not wait for the next frame */
}

/* When this thread wakes next (b->lock held): for the drain due if it is its turn (or the other
 * is putting), else for the drain after it, which is its own or, if the other is still in a
 * put by then, the drain the other could not make. */
static int64_t wake_time(const struct turns *t, int me, int64_t now, int64_t period_ns)
{
	if (!t->due)
		return INT64_MAX; /* a thread waits on the port, or nothing runs: until signalled */
	if (t->due <= now)
		return INT64_MAX; /* the other is draining it now: it wakes us if the next is ours */
	if (t->next == me || t->putter == 1 - me)
		return t->due;
	int64_t step = 2 * t->hold < period_ns ? 2 * t->hold : period_ns;
	int64_t after = t->due + step;
	return t->due < t->flush_at && after > t->flush_at ? t->flush_at : after;
}

/* Stopping (b->lock held): the reader reads the port once more if nobody does and leaves; the
 * publisher, once the reader has left and no put runs, reads it once more and publishes all
 * that is queued (nothing is read for a put that is stuck: that is waited for). Returns whether
 * this thread is done. */
static int stop_turn(struct bus *b, struct turns *t, int me, zn_can_rx_t *rx, struct rx_entry *taken)
{
	size_t n = 0;
	if (me == 0) {
		if (t->port == NOBODY) {
			t->port = me;
			drain_to_queue(b, rx, 0, &n);
			t->port = NOBODY;
		}
		t->reader_done = 1;
		zn_cond_signal(b->nonempty);
		return 1;
	}
	if (!t->reader_done || t->port != NOBODY || t->putter != NOBODY) {
		zn_cond_wait(b->nonempty, b->lock, -1);
		return 0;
	}
	t->port = me;
	drain_to_queue(b, rx, 0, &n);
	t->port = NOBODY;
	publish_queue(b, t, me, taken, 1);
	return 1;
}

/* Batching mode, thread me (0 the reader, 1 the publisher): takes its turns until stopped. */
static void batch_thread(struct bus *b, int me)
{
	struct turns *t = &turns[b->index];
	int64_t period_ns = (int64_t)zn_node.cfg.publish_period_ms * 1000000;
	zn_can_rx_t *rx = malloc(ZN_CAN_BURST_MAX * sizeof(*rx)); /* off the stack: a small task's budget */
	struct rx_entry *taken = malloc(zn_node.cfg.batch_max_frames * sizeof(*taken));
	if (!rx || !taken) {
		zn_log("E", "%s: out of memory for %s", b->name, me ? "the publisher" : "the reader");
		free(rx);
		free(taken);
		return;
	}
	zn_mutex_lock(b->lock);
	for (;;) {
		if (zn_node.stopping) {
			if (stop_turn(b, t, me, rx, taken))
				break;
			continue;
		}
		int64_t now = zn_monotonic_ns();
		if (t->port == NOBODY && (!t->due || now >= t->due)) {
			drain_turn(b, t, me, rx, taken);
			continue;
		}
		/* frames of zn_node_submit while the port is waited on: their period ends without a drain */
		if (t->port != NOBODY && t->idle_read && t->due && now >= t->due && t->putter == NOBODY) {
			int ended = plan(t, 0, now, period_ns, zn_can_rx_capacity(b->can));
			publish_queue(b, t, me, taken, ended);
			continue;
		}
		if (t->putter == NOBODY && b->queued >= zn_node.cfg.batch_max_frames) {
			publish_queue(b, t, me, taken, 0);
			continue;
		}
		int64_t until = wake_time(t, me, now, period_ns);
		/* the reader is joined first on stop, and only a stop wait would see it at once */
		if (me == 0 && until - now > (int64_t)CAN_RECEIVE_TIMEOUT_MS * 1000000)
			until = now + (int64_t)CAN_RECEIVE_TIMEOUT_MS * 1000000;
		t->sleeping[me] = until;
		zn_cond_wait(b->nonempty, b->lock, until == INT64_MAX ? -1 : (int)((until - now + 999999) / 1000000));
		t->sleeping[me] = 0;
	}
	zn_mutex_unlock(b->lock);
	free(rx);
	free(taken);
}
