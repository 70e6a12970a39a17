/* zenoh_node.c - the bridge: per bus, a CAN reader thread feeding a bounded
 * queue and a publisher thread draining it (one sample per frame, or one
 * batch per publish period); a Zenoh subscriber validating commands and
 * transmitting them; a liveliness token and a stats queryable.
 *
 * The queue decouples the CAN reader from Zenoh: a slow network can cost
 * queued frames (counted as rx_queue_drops) but never blocks CAN reception.
 * Sequence numbers are assigned on reception, before the queue, so any loss
 * after that point shows as a gap to subscribers. */
#include "zenoh_node.h"

#include <assert.h>
#include <ctype.h>
#include <inttypes.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sdkconfig.h"
#include "zenoh_serialize.h"
#include "zn_port_can.h"
#include "zn_port_os.h"

#define CAN_RECEIVE_TIMEOUT_MS 200  /* how soon a reader notices shutdown */
#define CAN_TRANSMIT_TIMEOUT_MS 100 /* a command that cannot be sent by then is counted as failed */
#define CAN_REOPEN_MIN_MS 100
#define CAN_REOPEN_MAX_MS 2000
#define MONITOR_PERIOD_MS 500
#define PUBLISH_CHUNK 64 /* frames taken from the queue per lock in immediate mode */
#define STATS_JSON_MAX 8192
#define TX_REASONS (ZN_WIRE_REASONS + 1) /* wire reasons + attachment */
#define TX_REASON_ATTACHMENT ZN_WIRE_REASONS

#define COUNT(field) __atomic_fetch_add(&(field), 1, __ATOMIC_RELAXED)
#define COUNT_N(field, n) __atomic_fetch_add(&(field), (n), __ATOMIC_RELAXED)
#define READ(field) __atomic_load_n(&(field), __ATOMIC_RELAXED)

/* Propagate an error: the one pattern for early returns in init. */
#define ZN_TRY(expr)                                                                                                   \
	do {                                                                                                           \
		esp_err_t zn_try_rc = (expr);                                                                          \
		if (zn_try_rc != ESP_OK)                                                                               \
			return zn_try_rc;                                                                              \
	} while (0)

struct rx_entry {
	can_message_t msg;
	int64_t rx_time_ns;
	uint64_t seq;
};

struct bus_counters {
	uint64_t can_rx_frames, filtered, rx_queue_drops;
	uint64_t published_samples, published_frames, publish_errors;
	uint64_t tx_samples, tx_frames, can_tx_errors;
	uint64_t tx_rejected[TX_REASONS];
	uint64_t can_reopens;
};

struct bus {
	size_t index;
	const char *name;
	char rx_key[ZN_KEY_MAX], tx_key[ZN_KEY_MAX], token_key[ZN_KEY_MAX];
	zn_can_t *can;
	zn_mutex_t *can_lock; /* the reader reopens the port; the subscriber transmits on it */
	zn_publisher_t *pub;
	zn_subscriber_t *sub;
#ifdef ZN_SEEDED_FAULTS
	zn_publisher_t *misrouted;
	uint64_t fault_count;
	uint8_t held[ZN_BATCH_MAX_FRAMES * ZENOH_CAN_WIRE_SIZE], held_att[ZN_ATTACHMENT_HEADER + ZN_BATCH_MAX_FRAMES * 8];
	size_t held_len, held_att_len;
#endif
	zn_token_t *token;
	/* ROS 2 output (cfg.ros2_topic): can_msgs/msg/Frame on the rmw_zenoh data key */
	char ros_topic[ZN_KEY_MAX], ros_key[ZN_KEY_MAX];
	zn_publisher_t *ros_pub;
	zn_token_t *ros_token;
	uint64_t ros_seq;
	zn_thread_t *reader, *publisher;
	/* rx queue: ring of rx_entry, guarded by lock */
	zn_mutex_t *lock;
	zn_cond_t *nonempty;
	struct rx_entry *queue;
	uint32_t cap, head, len;
	uint64_t next_seq;
	struct bus_counters n;
};

static struct {
	zenoh_node_config_t cfg;
	zn_session_t *session;
	zn_queryable_t *stats_q;
	char stats_key[ZN_KEY_MAX];
	struct bus buses[ZN_MAX_BUSES];
	zn_thread_t *monitor;
	zn_mutex_t *stop_lock;
	zn_cond_t *stop_cond;
	volatile int stopping;
	int running;
	int64_t start_ns;
	uint64_t reconnects;
	int connected, ever_connected;
	char router_ids[512]; /* routers at the last poll; written by init, then by the monitor only */
	uint8_t gid_seed[16];  /* from the session id: ROS 2 GIDs */
	zn_token_t *ros_node_token;
} node;

static const char *const mode_names[] = { "client", "peer", "router" };

#ifdef ZN_SEEDED_FAULTS
/* Seeded faults: a broken bridge on purpose, so the bench can prove each of
 * its checks fails for the fault it exists for. Compiled only into the
 * zenoh-node-faulty test executable; ZN_FAULT=<kind>[:<n>] selects one:
 *   drop:N   drop every Nth sample          dup:N    publish every Nth sample twice
 *   swap:N   publish every Nth sample after the one that follows it
 *   flip:N   flip the lowest bit of data byte 0 of every Nth sample
 *   delay:MS hold every sample MS ms        wrongkey publish on <rx key>_misrouted
 * and on the Zenoh -> CAN path:
 *   txdrop:N never write every Nth command  txflip:N flip the lowest bit of data byte 0 of every Nth */
#include <stdlib.h>
#include <time.h>
static struct {
	enum {
		FAULT_NONE,
		FAULT_DROP,
		FAULT_DUP,
		FAULT_SWAP,
		FAULT_FLIP,
		FAULT_DELAY,
		FAULT_WRONGKEY,
		FAULT_TXDROP,
		FAULT_TXFLIP,
	} kind;
	unsigned n;
	unsigned tx_count;
} fault;

static void parse_fault(void)
{
	static const char *const names[] = { "", "drop", "dup", "swap", "flip", "delay", "wrongkey", "txdrop", "txflip" };
	const char *spec = getenv("ZN_FAULT");
	if (!spec || !*spec)
		return;
	for (int k = 1; k <= FAULT_TXFLIP; k++) {
		size_t len = strlen(names[k]);
		if (strncmp(spec, names[k], len) == 0 && (spec[len] == ':' || spec[len] == '\0')) {
			fault.kind = k;
			fault.n = spec[len] == ':' ? (unsigned)strtoul(spec + len + 1, NULL, 10) : 1;
			if (fault.n == 0)
				fault.n = 1;
			zn_log("W", "SEEDED FAULT ACTIVE: %s (n=%u) - this bridge is broken on purpose", names[k], fault.n);
			return;
		}
	}
	zn_log("E", "ZN_FAULT='%s' is not drop|dup|swap|flip|delay|txdrop|txflip:N or wrongkey; no fault seeded", spec);
}

/* The Zenoh -> CAN faults: 1 = drop this command (the caller still counts it written). */
static int tx_fault(can_message_t *msg)
{
	if (fault.kind != FAULT_TXDROP && fault.kind != FAULT_TXFLIP)
		return 0;
	if (++fault.tx_count % fault.n)
		return 0;
	if (fault.kind == FAULT_TXDROP)
		return 1;
	if (msg->data_length_code > 0 && !msg->rtr)
		msg->data[0] ^= 0x01;
	return 0;
}
#endif
static const char *const tx_reason_names[TX_REASONS] = {
	"ok", "argument", "length", "dlc", "flags", "reserved", "id_range", "remote_data", "padding", "attachment",
};

/* ---- configuration ---- */

static void copy_str(char *dst, size_t cap, const char *src)
{
	snprintf(dst, cap, "%s", src ? src : "");
}

void zenoh_node_default_config(zenoh_node_config_t *cfg)
{
	memset(cfg, 0, sizeof(*cfg));
#ifdef CONFIG_ZENOH_NODE_ENABLED
	cfg->enabled = CONFIG_ZENOH_NODE_ENABLED;
#else
	cfg->enabled = false;
#endif
	copy_str(cfg->node_name, sizeof(cfg->node_name), "zenoh-node");
	copy_str(cfg->router_address, sizeof(cfg->router_address), CONFIG_ZENOH_ROUTER_ADDRESS);
	cfg->mode = (zn_mode_t)CONFIG_ZENOH_NODE_MODE;
	cfg->publish_period_ms = CONFIG_ZENOH_PUBLISH_PERIOD_MS;
	cfg->batch_max_frames = CONFIG_ZENOH_BATCH_MAX_FRAMES;
	copy_str(cfg->key_prefix, sizeof(cfg->key_prefix), CONFIG_ZENOH_KEY_PREFIX);
	copy_str(cfg->buses[0], sizeof(cfg->buses[0]), "vcan0");
	cfg->bus_count = 1;
	/* telemetry: block rather than let Zenoh drop silently; the node's own
	 * queue bounds memory and counts what it cannot keep */
	/* not express: Zenoh may then put several samples in one write under load. Measured
	 * (docs/benchmark.md): 4x the sustained rate at a third of the CPU per frame, same latency. */
	cfg->rx_qos = (zn_qos_t){ .priority = 5, .congestion = ZN_CONGESTION_BLOCK, .express = 0 };
	cfg->tx_qos = (zn_qos_t){ .priority = 2, .congestion = ZN_CONGESTION_BLOCK, .express = 1 };
	cfg->rx_queue_frames = CONFIG_ZENOH_RX_QUEUE_FRAMES;
#ifdef CONFIG_ZENOH_COMPRESSION
	cfg->compression = CONFIG_ZENOH_COMPRESSION;
#endif
#ifdef CONFIG_ZENOH_ROS2_TOPIC
	copy_str(cfg->ros2_topic, sizeof(cfg->ros2_topic), CONFIG_ZENOH_ROS2_TOPIC);
	cfg->ros2_domain = CONFIG_ZENOH_ROS2_DOMAIN;
#endif
}

static int valid_key_chunk(const char *s)
{
	if (!*s)
		return 0;
	for (; *s; s++)
		if (*s == '*' || *s == '$' || *s == '?' || *s == '#' || *s == '/' || *s == ' ')
			return 0;
	return 1;
}

esp_err_t zenoh_node_check_config(const zenoh_node_config_t *cfg, char *err, size_t err_len)
{
#define BAD(...)                                                                                                       \
	do {                                                                                                           \
		snprintf(err, err_len, __VA_ARGS__);                                                                   \
		return ESP_ERR_INVALID_ARG;                                                                            \
	} while (0)
	if (cfg->mode > ZN_MODE_ROUTER)
		BAD("mode %d is not 0 (client), 1 (peer) or 2 (router)", (int)cfg->mode);
	if (cfg->mode == ZN_MODE_CLIENT && !cfg->router_address[0])
		BAD("client mode needs a router address (ZENOH_ROUTER_ADDRESS / --router)");
	if (cfg->publish_period_ms > 60000)
		BAD("publish period %" PRIu32 " ms is over 60000 ms", cfg->publish_period_ms);
	if (cfg->batch_max_frames < 1 || cfg->batch_max_frames > ZN_BATCH_MAX_FRAMES)
		BAD("batch max %" PRIu32 " frames is not 1..%d", cfg->batch_max_frames, ZN_BATCH_MAX_FRAMES);
	if (cfg->rx_queue_frames < 16 || cfg->rx_queue_frames > 1048576)
		BAD("rx queue %" PRIu32 " frames is not 16..1048576", cfg->rx_queue_frames);
	if (cfg->bus_count < 1 || cfg->bus_count > ZN_MAX_BUSES)
		BAD("%zu CAN buses: 1..%d supported", cfg->bus_count, ZN_MAX_BUSES);
	if (!valid_key_chunk(cfg->node_name))
		BAD("node name '%s' must be one key chunk (no '/', '*', '$', '?', '#', spaces)", cfg->node_name);
	if (!cfg->key_prefix[0] || cfg->key_prefix[0] == '/' || strchr(cfg->key_prefix, '*') ||
	    cfg->key_prefix[strlen(cfg->key_prefix) - 1] == '/')
		BAD("key prefix '%s' must be a plain key expression (no wildcards, no leading/trailing '/')",
		    cfg->key_prefix);
	for (size_t i = 0; i < cfg->bus_count; i++) {
		if (!valid_key_chunk(cfg->buses[i]))
			BAD("CAN bus name '%s' must be one key chunk", cfg->buses[i]);
		for (size_t j = 0; j < i; j++)
			if (strcmp(cfg->buses[i], cfg->buses[j]) == 0)
				BAD("CAN bus '%s' given twice", cfg->buses[i]);
	}
	if (cfg->ros2_topic[0]) {
		size_t n = strlen(cfg->ros2_topic);
		if (cfg->ros2_topic[0] != '/' || n < 2 || cfg->ros2_topic[n - 1] == '/')
			BAD("ROS 2 topic '%s' must be absolute, like /vehicle/can", cfg->ros2_topic);
		for (const char *c = cfg->ros2_topic; *c; c++)
			if (!(isalnum((unsigned char)*c) || *c == '_' || *c == '/') || (c[0] == '/' && c[1] == '/'))
				BAD("ROS 2 topic '%s': only letters, digits, '_' and single '/'", cfg->ros2_topic);
	}
	if (cfg->ros2_domain > 232)
		BAD("ROS 2 domain %" PRIu32 " is not 0..232", cfg->ros2_domain);
	const zn_qos_t *qos[2] = { &cfg->rx_qos, &cfg->tx_qos };
	for (int i = 0; i < 2; i++)
		if (qos[i]->priority < 1 || qos[i]->priority > 7)
			BAD("priority %u is not 1 (real time) .. 7 (background)", qos[i]->priority);
	const zn_id_range_t *lists[2] = { cfg->allow, cfg->deny };
	size_t counts[2] = { cfg->allow_count, cfg->deny_count };
	for (int l = 0; l < 2; l++)
		for (size_t i = 0; i < counts[l]; i++) {
			const zn_id_range_t *r = &lists[l][i];
			uint32_t max = r->extended ? CAN_EXTD_ID_MASK : CAN_STD_ID_MASK;
			if (r->first > r->last || r->last > max)
				BAD("id range 0x%" PRIX32 "-0x%" PRIX32 " is empty or beyond 0x%" PRIX32, r->first, r->last,
				    max);
		}
	return ESP_OK;
#undef BAD
}

static bool range_match(const zn_id_range_t *r, size_t n, const can_message_t *msg)
{
	for (size_t i = 0; i < n; i++)
		if ((bool)msg->extd == r[i].extended && msg->identifier >= r[i].first && msg->identifier <= r[i].last)
			return true;
	return false;
}

bool zenoh_node_id_allowed(const zenoh_node_config_t *cfg, const can_message_t *msg)
{
	if (cfg->allow_count && !range_match(cfg->allow, cfg->allow_count, msg))
		return false;
	return !range_match(cfg->deny, cfg->deny_count, msg);
}

/* ---- CAN -> Zenoh ---- */

esp_err_t zenoh_node_submit(size_t bus_index, const can_message_t *msg, int64_t rx_time_ns)
{
	if (bus_index >= node.cfg.bus_count || !node.running)
		return ESP_ERR_INVALID_STATE;
	struct bus *b = &node.buses[bus_index];
	COUNT(b->n.can_rx_frames);
	if (!zenoh_node_id_allowed(&node.cfg, msg)) {
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
	size_t wake_at = node.cfg.publish_period_ms ? node.cfg.batch_max_frames : 1;
	if (b->len == wake_at)
		zn_cond_signal(b->nonempty);
	zn_mutex_unlock(b->lock);
	return ESP_OK;
}

esp_err_t zenoh_publish_can_msg(const can_message_t *msg)
{
	return zenoh_node_submit(0, msg, zn_realtime_ns());
}

static void put_u16_le(uint8_t *p, uint16_t v)
{
	p[0] = (uint8_t)v;
	p[1] = (uint8_t)(v >> 8);
}

static void put_u64_le(uint8_t *p, uint64_t v)
{
	for (int i = 0; i < 8; i++)
		p[i] = (uint8_t)(v >> (8 * i));
}

#ifdef ZN_SEEDED_FAULTS
static int put_sample(struct bus *b, uint8_t *payload, size_t len, const uint8_t *att, size_t att_len)
{
	if (fault.kind == FAULT_NONE)
		return zn_put(b->pub, payload, len, att, att_len);
	int nth = ++b->fault_count % fault.n == 0;
	switch (fault.kind) {
	case FAULT_DROP:
		return nth ? 0 : zn_put(b->pub, payload, len, att, att_len); /* "published", silently lost */
	case FAULT_DUP:
		if (nth)
			zn_put(b->pub, payload, len, att, att_len);
		return zn_put(b->pub, payload, len, att, att_len);
	case FAULT_SWAP:
		if (nth && b->held_len == 0) { /* hold this one back until the next sample is out */
			memcpy(b->held, payload, len);
			memcpy(b->held_att, att, att_len);
			b->held_len = len;
			b->held_att_len = att_len;
			return 0;
		}
		if (zn_put(b->pub, payload, len, att, att_len) != 0)
			return -1;
		if (b->held_len) {
			zn_put(b->pub, b->held, b->held_len, b->held_att, b->held_att_len);
			b->held_len = 0;
		}
		return 0;
	case FAULT_FLIP:
		if (nth && payload[4] > 0 && !(payload[5] & ZENOH_CAN_FLAG_RTR))
			payload[8] ^= 0x01;
		return zn_put(b->pub, payload, len, att, att_len);
	case FAULT_DELAY: {
		/* a pipeline delay, not a throughput cap: hold until CAN receive time + n ms */
		int64_t rx_ns = 0;
		for (int i = 7; i >= 0; i--)
			rx_ns = rx_ns << 8 | att[ZN_ATTACHMENT_HEADER + i];
		int64_t due = rx_ns + (int64_t)fault.n * 1000000;
		struct timespec ts = { .tv_sec = due / 1000000000, .tv_nsec = due % 1000000000 };
		while (clock_nanosleep(CLOCK_REALTIME, TIMER_ABSTIME, &ts, NULL) != 0)
			;
		return zn_put(b->pub, payload, len, att, att_len);
	}
	case FAULT_WRONGKEY:
		return zn_put(b->misrouted, payload, len, att, att_len);
	case FAULT_NONE:
	case FAULT_TXDROP: /* Zenoh -> CAN faults: tx_fault() */
	case FAULT_TXFLIP:
		break;
	}
	return zn_put(b->pub, payload, len, att, att_len);
}
#else
static int put_sample(struct bus *b, uint8_t *payload, size_t len, const uint8_t *att, size_t att_len)
{
	return zn_put(b->pub, payload, len, att, att_len);
}
#endif

/* Publishes frames[0..n) (consecutive sequence numbers) as one sample. */
/* One can_msgs/msg/Frame sample per CAN frame, with rmw_zenoh's attachment: int64
 * sequence number, int64 source time (ns), the publisher's GID (length 16, bytes). */
static void publish_ros2(struct bus *b, const struct rx_entry *frames, size_t n)
{
	uint8_t cdr[64 + ZN_NAME_MAX];
	uint8_t att[8 + 8 + 1 + 16];
	for (size_t i = 0; i < n; i++) {
		int len = zn_ros2_encode_can_frame(&frames[i].msg, frames[i].rx_time_ns, b->name, cdr, sizeof(cdr));
		if (len < 0)
			continue;
		put_u64_le(att, ++b->ros_seq);
		put_u64_le(att + 8, (uint64_t)frames[i].rx_time_ns);
		att[16] = 16;
		for (int g = 0; g < 16; g++) /* a GID unique to this bus's publisher within the node */
			att[17 + g] = (uint8_t)(node.gid_seed[g] ^ (g == 15 ? b->index : 0));
		zn_put(b->ros_pub, cdr, (size_t)len, att, sizeof(att));
	}
}

static void publish(struct bus *b, const struct rx_entry *frames, size_t n)
{
	static_assert(ZN_BATCH_MAX_FRAMES * ZENOH_CAN_WIRE_SIZE <= 16384, "batch payload bound");
	uint8_t payload[ZN_BATCH_MAX_FRAMES * ZENOH_CAN_WIRE_SIZE];
	uint8_t attachment[ZN_ATTACHMENT_HEADER + ZN_BATCH_MAX_FRAMES * 8];
	size_t len = 0;
	attachment[0] = ZN_ATTACHMENT_VERSION;
	attachment[1] = 0;
	put_u16_le(attachment + 2, (uint16_t)n);
	put_u64_le(attachment + 4, frames[0].seq);
	for (size_t i = 0; i < n; i++) {
		if (zenoh_serialize_can_msg(&frames[i].msg, payload + len, sizeof(payload) - len) < 0) {
			COUNT(b->n.publish_errors); /* the CAN port never hands over such a frame */
			return;
		}
		len += ZENOH_CAN_WIRE_SIZE;
		put_u64_le(attachment + ZN_ATTACHMENT_HEADER + 8 * i, (uint64_t)frames[i].rx_time_ns);
	}
	if (put_sample(b, payload, len, attachment, ZN_ATTACHMENT_HEADER + 8 * n) == 0) {
		COUNT(b->n.published_samples);
		COUNT_N(b->n.published_frames, n);
	} else {
		COUNT(b->n.publish_errors);
	}
	if (b->ros_pub)
		publish_ros2(b, frames, n);
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

static void publisher_thread(void *arg)
{
	struct bus *b = arg;
	static_assert(ZN_BATCH_MAX_FRAMES >= PUBLISH_CHUNK, "chunk fits the batch buffer");
	struct rx_entry *taken = malloc(ZN_BATCH_MAX_FRAMES * sizeof(*taken));
	if (!taken) {
		zn_log("E", "%s: out of memory for the publisher", b->name);
		return;
	}
	uint32_t period_ms = node.cfg.publish_period_ms;
	size_t batch_max = period_ms ? node.cfg.batch_max_frames : 1;
	int64_t next_flush = zn_monotonic_ns() + (int64_t)period_ms * 1000000;
	for (;;) {
		zn_mutex_lock(b->lock);
		if (period_ms == 0) {
			while (b->len == 0 && !node.stopping)
				zn_cond_wait(b->nonempty, b->lock, -1);
		} else {
			/* wait for the period to end, unless a full batch is already there */
			while (!node.stopping && b->len < batch_max) {
				int64_t left_ms = (next_flush - zn_monotonic_ns()) / 1000000;
				if (left_ms <= 0)
					break;
				zn_cond_wait(b->nonempty, b->lock, (int)left_ms);
			}
			if (zn_monotonic_ns() >= next_flush)
				next_flush += (int64_t)period_ms * 1000000 *
					      (1 + (zn_monotonic_ns() - next_flush) / ((int64_t)period_ms * 1000000));
		}
		int stopping = node.stopping;
		size_t n = take(b, taken, period_ms ? batch_max : PUBLISH_CHUNK);
		zn_mutex_unlock(b->lock);
		if (n)
			publish_runs(b, taken, n, batch_max);
		if (stopping && n == 0)
			break; /* queue flushed */
	}
	free(taken);
}

static int stop_wait(int timeout_ms)
{
	zn_mutex_lock(node.stop_lock);
	if (!node.stopping)
		zn_cond_wait(node.stop_cond, node.stop_lock, timeout_ms);
	int stopping = node.stopping;
	zn_mutex_unlock(node.stop_lock);
	return stopping;
}

static void reader_thread(void *arg)
{
	struct bus *b = arg;
	int backoff_ms = CAN_REOPEN_MIN_MS;
	while (!node.stopping) {
		can_message_t msg;
		int64_t rx_time_ns;
		esp_err_t rc = zn_can_receive(b->can, &msg, &rx_time_ns, CAN_RECEIVE_TIMEOUT_MS);
		if (rc == ESP_OK) {
			zenoh_node_submit(b->index, &msg, rx_time_ns);
			backoff_ms = CAN_REOPEN_MIN_MS;
			continue;
		}
		if (rc == ESP_ERR_TIMEOUT)
			continue;
		/* bus gone (interface down, userspace hub restarted): reopen with backoff */
		zn_log("W", "%s: CAN bus lost, reopening in %d ms", b->name, backoff_ms);
		if (stop_wait(backoff_ms))
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

/* ---- Zenoh -> CAN ---- */

static uint16_t get_u16_le(const uint8_t *p)
{
	return (uint16_t)(p[0] | p[1] << 8);
}

static void on_command(const uint8_t *payload, size_t len, const uint8_t *attachment, size_t attachment_len, void *ctx)
{
	struct bus *b = ctx;
	can_message_t msgs[ZN_BATCH_MAX_FRAMES];
	size_t count = 0;
	COUNT(b->n.tx_samples);
	zn_wire_result_t rc = len > sizeof(msgs) / sizeof(msgs[0]) * ZENOH_CAN_WIRE_SIZE
				      ? ZN_WIRE_ERR_LENGTH
				      : zenoh_decode_can_batch(payload, len, msgs, ZN_BATCH_MAX_FRAMES, &count);
	int reason = rc == ZN_WIRE_OK ? 0 : -(int)rc;
	/* an attachment is optional; if present it must describe this payload */
	if (reason == 0 && attachment &&
	    (attachment_len < ZN_ATTACHMENT_HEADER || attachment[0] != ZN_ATTACHMENT_VERSION || attachment[1] != 0 ||
	     get_u16_le(attachment + 2) != count || attachment_len != ZN_ATTACHMENT_HEADER + 8 * count))
		reason = TX_REASON_ATTACHMENT;
	if (reason) {
		/* refused whole: a command is applied completely or not at all */
		if (COUNT(b->n.tx_rejected[reason]) == 0)
			zn_log("W", "%s: refused a command on %s (%s, %zu bytes); further refusals only counted", b->name,
			       b->tx_key, tx_reason_names[reason], len);
		return;
	}
	zn_mutex_lock(b->can_lock);
	for (size_t i = 0; i < count; i++) {
#ifdef ZN_SEEDED_FAULTS
		if (tx_fault(&msgs[i])) {
			COUNT(b->n.tx_frames); /* "written", silently lost */
			continue;
		}
#endif
		if (zn_can_transmit(b->can, &msgs[i], CAN_TRANSMIT_TIMEOUT_MS) == ESP_OK)
			COUNT(b->n.tx_frames);
		else
			COUNT(b->n.can_tx_errors);
	}
	zn_mutex_unlock(b->can_lock);
}

/* ---- stats ---- */

static size_t append(char *buf, size_t cap, size_t off, const char *fmt, ...)
{
	if (off >= cap)
		return off;
	va_list ap;
	va_start(ap, fmt);
	int n = vsnprintf(buf + off, cap - off, fmt, ap);
	va_end(ap);
	return n < 0 ? off : off + (size_t)n;
}

size_t zenoh_node_stats_json(char *buf, size_t cap)
{
	size_t off = 0;
	off = append(buf, cap, off,
		     "{\"node\": \"%s\", \"mode\": \"%s\", \"uptime_ms\": %" PRId64 ", \"connected\": %s, "
		     "\"reconnects\": %" PRIu64 ", \"publish_period_ms\": %" PRIu32 ", \"buses\": [",
		     node.cfg.node_name, mode_names[node.cfg.mode], (zn_monotonic_ns() - node.start_ns) / 1000000,
		     READ(node.connected) ? "true" : "false", READ(node.reconnects), node.cfg.publish_period_ms);
	for (size_t i = 0; i < node.cfg.bus_count; i++) {
		struct bus *b = &node.buses[i];
		off = append(buf, cap, off,
			     "%s{\"bus\": \"%s\", \"rx_key\": \"%s\", \"tx_key\": \"%s\", \"can_rx_frames\": %" PRIu64
			     ", \"filtered\": %" PRIu64 ", \"rx_queue_drops\": %" PRIu64
			     ", \"published_samples\": %" PRIu64 ", \"published_frames\": %" PRIu64
			     ", \"publish_errors\": %" PRIu64 ", \"tx_samples\": %" PRIu64 ", \"tx_frames\": %" PRIu64
			     ", \"can_tx_errors\": %" PRIu64 ", \"can_reopens\": %" PRIu64 ", \"tx_rejected\": {",
			     i ? ", " : "", b->name, b->rx_key, b->tx_key, READ(b->n.can_rx_frames), READ(b->n.filtered),
			     READ(b->n.rx_queue_drops), READ(b->n.published_samples), READ(b->n.published_frames),
			     READ(b->n.publish_errors), READ(b->n.tx_samples), READ(b->n.tx_frames),
			     READ(b->n.can_tx_errors), READ(b->n.can_reopens));
		for (int r = 1; r < TX_REASONS; r++)
			off = append(buf, cap, off, "%s\"%s\": %" PRIu64, r > 1 ? ", " : "", tx_reason_names[r],
				     READ(b->n.tx_rejected[r]));
		off = append(buf, cap, off, "}}");
	}
	off = append(buf, cap, off, "]}");
	if (off >= cap && cap) {
		buf[0] = '\0'; /* never hand out a truncated object */
		return 0;
	}
	return off;
}

static size_t on_stats_query(char *buf, size_t cap, void *ctx)
{
	(void)ctx;
	return zenoh_node_stats_json(buf, cap);
}

/* Counts reconnections: the router set going away and coming back, or
 * changing identity in between two polls (a router restarted quickly). */
static void monitor_thread(void *arg)
{
	(void)arg;
	char ids[512];
	int announced_wait = 0;
	while (!stop_wait(MONITOR_PERIOD_MS)) {
		int routers = zn_routers(node.session, ids, sizeof(ids));
		int connected = routers > 0 || node.cfg.mode != ZN_MODE_CLIENT; /* peers need no router */
		int was_connected = READ(node.connected);
		int replaced = routers > 0 && node.router_ids[0] && strcmp(ids, node.router_ids) != 0;
		if (connected && (!was_connected || replaced)) {
			if (node.ever_connected) {
				COUNT(node.reconnects);
				zn_log("I", "reconnected to the Zenoh router %s%s", ids, replaced ? " (new router id)" : "");
			} else {
				zn_log("I", "connected (%s mode)%s%s", mode_names[node.cfg.mode], routers ? ", router " : "",
				       routers ? ids : "");
			}
			node.ever_connected = 1;
		} else if (!connected && was_connected) {
			zn_log("W", "lost the Zenoh router; retrying %s", node.cfg.router_address);
		} else if (!connected && !node.ever_connected && !announced_wait) {
			zn_log("I", "waiting for the Zenoh router at %s (retrying)", node.cfg.router_address);
			announced_wait = 1;
		}
		if (routers > 0)
			snprintf(node.router_ids, sizeof(node.router_ids), "%s", ids);
		__atomic_store_n(&node.connected, connected, __ATOMIC_RELAXED);
	}
}

/* ---- lifecycle ---- */

static esp_err_t init_bus(struct bus *b, size_t index)
{
	const zenoh_node_config_t *cfg = &node.cfg;
	b->index = index;
	b->name = cfg->buses[index];
	if (cfg->bus_count == 1) {
		snprintf(b->rx_key, sizeof(b->rx_key), "%s/rx", cfg->key_prefix);
		snprintf(b->tx_key, sizeof(b->tx_key), "%s/tx", cfg->key_prefix);
	} else {
		snprintf(b->rx_key, sizeof(b->rx_key), "%s/%s/rx", cfg->key_prefix, b->name);
		snprintf(b->tx_key, sizeof(b->tx_key), "%s/%s/tx", cfg->key_prefix, b->name);
	}
	snprintf(b->token_key, sizeof(b->token_key), "%s/bridges/%s/%s/%s", cfg->key_prefix, cfg->node_name, b->name,
		 mode_names[cfg->mode]);
	b->cap = cfg->rx_queue_frames;
	b->queue = calloc(b->cap, sizeof(*b->queue));
	if (!b->queue)
		return ESP_ERR_NO_MEM;
	ZN_TRY(zn_mutex_new(&b->lock));
	ZN_TRY(zn_mutex_new(&b->can_lock));
	ZN_TRY(zn_cond_new(&b->nonempty));
	if (zn_can_open(b->name, &b->can) != ESP_OK) {
		zn_log("E", "cannot open CAN bus %s", b->name);
		return ESP_FAIL;
	}
	if (zn_declare_publisher(node.session, b->rx_key, &cfg->rx_qos, &b->pub) != 0 ||
	    zn_declare_subscriber(node.session, b->tx_key, on_command, b, &b->sub) != 0) {
		zn_log("E", "cannot declare %s / %s", b->rx_key, b->tx_key);
		return ESP_FAIL;
	}
	if (cfg->ros2_topic[0]) {
		if (cfg->bus_count == 1)
			copy_str(b->ros_topic, sizeof(b->ros_topic), cfg->ros2_topic);
		else
			snprintf(b->ros_topic, sizeof(b->ros_topic), "%s/%s", cfg->ros2_topic, b->name);
		/* <domain>/<topic without the leading '/'>/<DDS type>/<type hash> */
		snprintf(b->ros_key, sizeof(b->ros_key), "%" PRIu32 "/%s/%s/%s", cfg->ros2_domain, b->ros_topic + 1,
			 ZN_ROS2_FRAME_TYPE, ZN_ROS2_FRAME_HASH);
		if (zn_declare_publisher(node.session, b->ros_key, &cfg->rx_qos, &b->ros_pub) != 0) {
			zn_log("E", "cannot declare the ROS 2 publisher %s", b->ros_key);
			return ESP_FAIL;
		}
	}
#ifdef ZN_SEEDED_FAULTS
	if (fault.kind == FAULT_WRONGKEY) {
		char key[ZN_KEY_MAX + 16];
		snprintf(key, sizeof(key), "%s_misrouted", b->rx_key);
		if (zn_declare_publisher(node.session, key, &cfg->rx_qos, &b->misrouted) != 0)
			return ESP_FAIL;
	}
#endif
	return ESP_OK;
}

/* rmw_zenoh's liveliness tokens: the node, and one publisher per bus, so ROS 2 tools
 * list them and subscribers match (docs/viewer.md has the format). */
static esp_err_t declare_ros2_tokens(const zenoh_node_config_t *cfg, const char *zid)
{
	char ros_node[ZN_NAME_MAX], key[2 * ZN_KEY_MAX], topic[ZN_KEY_MAX];
	copy_str(ros_node, sizeof(ros_node), cfg->node_name);
	for (char *c = ros_node; *c; c++)
		if (!isalnum((unsigned char)*c))
			*c = '_'; /* ROS node names: letters, digits, '_' */
	for (int g = 0; g < 16; g++) {
		unsigned v = 0;
		sscanf(zid + 2 * g, "%2x", &v);
		node.gid_seed[g] = (uint8_t)v;
	}
	snprintf(key, sizeof(key), "@ros2_lv/%" PRIu32 "/%s/0/0/NN/%%/%%/%s", cfg->ros2_domain, zid, ros_node);
	if (zn_declare_token(node.session, key, &node.ros_node_token) != 0)
		return ESP_FAIL;
	for (size_t i = 0; i < cfg->bus_count; i++) {
		struct bus *b = &node.buses[i];
		copy_str(topic, sizeof(topic), b->ros_topic);
		for (char *c = topic; *c; c++)
			if (*c == '/')
				*c = '%';
		snprintf(key, sizeof(key), "@ros2_lv/%" PRIu32 "/%s/0/%zu/MP/%%/%%/%s/%s/%s/%s/::,10:,:,:,,", cfg->ros2_domain,
			 zid, i + 1, ros_node, topic, ZN_ROS2_FRAME_TYPE, ZN_ROS2_FRAME_HASH);
		if (zn_declare_token(node.session, key, &b->ros_token) != 0)
			return ESP_FAIL;
		zn_log("I", "ROS 2: %s as can_msgs/msg/Frame on %s", b->ros_topic, b->ros_key);
	}
	return ESP_OK;
}

esp_err_t zenoh_node_init(const zenoh_node_config_t *cfg)
{
	char err[256];
	if (node.running)
		return ESP_ERR_INVALID_STATE;
	if (zenoh_node_check_config(cfg, err, sizeof(err)) != ESP_OK) {
		zn_log("E", "invalid configuration: %s", err);
		return ESP_ERR_INVALID_ARG;
	}
	memset(&node, 0, sizeof(node));
	node.cfg = *cfg;
#ifdef ZN_SEEDED_FAULTS
	parse_fault();
#endif
	node.start_ns = zn_monotonic_ns();
	ZN_TRY(zn_mutex_new(&node.stop_lock));
	ZN_TRY(zn_cond_new(&node.stop_cond));

	zn_session_config_t scfg = {
		.mode = cfg->mode,
		.connect = cfg->router_address,
		.listen = cfg->listen,
		.config_file = cfg->zenoh_config_file[0] ? cfg->zenoh_config_file : NULL,
		.compression = cfg->compression,
	};
	if (zn_open(&scfg, &node.session) != 0) {
		zn_log("E", "cannot open the Zenoh session");
		return ESP_FAIL;
	}
	/* the routers we start with: a replacement seen by the first poll is a reconnect */
	int routers = zn_routers(node.session, node.router_ids, sizeof(node.router_ids));
	node.connected = node.ever_connected = routers > 0 || cfg->mode != ZN_MODE_CLIENT;
	if (node.ever_connected)
		zn_log("I", "connected (%s mode)%s%s", mode_names[cfg->mode], routers > 0 ? ", router " : "",
		       routers > 0 ? node.router_ids : "");
	for (size_t i = 0; i < cfg->bus_count; i++)
		ZN_TRY(init_bus(&node.buses[i], i));
	snprintf(node.stats_key, sizeof(node.stats_key), "%s/bridges/%s/stats", cfg->key_prefix, cfg->node_name);
	if (zn_declare_queryable(node.session, node.stats_key, on_stats_query, NULL, &node.stats_q) != 0) {
		zn_log("E", "cannot declare the stats queryable %s", node.stats_key);
		return ESP_FAIL;
	}
	node.running = 1;
	for (size_t i = 0; i < cfg->bus_count; i++) {
		struct bus *b = &node.buses[i];
		ZN_TRY(zn_thread_start(&b->publisher, "zn-pub", publisher_thread, b));
		ZN_TRY(zn_thread_start(&b->reader, "zn-can", reader_thread, b));
	}
	ZN_TRY(zn_thread_start(&node.monitor, "zn-mon", monitor_thread, NULL));
	/* last: the token tells others the bridge forwards both ways from now on */
	for (size_t i = 0; i < cfg->bus_count; i++) {
		struct bus *b = &node.buses[i];
		if (zn_declare_token(node.session, b->token_key, &b->token) != 0) {
			zn_log("E", "cannot declare the liveliness token %s", b->token_key);
			return ESP_FAIL;
		}
		zn_log("I", "bridging %s: CAN -> %s, %s -> CAN (token %s)", b->name, b->rx_key, b->tx_key, b->token_key);
	}
	char zid[64] = "";
	zn_session_id(node.session, zid, sizeof(zid));
	if (cfg->ros2_topic[0] && declare_ros2_tokens(cfg, zid) != ESP_OK)
		return ESP_FAIL;
	zn_log("I", "ready: zid %s, mode %s, publish period %" PRIu32 " ms, stats on %s", zid, mode_names[cfg->mode],
	       cfg->publish_period_ms, node.stats_key);
	return ESP_OK;
}

void zenoh_node_stop(void)
{
	if (!node.running)
		return;
	/* withdraw the tokens first: nobody should send commands to a bridge on its way out */
	for (size_t i = 0; i < node.cfg.bus_count; i++) {
		if (node.buses[i].token) {
			zn_undeclare_token(node.buses[i].token);
			node.buses[i].token = NULL;
		}
		if (node.buses[i].ros_token) {
			zn_undeclare_token(node.buses[i].ros_token);
			node.buses[i].ros_token = NULL;
		}
	}
	if (node.ros_node_token) {
		zn_undeclare_token(node.ros_node_token);
		node.ros_node_token = NULL;
	}
	zn_mutex_lock(node.stop_lock);
	node.stopping = 1;
	zn_cond_signal(node.stop_cond);
	zn_mutex_unlock(node.stop_lock);
	for (size_t i = 0; i < node.cfg.bus_count; i++) {
		struct bus *b = &node.buses[i];
		zn_thread_join(b->reader);
		zn_mutex_lock(b->lock);
		zn_cond_signal(b->nonempty);
		zn_mutex_unlock(b->lock);
		zn_thread_join(b->publisher); /* flushes the pending batch */
	}
	zn_thread_join(node.monitor);
	for (size_t i = 0; i < node.cfg.bus_count; i++) {
		struct bus *b = &node.buses[i];
		zn_undeclare_subscriber(b->sub);
		zn_undeclare_publisher(b->pub);
		if (b->ros_pub)
			zn_undeclare_publisher(b->ros_pub);
#ifdef ZN_SEEDED_FAULTS
		zn_undeclare_publisher(b->misrouted);
#endif
	}
	zn_undeclare_queryable(node.stats_q);
	char *stats = malloc(STATS_JSON_MAX);
	if (stats && zenoh_node_stats_json(stats, STATS_JSON_MAX))
		zn_log("I", "final stats: %s", stats);
	free(stats);
	zn_close(node.session);
	for (size_t i = 0; i < node.cfg.bus_count; i++) {
		struct bus *b = &node.buses[i];
		zn_can_close(b->can);
		free(b->queue);
		zn_cond_free(b->nonempty);
		zn_mutex_free(b->lock);
		zn_mutex_free(b->can_lock);
	}
	zn_cond_free(node.stop_cond);
	zn_mutex_free(node.stop_lock);
	node.running = 0;
}
