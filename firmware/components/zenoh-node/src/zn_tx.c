/* zn_tx.c - Zenoh -> CAN for one bus. The subscriber callback runs on
 * Zenoh's thread and must never wait for the bus: it validates a command
 * whole and queues all of its frames, or refuses it whole (an invalid frame or
 * attachment: tx_rejected.<reason>; older than tx_max_age_ms: tx_rejected.stale;
 * stamped further ahead than that: tx_rejected.future; no room for every frame: tx_queue_full). The transmitter thread takes the
 * waiting command of highest CAN priority (lowest arbitration key of its first
 * frame, FIFO among equals), checks its age again (it may have gone stale
 * behind a stalled bus) and writes its frames onto the CAN port. When a frame
 * cannot be written (bus stalled past CAN_TRANSMIT_TIMEOUT_MS) it counts
 * can_tx_errors and abandons the rest of that command (tx_abandoned), so one
 * stalled command costs one timeout, not one per frame.
 *
 * Direct writes: a command that finds nothing queued and nobody writing is
 * written by the callback itself, with a timeout of 0 (it still never waits),
 * so a bridge whose bus keeps up costs no transmitter wakeup per command. What
 * the bus does not take at once is the transmitter's next command (tx_rest),
 * ahead of the queue: a command stays whole, never interleaved with another.
 *
 * Queued commands together: when the transmitter takes a command of fewer frames than a
 * burst, the commands next in the heap whose frames still fit go with it, in heap order,
 * in one burst (Linux: one sendmmsg), written with a timeout of 0 like a direct write. What
 * the bus does not take at once stays whole and in order: a command cut in its frames is the
 * next one, alone, with the bus's timeouts (tx_rest); those not begun go back to the heap in
 * their places. When the bus took none of a group, its first command is written alone with
 * the bus's timeouts and the next ZN_CAN_BURST_MAX commands too (tx_solo, or until the queue
 * empties), so a bus that stays full costs one gathering per 64 commands, not one each. A
 * stale command ends a group (it is refused when its turn comes), so freshness and order are
 * as when each command went alone.
 *
 * A command's source time: its attachment's first frame time when it carries
 * an attachment (and that time is not 0), else the sample's Zenoh timestamp,
 * else none (accepted, counted tx_unstamped). Ages are CLOCK_REALTIME now minus
 * the source time (docs/bridge.md, Freshness); a time ahead of now is age 0, but
 * one further ahead than tx_max_age_ms would never go stale: refused on arrival
 * (tx_rejected.future), as is an attachment time beyond int64 (year 2262).
 *
 * Shutdown: zn_tx_close shuts a gate the callback passes on entry, then
 * undeclares the subscriber and waits until no callback is inside; a callback
 * Zenoh still starts later sees the gate shut and touches nothing else but its
 * count beside the gate (tx_refused_closed, as one before start has succeeded). The
 * transmitter then writes what is queued while the bus takes it. Once a write
 * has failed (tx_failed: none went since), it writes only what the bus takes at
 * once (a timeout of 0, in groups) and abandons all that is left at the first
 * group the bus takes none of: a stalled bus holds stop one timeout, not one per
 * command, and a failure the bus has recovered from since costs nothing. */
#include <assert.h>
#include <inttypes.h>
#include <stdlib.h>

#include "zn_internal.h"

/* buffers sized for the target (docs/bridge.md, Limits): 24 bytes a queued frame on a
 * 32-bit core, and the largest command within what the Zenoh port lets in */
static_assert(sizeof(struct tx_entry) <= 24, "a queued command frame");
static_assert(sizeof(struct tx_cmd) <= 24, "a queued command");
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

uint32_t zn_tx_arbitration_key(const can_message_t *msg)
{
	if (!msg->extd) /* base id, RTR, IDE = 0 */
		return (msg->identifier & CAN_STD_ID_MASK) << 21 | (uint32_t)msg->rtr << 20;
	uint32_t id = msg->identifier & CAN_EXTD_ID_MASK; /* base id (its top 11 bits), SRR = 1, IDE = 1, 18 bits, RTR */
	return (id >> 18) << 21 | 1u << 20 | 1u << 19 | (id & 0x3FFFF) << 1 | (uint32_t)msg->rtr;
}

esp_err_t zn_tx_queue_init(struct bus *b, uint32_t frames)
{
	b->tx_cap = frames;
	b->txq = calloc(frames, sizeof(*b->txq));
	b->tx_heap = calloc(frames, sizeof(*b->tx_heap)); /* a command has at least one frame */
	b->tx_burst = malloc(ZN_CAN_BURST_MAX * sizeof(*b->tx_burst));
	b->tx_group = malloc(ZN_CAN_BURST_MAX * sizeof(*b->tx_group)); /* a command has at least one frame */
	if (!b->txq || !b->tx_heap || !b->tx_burst || !b->tx_group)
		return ESP_ERR_NO_MEM;
	for (uint32_t i = 0; i < frames; i++)
		b->txq[i].next = i + 1 < frames ? i + 1 : ZN_TX_NONE;
	b->tx_free = 0;
	b->tx_len = b->tx_waiting = b->tx_order = 0;
	b->tx_rest.count = 0;
	b->tx_direct = 0;
	b->tx_solo = 0;
	return ESP_OK;
}

/* Does a wait before b in the heap? Lower key first; among equals the earlier arrival
 * (orders wrap: waiting commands are fewer than 2^31 apart). */
static int before(const struct tx_cmd *a, const struct tx_cmd *c)
{
	return a->key != c->key ? a->key < c->key : (int32_t)(a->order - c->order) < 0;
}

static void heap_push(struct bus *b, struct tx_cmd c) /* tx_lock held, room checked */
{
	uint32_t i = b->tx_waiting++;
	while (i > 0 && before(&c, &b->tx_heap[(i - 1) / 2])) {
		b->tx_heap[i] = b->tx_heap[(i - 1) / 2];
		i = (i - 1) / 2;
	}
	b->tx_heap[i] = c;
}

static struct tx_cmd heap_pop(struct bus *b) /* tx_lock held, tx_waiting > 0 */
{
	struct tx_cmd top = b->tx_heap[0], last = b->tx_heap[--b->tx_waiting];
	uint32_t i = 0, n = b->tx_waiting;
	for (;;) {
		uint32_t child = 2 * i + 1;
		if (child >= n)
			break;
		if (child + 1 < n && before(&b->tx_heap[child + 1], &b->tx_heap[child]))
			child++;
		if (!before(&b->tx_heap[child], &last))
			break;
		b->tx_heap[i] = b->tx_heap[child];
		i = child;
	}
	if (n > 0)
		b->tx_heap[i] = last;
	return top;
}

/* Returns the slots of a chain of n frames from slot to the free list (tx_lock held). */
static void release(struct bus *b, uint32_t slot, uint32_t n)
{
	while (n-- > 0 && slot != ZN_TX_NONE) {
		uint32_t next = b->txq[slot].next;
		b->txq[slot].next = b->tx_free;
		b->tx_free = slot;
		b->tx_len--;
		slot = next;
	}
}

/* The command's source time (ns since the epoch, 0 = none): the attachment's first frame time wins
 * over the sample's Zenoh timestamp, which the first router sets when the sender set none. */
static int64_t source_time(const uint8_t *attachment, size_t att_len, uint64_t zenoh_ns)
{
	if (attachment && att_len >= ZN_ATTACHMENT_SIZE(1)) {
		uint64_t t = 0;
		for (int i = 7; i >= 0; i--)
			t = t << 8 | attachment[ZN_ATTACHMENT_HEADER + i];
		if (t) /* beyond int64: later than any clock reads, so refused as ahead when judged */
			return t <= INT64_MAX ? (int64_t)t : INT64_MAX;
	}
	return zenoh_ns <= INT64_MAX ? (int64_t)zenoh_ns : 0;
}

/* Is a command of this source time older than the deadline? (0 = freshness off, or no time) */
static int stale(int64_t source_ns, int64_t *age_ms)
{
	uint32_t max_age_ms = zn_node.cfg.tx_max_age_ms;
	if (!max_age_ms || !source_ns)
		return 0;
	int64_t age = zn_realtime_ns() - source_ns;
	*age_ms = age / 1000000;
	return age > (int64_t)max_age_ms * 1000000;
}

/* Is a command's source time further ahead of the bridge's clock than the deadline? Such a
 * command would never go stale however late it arrives (a sender's clock ahead, or a forged
 * stamp), so it is refused on arrival. (0 = freshness off, or no time) */
static int ahead(int64_t source_ns, int64_t *ahead_ms)
{
	uint32_t max_age_ms = zn_node.cfg.tx_max_age_ms;
	if (!max_age_ms || !source_ns)
		return 0;
	int64_t lead = source_ns - zn_realtime_ns(); /* both positive: no overflow */
	*ahead_ms = lead / 1000000;
	return lead > (int64_t)max_age_ms * 1000000;
}

static void refuse_stale(struct bus *b, int64_t age_ms, uint32_t frames, const char *where)
{
	if (COUNT(b->n.tx_rejected_stale) == 0)
		zn_log("W",
		       "%s: refused a stale command on %s %s (%" PRId64 " ms old > tx_max_age_ms %" PRIu32
		       ", %" PRIu32 " frames); further refusals only counted (tx_rejected.stale)",
		       b->name, b->tx_key, where, age_ms, zn_node.cfg.tx_max_age_ms, frames);
}

/* The first n frames of command c are on the bus: their slots are released, in chain order, and
 * they leave the command (tx_lock held). */
static void written(struct bus *b, struct tx_cmd *c, uint32_t n)
{
	for (uint32_t i = 0; i < n; i++) {
		uint32_t next = b->txq[c->first].next;
		release(b, c->first, 1);
		c->first = next;
	}
	c->count -= n;
}

/* Writes the next burst of command c (up to max <= ZN_CAN_BURST_MAX of its frames, copied to burst)
 * with zn_can_send_burst's timeout (0: what the bus takes at once). The frames written leave
 * the command (c->first, c->count) and their slots are released; counted in tx_frames. */
static esp_err_t write_burst(struct bus *b, struct tx_cmd *c, can_message_t *burst, uint32_t max, int timeout_ms)
{
	uint32_t k = 0;
	for (uint32_t at = c->first; k < max && k < c->count; k++) {
		burst[k] = b->txq[at].msg;
		at = b->txq[at].next;
	}
	size_t sent = 0;
	zn_mutex_lock(b->can_lock);
	esp_err_t rc = zn_can_send_burst(b->can, burst, k, &sent, timeout_ms);
	zn_mutex_unlock(b->can_lock);
	zn_mutex_lock(b->tx_lock);
	written(b, c, (uint32_t)sent);
	if (sent > 0)
		b->tx_failed = 0; /* the bus takes frames again */
	zn_mutex_unlock(b->tx_lock);
	COUNT_N(b->n.tx_frames, sent);
	return rc;
}

static void accept(struct bus *b, const uint8_t *payload, size_t len, const uint8_t *attachment, size_t att_len,
		   uint64_t zenoh_ns)
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
	int64_t source_ns = source_time(attachment, att_len, zenoh_ns), age_ms = 0;
	if (stale(source_ns, &age_ms)) {
		refuse_stale(b, age_ms, (uint32_t)count, "on arrival");
		return;
	}
	if (ahead(source_ns, &age_ms)) {
		if (COUNT(b->n.tx_rejected_future) == 0)
			zn_log("W",
			       "%s: refused a command on %s stamped %" PRId64 " ms ahead of this clock (> tx_max_age_ms %" PRIu32
			       ", %zu frames): it would never go stale; further refusals only counted (tx_rejected.future)",
			       b->name, b->tx_key, age_ms, zn_node.cfg.tx_max_age_ms, count);
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
	if (!source_ns) /* written: a refused one is counted under its reason only */
		COUNT(b->n.tx_unstamped);
	struct tx_cmd c = { .order = b->tx_order++, .first = b->tx_free, .count = (uint32_t)count,
			    .source_ns = source_ns };
	uint32_t slot = b->tx_free;
	for (size_t i = 0; i < count; i++) {
		struct tx_entry *e = &b->txq[slot];
		size_t one;
		zn_wire_decode(payload + i * ZN_WIRE_FRAME_SIZE, ZN_WIRE_FRAME_SIZE, &e->msg, 1, &one); /* valid: above */
		if (i == 0)
			c.key = zn_tx_arbitration_key(&e->msg);
		if (i + 1 == count) { /* the command's chain ends here; the free list goes on after it */
			b->tx_free = e->next;
			e->next = ZN_TX_NONE;
		}
		slot = e->next;
	}
	b->tx_len += (uint32_t)count;
	if (b->tx_len > count || b->tx_direct) { /* others wait or are being written: queue behind them */
		heap_push(b, c);
		if (!b->tx_direct) /* else the direct writer hands over when it is done */
			zn_cond_signal(b->tx_ready);
		zn_mutex_unlock(b->tx_lock);
		return;
	}
	b->tx_direct = 1; /* the transmitter waits until this command is written or handed over */
	zn_mutex_unlock(b->tx_lock);
	while (c.count > 0 && write_burst(b, &c, b->tx_burst, ZN_CAN_BURST_MAX, 0) == ESP_OK)
		;
	COUNT_N(b->n.tx_direct_frames, count - c.count);
	zn_mutex_lock(b->tx_lock);
	b->tx_direct = 0;
	b->tx_rest = c; /* what the bus did not take at once (count 0: nothing) */
	if (c.count > 0 || b->tx_waiting > 0)
		zn_cond_signal(b->tx_ready);
	zn_mutex_unlock(b->tx_lock);
}

/* A command the shut gate turned away (the bridge starting or stopping): counted beside the gate, as
 * init and release may be resetting b; the bus named by its index, since its name is b's too. */
static void refuse_closed(const struct bus *b)
{
	size_t bus = (size_t)(b - zn_node.buses);
	if (COUNT(zn_tx_refused_closed[bus]) == 0)
		zn_log("W",
		       "bus %zu: refused a command: the bridge takes none while it starts or stops; further refusals "
		       "only counted (tx_refused_closed)",
		       bus);
}

void zn_tx_on_command(const uint8_t *payload, size_t len, const uint8_t *attachment, size_t attachment_len,
		      uint64_t source_time_ns, void *ctx)
{
	struct bus *b = ctx;
	(void)source_time_ns; /* freshness is judged from it (docs/bridge.md) */
	/* the gate: b lives in static storage, the queue and its lock only until zn_tx_close returns */
	if (!zn_gate_enter(zn_cb_gate(b))) {
		refuse_closed(b);
		return;
	}
	accept(b, payload, len, attachment, attachment_len, source_time_ns);
	zn_gate_leave(zn_cb_gate(b), b->tx_lock, b->tx_idle);
}

void zn_tx_close(struct bus *b)
{
	zn_gate_shut(zn_cb_gate(b));
	if (b->sub) {
		zn_undeclare_subscriber(b->sub);
		b->sub = NULL;
	}
	zn_gate_wait(zn_cb_gate(b), b->tx_lock, b->tx_idle, CLOSE_RECHECK_MS);
}

/* What is left of a command's deadline (ms, at least 1), or -1 when it has none. */
static int64_t lifetime_left_ms(const struct tx_cmd *c)
{
	uint32_t max_age_ms = zn_node.cfg.tx_max_age_ms;
	if (!max_age_ms || !c->source_ns)
		return -1;
	int64_t left = ((int64_t)max_age_ms * 1000000 - (zn_realtime_ns() - c->source_ns)) / 1000000;
	return left > 0 ? left : 1;
}

/* Writes what is left of one command, a burst (Linux: one sendmmsg) at a time; returns whether
 * the bus took it all. Its slots are its writer's (the transmitter, or a callback writing
 * directly) until released; other callbacks only fill free ones. */
static int transmit_command(struct bus *b, struct tx_cmd *c, can_message_t *burst)
{
	while (c->count > 0) {
		/* a busy bus may hold a frame: never past the command's deadline, so a command
		 * that goes stale waiting for the bus is refused, not written late */
		int64_t left_ms = lifetime_left_ms(c), age_ms = 0;
		int timeout_ms = left_ms >= 0 && left_ms < CAN_TRANSMIT_TIMEOUT_MS ? (int)left_ms : CAN_TRANSMIT_TIMEOUT_MS;
		esp_err_t rc = ESP_ERR_TIMEOUT; /* stale: refused below */
		if (left_ms < 0) {
			rc = write_burst(b, c, burst, ZN_CAN_BURST_MAX, timeout_ms);
		} else if (!stale(c->source_ns, &age_ms)) {
			/* the port's timeout holds per frame: a burst given the deadline as its timeout went
			 * on past it while the bus took a frame now and then. So what the bus takes at once,
			 * then one frame waiting at most what is left, and the deadline judged again */
			rc = write_burst(b, c, burst, ZN_CAN_BURST_MAX, 0);
			if (rc == ESP_ERR_TIMEOUT)
				rc = write_burst(b, c, burst, 1, timeout_ms);
		}
		if (rc == ESP_OK)
			continue;
		uint32_t left = c->count;
		zn_mutex_lock(b->tx_lock);
		release(b, c->first, left);
		zn_mutex_unlock(b->tx_lock);
		if (rc == ESP_ERR_TIMEOUT && timeout_ms < CAN_TRANSMIT_TIMEOUT_MS) { /* the deadline bounded the wait */
			stale(c->source_ns, &age_ms);
			refuse_stale(b, age_ms, left, "waiting for the bus");
			return 1; /* the deadline ran out, not the bus */
		}
		COUNT_N(b->n.tx_abandoned, left - 1);
		if (COUNT(b->n.can_tx_errors) == 0)
			zn_log("W",
			       "%s: CAN transmit failed (bus stalled or gone): the rest of that command is abandoned "
			       "(tx_abandoned); further failures only counted",
			       b->name);
		return 0;
	}
	return 1;
}

/* Takes from the heap, after the command group[0], the commands whose frames fit one burst with
 * it, stopping at a stale one; returns how many the group holds (tx_lock held). */
static uint32_t gather(struct bus *b, struct tx_cmd *group)
{
	uint32_t n = 1, frames = group[0].count;
	int64_t age_ms = 0;
	while (b->tx_waiting > 0 && frames + b->tx_heap[0].count <= ZN_CAN_BURST_MAX &&
	       !stale(b->tx_heap[0].source_ns, &age_ms)) {
		group[n] = heap_pop(b);
		frames += group[n++].count;
	}
	return n;
}

/* Writes a group of whole commands in one burst with a timeout of 0 and returns the frames the
 * bus took. Each command's frames written are released and counted; a command begun but not
 * finished becomes tx_rest; those not begun go back to the heap, but for group[0] when nothing
 * went: the caller writes it alone, with the bus's timeouts. */
static size_t write_group(struct bus *b, struct tx_cmd *group, uint32_t n)
{
	uint32_t k = 0;
	for (uint32_t i = 0; i < n; i++)
		for (uint32_t at = group[i].first, j = 0; j < group[i].count; j++, at = b->txq[at].next)
			b->tx_burst[k++] = b->txq[at].msg;
	size_t sent = 0;
	zn_mutex_lock(b->can_lock);
	zn_can_send_burst(b->can, b->tx_burst, k, &sent, 0);
	zn_mutex_unlock(b->can_lock);
	zn_mutex_lock(b->tx_lock);
	if (sent > 0)
		b->tx_failed = 0;
	size_t left = sent;
	for (uint32_t i = 0; i < n; i++) {
		struct tx_cmd *c = &group[i];
		uint32_t done = left < c->count ? (uint32_t)left : c->count;
		left -= done;
		written(b, c, done);
		if (c->count == 0 || (i == 0 && sent == 0))
			continue;
		if (done > 0)
			b->tx_rest = *c;
		else
			heap_push(b, *c);
	}
	zn_mutex_unlock(b->tx_lock);
	COUNT_N(b->n.tx_frames, sent);
	return sent;
}

/* Stopping on a bus that takes nothing at once: every frame still queued (the caller's command's
 * too, its slots not released) is abandoned, counted. */
static void abandon_queue(struct bus *b)
{
	zn_mutex_lock(b->tx_lock);
	uint32_t left = b->tx_len;
	b->tx_waiting = 0;
	b->tx_rest.count = 0;
	b->tx_len = 0;
	zn_mutex_unlock(b->tx_lock);
	COUNT_N(b->n.tx_abandoned, left);
}

void zn_tx_transmitter_thread(void *arg)
{
	struct bus *b = arg;
	for (;;) {
		zn_mutex_lock(b->tx_lock);
		/* a callback writing directly (tx_direct) has the bus until it hands over; at stop none
		 * is (zn_tx_close waited for them) */
		while ((b->tx_direct || (b->tx_waiting == 0 && b->tx_rest.count == 0)) && !b->tx_stop) {
			if (!b->tx_direct)
				b->tx_solo = 0; /* the queue emptied: the bus keeps up again */
			zn_cond_wait(b->tx_ready, b->tx_lock, -1);
		}
		if (b->tx_waiting == 0 && b->tx_rest.count == 0) { /* stopping, and nothing is left */
			zn_mutex_unlock(b->tx_lock);
			return;
		}
		/* stopping after a failed write: only what the bus takes at once, so a stalled bus does not
		 * hold stop a timeout per command, and one that has recovered since loses nothing */
		int at_once = b->tx_stop && b->tx_failed;
		/* a command's rest is partly on the bus: its deadline is judged per burst
		 * (transmit_command), so it is refused as a whole only before any frame went */
		int rest = b->tx_rest.count > 0;
		struct tx_cmd c = rest ? b->tx_rest : heap_pop(b);
		b->tx_rest.count = 0;
		int64_t age_ms = 0;
		int too_old = !rest && stale(c.source_ns, &age_ms);
		if (too_old)
			release(b, c.first, c.count);
		uint32_t grouped = 1;
		b->tx_group[0] = c;
		if (!rest && !too_old) {
			if (b->tx_solo > 0 && !at_once)
				b->tx_solo--;
			else
				grouped = gather(b, b->tx_group);
		}
		zn_mutex_unlock(b->tx_lock);
		if (too_old) {
			refuse_stale(b, age_ms, c.count, "in the transmit queue");
			continue;
		}
		if (grouped > 1 || at_once) {
			if (write_group(b, b->tx_group, grouped) > 0)
				continue; /* what is left of it is tx_rest or back in the heap */
			if (at_once) { /* the bus took none: it, and all that waits, abandoned */
				abandon_queue(b);
				return;
			}
			b->tx_solo = ZN_CAN_BURST_MAX; /* only the transmitter reads or writes it */
		}
		if (!transmit_command(b, &c, b->tx_burst)) { /* the bus's one burst buffer: one writer at a time */
			zn_mutex_lock(b->tx_lock);
			b->tx_failed = 1;
			zn_mutex_unlock(b->tx_lock);
		}
	}
}
