/* zn_mock.h - test doubles for the CAN and Zenoh ports: in-memory buses and a
 * recording Zenoh, so unit tests run the component without I/O. */
#ifndef ZN_MOCK_H
#define ZN_MOCK_H

#include <pthread.h>
#include <stddef.h>
#include <stdint.h>
#include <time.h>

#include "driver/can.h"
#include "zn_port_zenoh.h"

#define MOCK_MAX_PUTS 4096
#define MOCK_PAYLOAD_MAX 16384
#define MOCK_ATTACHMENT_MAX 8300

struct mock_put {
	char key[256];
	uint8_t payload[MOCK_PAYLOAD_MAX];
	size_t len;
	uint8_t attachment[MOCK_ATTACHMENT_MAX];
	size_t attachment_len;
	int publisher; /* which declared publisher made it (mock_zenoh_publisher) */
	unsigned batch; /* the zn_batch_start its thread made it under, numbered from 1 (0: none) */
};

/* A publisher as declared: its key and QoS, in declaration order since mock_reset. */
struct mock_publisher {
	char key[256];
	zn_qos_t qos;
};

void mock_reset(void);

/* CLOCK_REALTIME deadline timeout_ms from now, for pthread_cond_timedwait. */
static inline struct timespec mock_deadline(int timeout_ms)
{
	struct timespec ts;
	clock_gettime(CLOCK_REALTIME, &ts);
	ts.tv_sec += timeout_ms / 1000;
	ts.tv_nsec += (long)(timeout_ms % 1000) * 1000000;
	if (ts.tv_nsec >= 1000000000) {
		ts.tv_sec++;
		ts.tv_nsec -= 1000000000;
	}
	return ts;
}

/* CAN */
void mock_can_inject(const char *bus, const can_message_t *msg, int64_t rx_time_ns);
size_t mock_can_tx_count(const char *bus);
/* Waits until at least n frames were transmitted on bus; returns the count. */
size_t mock_can_wait_tx(const char *bus, size_t n, int timeout_ms);
/* A stalled bus takes no frame: zn_can_transmit waits its timeout and fails (as a
 * controller whose bus is busy or has no acknowledging node). MOCK_HOLD: it
 * waits, whatever its timeout, until the stall is lifted (0); a caller that may
 * not wait (timeout 0) is told ESP_ERR_TIMEOUT at once. */
enum { MOCK_HOLD = 2 };
void mock_can_stall(const char *bus, int stalled);
/* The bus takes `frames` more frames, then none (a full controller queue): as
 * MOCK_HOLD, a caller that may wait waits until given room again, one that may
 * not is told ESP_ERR_TIMEOUT; -1: no limit (the default). */
void mock_can_tx_room(const char *bus, long frames);
/* Waits until n burst sends (zn_can_send_burst with a timeout) wait for the bus, held or stalled;
 * returns how many do. */
size_t mock_can_wait_tx_held(const char *bus, size_t n, int timeout_ms);
/* The stall ends just too late for the burst sends waiting now: they fail as though their timeout
 * had passed, and the bus takes every frame from now on (neither stalled nor limited). Returns how
 * many sends it failed. */
size_t mock_can_stall_ends(const char *bus);
/* Was transmitted frame i written by this thread? */
int mock_can_tx_by(const char *bus, size_t i, pthread_t thread);
/* The bus goes away under its open handles (hub restarted, interface down): they fail from
 * now on; a zn_can_open after this gets a working handle again. */
void mock_can_lose(const char *bus);
can_message_t mock_can_tx(const char *bus, size_t i);
/* n frames arriving at once (stamps first_rx_time_ns + i): a reader wakes once for them. */
void mock_can_inject_burst(const char *bus, const can_message_t *msgs, size_t n, int64_t first_rx_time_ns);
/* The port holds at most this many received frames; injected ones beyond are dropped. */
void mock_can_set_capacity(const char *bus, size_t frames);
size_t mock_can_rx_drops(const char *bus);
/* Receive calls that returned frames (zn_can_receive or _burst); transmit calls that sent. */
size_t mock_can_reads(const char *bus);
size_t mock_can_tx_calls(const char *bus);
/* Waits until n transmit calls with a timeout of 0 took no frame (a full bus); returns how many did. */
size_t mock_can_wait_tx_empty(const char *bus, size_t n, int timeout_ms);
/* Waits until a receive call waits for a frame on bus (a reader back at its port); returns whether one does. */
int mock_can_wait_receiving(const char *bus, int timeout_ms);

/* Zenoh */
size_t mock_zenoh_put_count(void);
const struct mock_put *mock_zenoh_put(size_t i);
/* Waits until at least n puts were made; returns the count (explicit readiness, no sleeps). */
size_t mock_zenoh_wait_puts(size_t n, int timeout_ms);
/* Delivers a sample to the subscriber on key, as the network would. */
/* As mock_zenoh_deliver, with the sample's Zenoh timestamp (ns since the epoch, 0 = none). */
int mock_zenoh_deliver_at(const char *key, const uint8_t *payload, size_t len, const uint8_t *attachment,
			  size_t attachment_len, uint64_t source_time_ns);
int mock_zenoh_deliver(const char *key, const uint8_t *payload, size_t len, const uint8_t *attachment,
		       size_t attachment_len);
int mock_zenoh_has_token(const char *key);
size_t mock_zenoh_publisher_count(void);
const struct mock_publisher *mock_zenoh_publisher(size_t i);
/* What the next zn_open returns (0, -1, ZN_PORT_ERR_CONFIG); mock_reset sets 0. */
void mock_zenoh_open_result(int rc);
/* A connection of the session closed (and was replaced): zn_connections_closed counts it. */
void mock_zenoh_close_connection(void);
/* 1: the session has no connection; puts are recorded and answered ZN_PORT_UNROUTED. */
void mock_zenoh_unrouted(int on);
/* zn_batch_start calls nested in another, and zn_batch_stop calls without one, since mock_reset. */
unsigned mock_zenoh_batch_misuse(void);
/* Once: the next subscriber declared on key gets this command at once, from within its
 * declaration (a command that arrives while the node starts). */
void mock_zenoh_deliver_on_declare(const char *key, const uint8_t *payload, size_t len);
/* The session configuration of the last zn_open. */
zn_session_config_t mock_zenoh_last_open(void);
/* Queries a declared queryable: the reply's length, NUL-terminated in buf; 0 and "" when
 * none answers or the reply does not fit in cap. */
size_t mock_zenoh_query(const char *key, char *buf, size_t cap);

#endif
