/* zn_internal.h - state shared by the component's files (not part of its API):
 * the node, its buses, and the per-bus counters the stats report. */
#ifndef ZN_INTERNAL_H
#define ZN_INTERNAL_H

#include <stdint.h>

#include "zn_gate.h"
#include "zn_node.h"
#include "zn_port_can.h"
#include "zn_port_os.h"
#include "zn_qos.h"
#include "zn_wire.h"

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

/* A frame waiting for the transmitter: one slot of the transmit queue's pool,
 * chained to the next frame of its command (or of the free list). */
#define ZN_TX_NONE UINT32_MAX
struct tx_entry {
	can_message_t msg;
	uint32_t next;
};

/* A command waiting for the transmitter, in a binary heap ordered by the CAN
 * arbitration key of its first frame (lowest first, as the bus arbitrates),
 * then by arrival (FIFO among equals). */
struct tx_cmd {
	uint32_t key, order; /* arbitration key (zn_tx_arbitration_key); arrival number */
	uint32_t first, count; /* its first slot in txq; its frames */
	int64_t source_ns;     /* source time (ns since the epoch), 0 = none */
};

struct bus_counters {
	uint64_t can_rx_frames, filtered, invalid_frames, rx_queue_drops;
	uint64_t published_samples, published_frames, publish_errors;
	uint64_t unrouted_frames; /* put with no connection open: went nowhere (ZN_PORT_UNROUTED) */
	uint64_t tx_samples, tx_frames, can_tx_errors, tx_queue_full, tx_abandoned;
	uint64_t tx_rejected[ZN_WIRE_REASONS];
	uint64_t can_reopens;
	uint64_t direct_frames, direct_stalls; /* immediate mode: frames the reader put itself; its puts that stalled */
	uint64_t tx_rejected_stale, tx_unstamped; /* freshness (tx_max_age_ms): refused as stale; no source time */
	uint64_t tx_rejected_future; /* refused: stamped further ahead of this clock than tx_max_age_ms */
	uint64_t tx_direct_frames; /* frames Zenoh's callback wrote itself (zn_tx.c, Direct writes) */
};

struct bus {
	size_t index;
	const char *name;
	char rx_key[ZN_KEY_MAX], tx_key[ZN_KEY_MAX], token_key[ZN_KEY_MAX];
	zn_can_t *can;
	zn_mutex_t *can_lock; /* the reader reopens the port; the transmitter or a direct write transmits on it */
	zn_publisher_t *pub[ZN_MAX_QOS_CLASSES]; /* CAN -> Zenoh, one per QoS class of qos, all on rx_key */
	zn_subscriber_t *sub;
	zn_token_t *token;
	/* ROS 2 output (cfg.ros2_topic): can_msgs/msg/Frame on the rmw_zenoh data key */
	char ros_topic[ZN_KEY_MAX], ros_key[ZN_KEY_MAX];
	zn_publisher_t *ros_pub;
	zn_token_t *ros_token;
	uint64_t ros_seq;
	zn_thread_t *reader, *publisher;
	/* rx queues (ring), guarded by lock */
	zn_mutex_t *lock;
	zn_cond_t *nonempty;
	/* one ring of rx_entry per QoS class (cap each); queued: frames in all of them */
	struct rx_ring {
		struct rx_entry *queue;
		uint32_t cap, head, len;
		uint64_t published_frames, drops; /* counters of this class */
	} ring[ZN_MAX_QOS_CLASSES];
	uint32_t queued;
	/* immediate mode, the reader's own put (zn_rx.c, Direct puts); all guarded by lock.
	 * direct: the reader is publishing (its put started at direct_since, monotonic ns);
	 * publishing: the publisher is; degraded: a put stalled, the reader hands over until the
	 * publisher caught up; watching: the publisher polls for a stalled put (direct_puts: the
	 * reader's count, to see when its puts have stopped); rescuing: the publisher reads the
	 * CAN port meanwhile, reader_back: the reader returned and waits on handback */
	int direct, publishing, degraded, watching, rescuing, reader_back;
	int long_stall_said; /* a put stalled 1 s was logged (once) */
	int reader_gone;     /* stopping: the reader has been joined, so nothing more is queued */
	int64_t direct_since, publish_since; /* ... and the publisher's current round started then */
	uint64_t direct_puts;
	zn_cond_t *handback;
	zn_qos_table_t qos; /* cfg.rx_qos_table over cfg.rx_qos */
	uint64_t next_seq;
	uint8_t *payload, *attachment; /* the publisher's sample being built (batch_max_frames) */
	/* tx queue: a pool of tx_cap frame slots (free list from tx_free) and a heap
	 * of the commands waiting (tx_heap, tx_waiting), filled by the subscriber
	 * callback, drained by the transmitter thread; guarded by tx_lock. tx_len:
	 * slots in use (waiting, or being written) */
	zn_mutex_t *tx_lock;
	zn_cond_t *tx_ready, *tx_idle;
	struct tx_entry *txq;
	struct tx_cmd *tx_heap;
	uint32_t tx_cap, tx_len, tx_free, tx_waiting, tx_order;
	int tx_stop;
	/* direct writes (zn_tx.c): a callback is writing (tx_direct); tx_burst: the burst buffer of
	 * whichever writes (the callback or the transmitter: never both at once, off the stack);
	 * the rest of its command the bus did not take at once, the transmitter's next (count 0: none) */
	int tx_direct;
	can_message_t *tx_burst;
	struct tx_cmd *tx_group; /* the transmitter's commands of one burst (zn_tx.c, Queued commands together) */
	uint32_t tx_solo;	 /* commands to write alone after a group the bus took none of */
	struct tx_cmd tx_rest;
	int tx_failed; /* the transmitter's last command failed and no frame went since: at stop, what the bus takes at once */
	zn_thread_t *transmitter;
	struct bus_counters n;
};

struct node {
	zn_node_config_t cfg;
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
	uint64_t connections_seen_closed; /* zn_connections_closed at the monitor's last poll: the monitor's only */
	int connected, ever_connected;
	char router_ids[512]; /* routers at the last poll; written by init, then by the monitor only */
	uint8_t gid_seed[16]; /* from the session id: ROS 2 GIDs */
	zn_token_t *ros_node_token;
};

extern struct node zn_node;

/* The callbacks' gates (zn_gate.h): the command callback's per bus (zn_tx_close shuts it), the
 * stats callback's. Outside zn_node, whose resets (init, release) would open them for an instant
 * to a callback Zenoh runs that late; shut from init until start has succeeded (a command is
 * not taken before the bridge is ready, its token) and from stop on. */
extern struct zn_gate zn_cb_gates[ZN_MAX_BUSES], zn_stats_gate;

/* Commands each bus's callback found its gate shut to (tx_refused_closed): counted beside the gates,
 * not in the bus's counters, which init and release reset under such a callback. Zeroed by init. */
extern uint64_t zn_tx_refused_closed[ZN_MAX_BUSES];

static inline struct zn_gate *zn_cb_gate(const struct bus *b)
{
	return &zn_cb_gates[b - zn_node.buses];
}
extern const char *const zn_mode_names[3];

/* Waits up to timeout_ms for zn_node_stop; returns whether it was called. */
int zn_stop_wait(int timeout_ms);

/* zn_rx.c: the CAN reader and the publisher of one bus */
void zn_rx_reader_thread(void *bus);
void zn_rx_publisher_thread(void *bus);
/* The QoS table parsed (validated before), a queue per class allocated; their publishers
 * declared; undeclared; the queues freed (each safe on what init left NULL). */
esp_err_t zn_rx_queue_init(struct bus *b);
int zn_rx_declare(struct bus *b);
void zn_rx_undeclare(struct bus *b);
void zn_rx_queue_free(struct bus *b);
/* For the stats: frames queued now, and how long the put running now has run (ms, 0: none). */
void zn_rx_gauges(struct bus *b, uint32_t *queued, int64_t *put_running_ms);

/* zn_tx.c: the subscriber callback of one bus's tx key, writing a command
 * itself when the bus is free or queueing it whole for the transmitter thread. zn_tx_close undeclares the subscriber and
 * returns once no callback is inside the queue any more. */
void zn_tx_on_command(const uint8_t *payload, size_t len, const uint8_t *attachment, size_t attachment_len,
		      uint64_t source_time_ns, void *bus);
void zn_tx_transmitter_thread(void *bus);
void zn_tx_close(struct bus *b);
/* Allocates the transmit queue (cfg.tx_queue_frames slots and as many command places). */
esp_err_t zn_tx_queue_init(struct bus *b, uint32_t frames);
/* The frame's place in CAN arbitration: lower wins the bus (11-bit base id, then
 * SRR/RTR, IDE, the 18 extension bits, RTR). */
uint32_t zn_tx_arbitration_key(const can_message_t *msg);

/* zn_stats.c */
void zn_stats_monitor_thread(void *arg);
size_t zn_stats_on_query(char *buf, size_t cap, void *ctx);
/* The stats JSON in a buffer of its size (malloc'd; NULL when out of memory). */
char *zn_stats_json_alloc(void);

/* zn_ros2.c: the ROS 2 output (keys, tokens, samples) */
esp_err_t zn_ros2_declare_bus(struct bus *b);
esp_err_t zn_ros2_declare_tokens(const char *zid);
void zn_ros2_publish(struct bus *b, const struct rx_entry *frames, size_t n);

#endif
