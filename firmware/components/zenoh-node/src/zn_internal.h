/* zn_internal.h - state shared by the component's files (not part of its API):
 * the node, its buses, and the per-bus counters the stats report. */
#ifndef ZN_INTERNAL_H
#define ZN_INTERNAL_H

#include <stdint.h>

#include "zn_node.h"
#include "zn_port_can.h"
#include "zn_port_os.h"
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

/* A frame waiting for the transmitter, with the number of the command it came in. */
struct tx_entry {
	can_message_t msg;
	uint32_t cmd;
};

struct bus_counters {
	uint64_t can_rx_frames, filtered, invalid_frames, rx_queue_drops;
	uint64_t published_samples, published_frames, publish_errors;
	uint64_t tx_samples, tx_frames, can_tx_errors, tx_queue_full, tx_abandoned;
	uint64_t tx_rejected[ZN_WIRE_REASONS];
	uint64_t can_reopens;
};

struct bus {
	size_t index;
	const char *name;
	char rx_key[ZN_KEY_MAX], tx_key[ZN_KEY_MAX], token_key[ZN_KEY_MAX];
	zn_can_t *can;
	zn_mutex_t *can_lock; /* the reader reopens the port; the transmitter transmits on it */
	zn_publisher_t *pub;
	zn_subscriber_t *sub;
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
	uint8_t *payload, *attachment; /* the publisher's sample being built (batch_max_frames) */
	/* tx queue: ring of tx_entry filled by the subscriber callback, drained by the
	 * transmitter thread; guarded by tx_lock */
	zn_mutex_t *tx_lock;
	zn_cond_t *tx_ready, *tx_idle;
	struct tx_entry *txq;
	uint32_t tx_cap, tx_head, tx_len, tx_cmd;
	int tx_stop;
	zn_thread_t *transmitter;
	int cb_inflight, cb_closed; /* atomics: callbacks inside the gate; gate closed (zn_tx_close) */
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
	int connected, ever_connected;
	char router_ids[512]; /* routers at the last poll; written by init, then by the monitor only */
	uint8_t gid_seed[16]; /* from the session id: ROS 2 GIDs */
	zn_token_t *ros_node_token;
};

extern struct node zn_node;
extern const char *const zn_mode_names[3];

/* Waits up to timeout_ms for zn_node_stop; returns whether it was called. */
int zn_stop_wait(int timeout_ms);

/* zn_rx.c: the CAN reader and the publisher of one bus */
void zn_rx_reader_thread(void *bus);
void zn_rx_publisher_thread(void *bus);

/* zn_tx.c: the subscriber callback of one bus's tx key, queueing commands
 * whole for the transmitter thread. zn_tx_close undeclares the subscriber and
 * returns once no callback is inside the queue any more. */
void zn_tx_on_command(const uint8_t *payload, size_t len, const uint8_t *attachment, size_t attachment_len,
		      uint64_t source_time_ns, void *bus);
void zn_tx_transmitter_thread(void *bus);
void zn_tx_close(struct bus *b);

/* zn_stats.c */
void zn_stats_monitor_thread(void *arg);
size_t zn_stats_on_query(char *buf, size_t cap, void *ctx);

/* zn_ros2.c: the ROS 2 output (keys, tokens, samples) */
esp_err_t zn_ros2_declare_bus(struct bus *b);
esp_err_t zn_ros2_declare_tokens(const char *zid);
void zn_ros2_publish(struct bus *b, const struct rx_entry *frames, size_t n);

#endif
