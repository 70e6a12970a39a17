/* zn_port_zenoh.h - contract of the Zenoh port: the few Zenoh operations
 * zenoh-node uses. Linux: ports/linux/zenoh_rust (the official zenoh crate);
 * ESP32 (planned): ports/esp32/zenoh_pico.c; tests: ports/mock/zenoh_mock.c.
 * All functions return 0 on success, a negative value on failure. Callbacks
 * run on the port's threads and must not block for long. */
#ifndef ZN_PORT_ZENOH_H
#define ZN_PORT_ZENOH_H

#include <stddef.h>
#include <stdint.h>

typedef struct zn_session zn_session_t;
typedef struct zn_publisher zn_publisher_t;
typedef struct zn_subscriber zn_subscriber_t;
typedef struct zn_token zn_token_t;
typedef struct zn_queryable zn_queryable_t;

typedef enum { ZN_MODE_CLIENT = 0, ZN_MODE_PEER = 1, ZN_MODE_ROUTER = 2 } zn_mode_t;

typedef struct {
	zn_mode_t mode;
	const char *connect;	 /* comma-separated endpoints, may be empty */
	const char *listen;	 /* comma-separated endpoints, may be empty */
	const char *config_file; /* optional JSON5 file applied first (TLS, auth, ...) */
	int compression;	 /* 1 = compress the transport (negotiated: used when the peer agrees) */
	size_t rx_message_max;	 /* largest message reassembled from fragments (bytes); larger ones are
				    dropped by the port, never buffered whole. 0 = the port's default */
	int low_latency;	 /* 1 = Zenoh's low-latency transport (no QoS: negotiated, used when the
				    router agrees); a port without such a transport (the planned ESP32
				    zenoh-pico one) must refuse it as a configuration error */
} zn_session_config_t;

/* zn_open's result when the configuration cannot work (invalid, or a file it
 * names cannot be read): no retry would heal it. Any other failure is -1. */
#define ZN_PORT_ERR_CONFIG (-2)
#define ZN_PORT_UNROUTED 1

typedef enum { ZN_CONGESTION_DROP = 0, ZN_CONGESTION_BLOCK = 1 } zn_congestion_t;

typedef struct {
	uint8_t priority; /* 1 (real time) .. 7 (background), Zenoh's scale */
	zn_congestion_t congestion;
	uint8_t express; /* 1 = send at once, never batched by Zenoh */
	uint8_t best_effort; /* 1 = best effort, 0 = reliable (Zenoh's default) */
} zn_qos_t;

/* source_time_ns: the sample's Zenoh timestamp (its publisher's HLC, or the
 * first router's when the publisher has none) in ns since the Unix epoch;
 * 0 when the sample carries no timestamp. */
typedef void (*zn_sample_cb)(const uint8_t *payload, size_t len, const uint8_t *attachment, size_t attachment_len,
			     uint64_t source_time_ns, void *ctx);
/* Writes the reply into buf (at most cap bytes) and returns its length; a length
 * of cap or more means it did not fit, and the port calls again with a buffer of
 * at least length + 1 bytes (snprintf's contract). */
typedef size_t (*zn_query_cb)(char *buf, size_t cap, void *ctx);

/* Opens a session. In client mode it retries until the router answers (with a
 * logged backoff), unless the configuration cannot work (ZN_PORT_ERR_CONFIG,
 * reason logged). Multicast scouting is always off; endpoints are explicit. */
int zn_open(const zn_session_config_t *config, zn_session_t **out);
int zn_declare_publisher(zn_session_t *s, const char *key, const zn_qos_t *qos, zn_publisher_t **out);
/* 0: handed to Zenoh. ZN_PORT_UNROUTED: handed to Zenoh while the session had
 * no connection to a router or peer at all, so it went nowhere (Zenoh's put
 * returns Ok; a connection that failed an instant ago may still count as open,
 * and one refused as it opened does until the second zn_poll_connections
 * after it). */
int zn_put(zn_publisher_t *pub, const uint8_t *payload, size_t len, const uint8_t *attachment, size_t attachment_len);
/* Until zn_batch_stop, the puts this thread makes add their samples to their
 * link's batch without writing it, so a burst of samples leaves as one write
 * where each would have been its own. No put waits for the stop: a batch that
 * fills or an express sample leaves at once, and another thread's write takes
 * what is held along. Call them in pairs around puts made back to back; the
 * node calls them from several threads at once (a bus's reader and publisher),
 * zn_batch_start with a lock held: it must not block. Linux: held per thread,
 * whatever the session. A port whose batching is per session (zenoh-pico's
 * zp_batch_start/stop, the planned ESP32 port) counts the starts and flushes at
 * the last stop; a port without batching makes them no-ops. */
void zn_batch_start(zn_session_t *s);
void zn_batch_stop(zn_session_t *s);
int zn_declare_subscriber(zn_session_t *s, const char *key, zn_sample_cb cb, void *ctx, zn_subscriber_t **out);
int zn_declare_token(zn_session_t *s, const char *key, zn_token_t **out);
int zn_declare_queryable(zn_session_t *s, const char *key, zn_query_cb cb, void *ctx, zn_queryable_t **out);
/* Routers this session is connected to right now: returns their number and
 * writes their Zenoh ids, sorted and comma separated, into ids. A restarted
 * router has a new id, so a restart faster than any poll is still seen. */
int zn_routers(zn_session_t *s, char *ids, size_t cap);
/* Drops from the connections zn_put counts one Zenoh announced before the
 * previous call and since neither accepted nor closed (it refused it as it
 * opened): Zenoh tells no event for it. Call it at the open and periodically
 * (the node: at start, then the monitor every 500 ms). */
void zn_poll_connections(zn_session_t *s);
/* Connections (Zenoh transports) of this session to a router or peer that
 * closed since it opened (the router's end, a failed write, a lost lease):
 * Zenoh opens a new one within milliseconds, and samples put while none was
 * up are lost though their put succeeded. */
uint64_t zn_connections_closed(zn_session_t *s);
/* The session's Zenoh id as hex, for logs. */
int zn_session_id(zn_session_t *s, char *buf, size_t cap);

void zn_undeclare_publisher(zn_publisher_t *pub);
void zn_undeclare_subscriber(zn_subscriber_t *sub);
void zn_undeclare_token(zn_token_t *token);
void zn_undeclare_queryable(zn_queryable_t *q);
void zn_close(zn_session_t *s);

#endif
