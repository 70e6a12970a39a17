/* faults.c - seeded faults: a broken bridge on purpose, so the bench can prove
 * each of its checks fails for the fault it exists for. A port that wraps the
 * real ones (linker --wrap of zn_declare_publisher, zn_put,
 * zn_undeclare_publisher, zn_can_transmit, zn_can_send_burst, zn_declare_subscriber and
 * zn_batch_start/stop), linked only into the
 * zenoh-node-faulty test executable: the component itself has no fault code.
 *
 * ZN_FAULT=<kind>[:<n>] selects one, on the CAN -> Zenoh samples (the
 * publishers of the .../rx keys):
 *   drop:N   drop every Nth sample          dup:N    publish every Nth sample twice
 *   swap:N   publish every Nth sample after the one that follows it
 *   flip:N   flip the lowest bit of data byte 0 of every Nth sample
 *   flip:N@BYTE.BIT  flip bit BIT (0 = lowest) of data byte BYTE (both 0..7) in every
 *            Nth frame that has that byte (a data frame with dlc > BYTE), counted
 *            frame by frame through batches, per publisher: one bit inside one
 *            signal, which a signal check can see (byte 0 bit 0 is often a counter's)
 *   delay:MS hold every sample MS ms        wrongkey publish on <rx key>_misrouted
 *   jitter:MS hold every sample 0..MS ms past its CAN receive time, a different hold each
 *            (pseudo-random, the same sequence every run), in order: the gaps a consumer
 *            sees spread while the median cycle and latency barely move
 * and on the Zenoh -> CAN path:
 *   txdrop:N never write every Nth command (reported written)
 *   txflip:N flip the lowest bit of data byte 0 of every Nth
 *   no-freshness  ignore the deadline (tx_max_age_ms): every command reaches the
 *            component without its source times (attachment times and Zenoh
 *            timestamp 0), so it is never refused as stale (counted unstamped) */
#define _GNU_SOURCE
#include <ctype.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "zn_node.h"
#include "zn_port_can.h"
#include "zn_port_os.h"
#include "zn_port_zenoh.h"
#include "zn_wire.h"

int __real_zn_declare_publisher(zn_session_t *s, const char *key, const zn_qos_t *qos, zn_publisher_t **out);
int __real_zn_put(zn_publisher_t *pub, const uint8_t *payload, size_t len, const uint8_t *attachment,
		  size_t attachment_len);
void __real_zn_undeclare_publisher(zn_publisher_t *pub);
esp_err_t __real_zn_can_transmit(zn_can_t *can, const can_message_t *msg, int timeout_ms);
int __real_zn_declare_subscriber(zn_session_t *s, const char *key, zn_sample_cb cb, void *ctx, zn_subscriber_t **out);
void __real_zn_batch_start(zn_session_t *s);
void __real_zn_batch_stop(zn_session_t *s);

int __wrap_zn_declare_publisher(zn_session_t *s, const char *key, const zn_qos_t *qos, zn_publisher_t **out);
int __wrap_zn_put(zn_publisher_t *pub, const uint8_t *payload, size_t len, const uint8_t *attachment,
		  size_t attachment_len);
void __wrap_zn_undeclare_publisher(zn_publisher_t *pub);
esp_err_t __wrap_zn_can_transmit(zn_can_t *can, const can_message_t *msg, int timeout_ms);
int __wrap_zn_declare_subscriber(zn_session_t *s, const char *key, zn_sample_cb cb, void *ctx, zn_subscriber_t **out);
void __wrap_zn_batch_start(zn_session_t *s);
void __wrap_zn_batch_stop(zn_session_t *s);

enum kind { NONE, DROP, DUP, SWAP, FLIP, DELAY, WRONGKEY, TXDROP, TXFLIP, NOFRESH, JITTER, KINDS };
static const char *const names[KINDS] = { "", "drop", "dup", "swap", "flip", "delay", "wrongkey", "txdrop", "txflip",
					  "no-freshness", "jitter" };

static struct {
	pthread_once_t once;
	enum kind kind;
	unsigned n, tx_count;
	int flip_byte; /* flip:N@BYTE.BIT: the byte (0..7) and its bit as a mask; -1: flip:N */
	uint8_t flip_mask;
} fault = { .once = PTHREAD_ONCE_INIT, .flip_byte = -1 };

/* The handle the component holds: the real publisher, and for the rx keys
 * what a fault needs (a second publisher, a sample held back). */
struct faulty_pub {
	zn_publisher_t *real, *misrouted;
	int faulted; /* an rx key: the CAN -> Zenoh faults apply */
	uint64_t count, frames; /* samples; frames that have the flip:N@BYTE.BIT byte */
	uint8_t held[ZN_BATCH_MAX_FRAMES * ZN_WIRE_FRAME_SIZE], held_att[ZN_ATTACHMENT_SIZE(ZN_BATCH_MAX_FRAMES)];
	size_t held_len, held_att_len;
	uint8_t copy[ZN_BATCH_MAX_FRAMES * ZN_WIRE_FRAME_SIZE];
};

/* "BYTE.BIT" of flip:N@BYTE.BIT, each a decimal 0..7; 0 or -1 (malformed). */
static int parse_flip_at(const char *at)
{
	char *end;
	if (!isdigit((unsigned char)at[0]))
		return -1;
	unsigned long byte = strtoul(at, &end, 10);
	if (*end != '.' || byte > 7 || !isdigit((unsigned char)end[1]))
		return -1;
	unsigned long bit = strtoul(end + 1, &end, 10);
	if (*end != '\0' || bit > 7)
		return -1;
	fault.flip_byte = (int)byte;
	fault.flip_mask = (uint8_t)(1u << bit);
	return 0;
}

static void parse_fault(void)
{
	const char *spec = getenv("ZN_FAULT");
	if (!spec || !*spec)
		return;
	for (int k = 1; k < KINDS; k++) {
		size_t len = strlen(names[k]);
		if (strncmp(spec, names[k], len) == 0 && (spec[len] == ':' || spec[len] == '\0')) {
			char *end = (char *)spec + len;
			fault.n = spec[len] == ':' ? (unsigned)strtoul(spec + len + 1, &end, 10) : 1;
			if (fault.n == 0)
				fault.n = 1;
			if (k == FLIP && *end == '@' && parse_flip_at(end + 1) != 0) {
				zn_log("E", "ZN_FAULT='%s': flip:N@BYTE.BIT wants BYTE and BIT 0..7 (e.g. flip:5@2.7); no fault seeded",
				       spec);
				return;
			}
			fault.kind = (enum kind)k;
			if (fault.flip_byte >= 0)
				zn_log("W", "SEEDED FAULT ACTIVE: %s (n=%u, byte %d mask 0x%02x) - this bridge is broken on purpose",
				       names[k], fault.n, fault.flip_byte, fault.flip_mask);
			else
				zn_log("W", "SEEDED FAULT ACTIVE: %s (n=%u) - this bridge is broken on purpose", names[k], fault.n);
			return;
		}
	}
	zn_log("E",
	       "ZN_FAULT='%s' is not drop|dup|swap|flip|delay|jitter|txdrop|txflip:N, flip:N@BYTE.BIT, wrongkey or "
	       "no-freshness; "
	       "no fault seeded",
	       spec);
}

static int is_rx_key(const char *key)
{
	size_t n = strlen(key);
	return n >= 3 && strcmp(key + n - 3, "/rx") == 0;
}

int __wrap_zn_declare_publisher(zn_session_t *s, const char *key, const zn_qos_t *qos, zn_publisher_t **out)
{
	pthread_once(&fault.once, parse_fault);
	struct faulty_pub *p = calloc(1, sizeof(*p));
	if (!p)
		return -1;
	p->faulted = is_rx_key(key);
	if (__real_zn_declare_publisher(s, key, qos, &p->real) != 0) {
		free(p);
		return -1;
	}
	if (p->faulted && fault.kind == WRONGKEY) {
		char misrouted[ZN_KEY_MAX + 16];
		snprintf(misrouted, sizeof(misrouted), "%s_misrouted", key);
		if (__real_zn_declare_publisher(s, misrouted, qos, &p->misrouted) != 0) {
			__real_zn_undeclare_publisher(p->real);
			free(p);
			return -1;
		}
	}
	*out = (zn_publisher_t *)p;
	return 0;
}

void __wrap_zn_undeclare_publisher(zn_publisher_t *pub)
{
	struct faulty_pub *p = (struct faulty_pub *)pub;
	if (!p)
		return;
	__real_zn_undeclare_publisher(p->real);
	if (p->misrouted)
		__real_zn_undeclare_publisher(p->misrouted);
	free(p);
}

/* The session this thread holds its puts for (zn_batch_start), NULL when it holds none. */
static __thread zn_session_t *holding;

void __wrap_zn_batch_start(zn_session_t *s)
{
	holding = s;
	__real_zn_batch_start(s);
}

void __wrap_zn_batch_stop(zn_session_t *s)
{
	holding = NULL;
	__real_zn_batch_stop(s);
}

/* A pipeline delay, not a throughput cap: hold until CAN receive time + hold_us. The samples this
 * thread holds (zn_batch_start) leave before the wait, each at its own due time, not with the
 * sample after it. */
static void delay_until_due(const uint8_t *att, size_t att_len, int64_t hold_us)
{
	if (att_len < ZN_ATTACHMENT_SIZE(1))
		return;
	int64_t rx_ns = 0;
	for (int i = 7; i >= 0; i--)
		rx_ns = rx_ns << 8 | att[ZN_ATTACHMENT_HEADER + i];
	int64_t due = rx_ns + hold_us * 1000;
	struct timespec ts = { .tv_sec = due / 1000000000, .tv_nsec = due % 1000000000 }, now;
	clock_gettime(CLOCK_REALTIME, &now);
	zn_session_t *release = (int64_t)now.tv_sec * 1000000000 + now.tv_nsec < due ? holding : NULL;
	if (release)
		__real_zn_batch_stop(release);
	while (clock_nanosleep(CLOCK_REALTIME, TIMER_ABSTIME, &ts, NULL) != 0)
		;
	if (release)
		__real_zn_batch_start(release);
}

int __wrap_zn_put(zn_publisher_t *pub, const uint8_t *payload, size_t len, const uint8_t *att, size_t att_len)
{
	struct faulty_pub *p = (struct faulty_pub *)pub;
	if (!p->faulted || fault.kind == NONE || fault.kind == TXDROP || fault.kind == TXFLIP || fault.kind == NOFRESH ||
	    len > sizeof(p->copy) || att_len > sizeof(p->held_att))
		return __real_zn_put(p->real, payload, len, att, att_len);
	int nth = ++p->count % fault.n == 0;
	switch (fault.kind) {
	case DROP:
		return nth ? 0 : __real_zn_put(p->real, payload, len, att, att_len); /* "published", silently lost */
	case DUP:
		if (nth)
			__real_zn_put(p->real, payload, len, att, att_len);
		return __real_zn_put(p->real, payload, len, att, att_len);
	case SWAP:
		if (nth && p->held_len == 0) { /* hold this one back until the next sample is out */
			memcpy(p->held, payload, len);
			memcpy(p->held_att, att, att_len);
			p->held_len = len;
			p->held_att_len = att_len;
			return 0;
		}
		if (__real_zn_put(p->real, payload, len, att, att_len) != 0)
			return -1;
		if (p->held_len) {
			__real_zn_put(p->real, p->held, p->held_len, p->held_att, p->held_att_len);
			p->held_len = 0;
		}
		return 0;
	case FLIP:
		memcpy(p->copy, payload, len);
		if (fault.flip_byte >= 0) { /* flip:N@BYTE.BIT: frame by frame */
			for (size_t off = 0; off + ZN_WIRE_FRAME_SIZE <= len; off += ZN_WIRE_FRAME_SIZE) {
				uint8_t *f = p->copy + off;
				if (f[4] > fault.flip_byte && !(f[5] & ZN_WIRE_FLAG_RTR) && ++p->frames % fault.n == 0)
					f[8 + fault.flip_byte] ^= fault.flip_mask;
			}
		} else if (nth && len >= ZN_WIRE_FRAME_SIZE && p->copy[4] > 0 && !(p->copy[5] & ZN_WIRE_FLAG_RTR))
			p->copy[8] ^= 0x01;
		return __real_zn_put(p->real, p->copy, len, att, att_len);
	case DELAY:
		delay_until_due(att, att_len, (int64_t)fault.n * 1000);
		return __real_zn_put(p->real, payload, len, att, att_len);
	case JITTER: {
		uint64_t x = p->count * 0x9E3779B97F4A7C15ull; /* splitmix64 of the sample's number */
		x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
		x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
		delay_until_due(att, att_len, (int64_t)((x ^ (x >> 31)) % ((uint64_t)fault.n * 1000 + 1)));
		return __real_zn_put(p->real, payload, len, att, att_len);
	}
	case WRONGKEY:
		return __real_zn_put(p->misrouted, payload, len, att, att_len);
	case NONE:
	case TXDROP:
	case TXFLIP:
	case NOFRESH:
	case KINDS:
		break;
	}
	return __real_zn_put(p->real, payload, len, att, att_len);
}

esp_err_t __wrap_zn_can_transmit(zn_can_t *can, const can_message_t *msg, int timeout_ms)
{
	if (fault.kind != TXDROP && fault.kind != TXFLIP)
		return __real_zn_can_transmit(can, msg, timeout_ms);
	/* "every Nth" counts frames the bus takes: a frame refused at once (a callback's
	 * timeout-0 try, docs/bridge.md) is tried again by the transmitter, not counted twice */
	unsigned nth = __atomic_load_n(&fault.tx_count, __ATOMIC_RELAXED) + 1; /* one writer at a time (zn_tx.c) */
	can_message_t out = *msg;
	int faulted = nth % fault.n == 0;
	if (faulted && fault.kind == TXFLIP && out.data_length_code > 0 && !out.rtr)
		out.data[0] ^= 0x01;
	esp_err_t rc = faulted && fault.kind == TXDROP ? ESP_OK /* "written", silently lost */
						       : __real_zn_can_transmit(can, &out, timeout_ms);
	if (rc == ESP_OK)
		__atomic_add_fetch(&fault.tx_count, 1, __ATOMIC_RELAXED);
	return rc;
}

/* Bursts go frame by frame through the wrap above while a Zenoh -> CAN fault is
 * seeded, so "every Nth" counts frames as it did before bursts. */
esp_err_t __real_zn_can_send_burst(zn_can_t *can, const can_message_t *msgs, size_t n, size_t *sent, int timeout_ms);
esp_err_t __wrap_zn_can_send_burst(zn_can_t *can, const can_message_t *msgs, size_t n, size_t *sent, int timeout_ms);
esp_err_t __wrap_zn_can_send_burst(zn_can_t *can, const can_message_t *msgs, size_t n, size_t *sent, int timeout_ms)
{
	if (fault.kind != TXDROP && fault.kind != TXFLIP)
		return __real_zn_can_send_burst(can, msgs, n, sent, timeout_ms);
	for (*sent = 0; *sent < n; (*sent)++) {
		esp_err_t rc = __wrap_zn_can_transmit(can, &msgs[*sent], timeout_ms);
		if (rc != ESP_OK)
			return rc;
	}
	return ESP_OK;
}

/* no-freshness: the component's callback sees every command without a source time. The
 * wrappers live in static storage: Zenoh may still start a callback while undeclaring. */
static struct sub_wrap {
	zn_sample_cb cb;
	void *ctx;
} subs[ZN_MAX_BUSES];
static unsigned sub_count;

static void stripped(const uint8_t *payload, size_t len, const uint8_t *att, size_t att_len, uint64_t source_time_ns,
		     void *ctx)
{
	(void)source_time_ns;
	struct sub_wrap *w = ctx;
	uint8_t copy[ZN_ATTACHMENT_SIZE(ZN_BATCH_MAX_FRAMES)];
	if (!att || att_len < ZN_ATTACHMENT_HEADER || att_len > sizeof(copy)) {
		w->cb(payload, len, att, att_len, 0, w->ctx); /* none to strip, or the component refuses it */
		return;
	}
	memcpy(copy, att, att_len);
	memset(copy + ZN_ATTACHMENT_HEADER, 0, att_len - ZN_ATTACHMENT_HEADER); /* the frame times */
	w->cb(payload, len, copy, att_len, 0, w->ctx);
}

int __wrap_zn_declare_subscriber(zn_session_t *s, const char *key, zn_sample_cb cb, void *ctx, zn_subscriber_t **out)
{
	pthread_once(&fault.once, parse_fault);
	unsigned i = __atomic_fetch_add(&sub_count, 1, __ATOMIC_RELAXED) % ZN_MAX_BUSES; /* a node's buses, reused per init */
	if (fault.kind != NOFRESH)
		return __real_zn_declare_subscriber(s, key, cb, ctx, out);
	subs[i] = (struct sub_wrap){ cb, ctx };
	return __real_zn_declare_subscriber(s, key, stripped, &subs[i], out);
}
